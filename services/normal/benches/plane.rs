//! Wall-plane fit on rendered stereo clouds: 640x480 (76 800 points, stereo step
//! 2) and 1280x960 (307 200 points), and the face's offset measured around the
//! outlet's holes in the same clouds. `cargo bench -p outlet-normal --bench plane`.

use criterion::{Criterion, criterion_group, criterion_main};
use outlet_normal::{FaceParams, PlaneParams, fit_wall_plane, measure_face};
use outlet_protocol::CameraModel;
use std::hint::black_box;

fn cloud(width: u32, height: u32, index: u64) -> (Vec<[f32; 3]>, PlaneParams, outlet_sim::Scene) {
    let f = 525.0 * width as f64 / 640.0;
    let camera =
        CameraModel::new(width, height, [f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0], [0.0; 5])
            .expect("camera");
    let scene = outlet_sim::sample_scene("white2x2", 1, index, &camera).expect("scene");
    let params = PlaneParams::for_stereo(f, scene.stereo.baseline_m, scene.stereo.disparity_sigma_px);
    (outlet_sim::stereo_cloud(&scene), params, scene)
}

fn bench(c: &mut Criterion) {
    for (width, height) in [(640, 480), (1280, 960)] {
        let (points, params, scene) = cloud(width, height, 0);
        c.bench_function(&format!("fit_wall_plane {} points ({width}x{height})", points.len()), |b| {
            b.iter(|| fit_wall_plane(black_box(&points), black_box(&params)).expect("plane"))
        });
        let wall = fit_wall_plane(&points, &params).expect("plane");
        let holes: Vec<nalgebra::Point2<f64>> =
            scene.geometry().expect("outlet").holes.iter().map(|h| h.position()).collect();
        let face = FaceParams::default();
        assert!(measure_face(&points, &wall, &scene.pose, &holes, &face).is_some(), "no face measured");
        c.bench_function(&format!("measure_face {} points ({width}x{height})", points.len()), |b| {
            b.iter(|| measure_face(black_box(&points), &wall, &scene.pose, &holes, &face))
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
