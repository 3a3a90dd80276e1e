//! Time to solve one outlet's pose (with covariances), per mode.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Point2, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use outlet_pose::{Observations, PlaneMeasurement, solve_mono, solve_normal, solve_plane};
use outlet_protocol::{CameraModel, OutletGeometry};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let cam = CameraModel::default_vga();
    let axis = Unit::new_normalize(Vector3::new(0.6, 0.8, 0.0));
    let truth = Isometry3::from_parts(
        Translation3::new(0.01, 0.02, 0.32),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_axis_angle(&axis, 0.4)),
    );
    for name in ["2x1", "2x2"] {
        let model: Vec<Point2<f64>> =
            OutletGeometry::builtin(name).expect("builtin").holes.iter().map(|h| h.position()).collect();
        let pixels: Vec<Point2<f64>> = model
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let p = cam.project(&(truth * Point3::new(m.x / 1000.0, m.y / 1000.0, 0.0))).expect("in front");
                Point2::new(p.x + 0.2 * ((k % 3) as f64 - 1.0), p.y - 0.2 * ((k % 2) as f64 - 0.5))
            })
            .collect();
        let obs = Observations::uniform(&model, &pixels, &cam, 0.2);
        let n = truth.rotation * Vector3::z();
        let plane = PlaneMeasurement::new(n, n.dot(&truth.translation.vector) + 0.005, 0.005, 0.0003, 0.005);
        c.bench_function(&format!("pose_plane_{name}"), |b| b.iter(|| black_box(solve_plane(&obs, &plane))));
        c.bench_function(&format!("pose_normal_{name}"), |b| b.iter(|| black_box(solve_normal(&obs, &n, 0.017))));
        c.bench_function(&format!("pose_mono_{name}"), |b| b.iter(|| black_box(solve_mono(&obs))));
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
