//! Properties of the pose solvers over random scenes (proptest):
//! - a rigid motion of the outlet and its wall (camera fixed, outlet kept in view
//!   and in front) moves every solution with it, and on noise-free pixels the
//!   solution is the true pose;
//! - scaling the pixels' noise sigma by k scales every predicted covariance by k²
//!   (in plane mode together with the plane's covariance, the other input).

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use outlet_pose::{Observations, OutletPose, PlaneMeasurement, solve_mono, solve_normal, solve_plane};
use outlet_protocol::{CameraModel, OutletGeometry};
use proptest::prelude::*;

fn camera() -> CameraModel {
    CameraModel { distortion: [-0.12, 0.05, 0.001, -0.001, 0.0], ..CameraModel::default_vga() }
}

fn model(name: &str) -> Vec<Point2<f64>> {
    OutletGeometry::builtin(name).expect("builtin").holes.iter().map(|h| h.position()).collect()
}

fn hole_m(m: &Point2<f64>) -> Point3<f64> {
    Point3::new(m.x / 1000.0, m.y / 1000.0, 0.0)
}

/// Noise-free pixels of the holes; `None` when a hole is behind the camera or
/// less than 10 px inside the image, or the outlet is seen within 30 degrees of
/// edge on.
fn pixels(truth: &Isometry3<f64>, model: &[Point2<f64>], cam: &CameraModel) -> Option<Vec<Point2<f64>>> {
    let normal = truth.rotation * Vector3::z();
    let sight = truth.translation.vector.normalize();
    if normal.dot(&sight).abs() < 30f64.to_radians().sin() {
        return None;
    }
    model
        .iter()
        .map(|m| {
            let p = truth * hole_m(m);
            (p.z > 0.05).then_some(())?;
            cam.project(&p).filter(|q| cam.contains(*q, 10.0))
        })
        .collect()
}

/// The wall of the outlet as stereo would measure it: the face plane moved back
/// by the face offset, with a modest uncertainty.
fn wall(truth: &Isometry3<f64>, covariance_scale: f64) -> PlaneMeasurement {
    let n = truth.rotation * Vector3::z();
    let d_face = n.dot(&truth.translation.vector);
    let mut plane = PlaneMeasurement::new(n, d_face + 0.005, 0.01, 0.0005, 0.005);
    plane.covariance *= covariance_scale;
    plane
}

/// An outlet 20-55 cm away, tilted up to 40 degrees, any roll, a little off centre.
fn outlet_pose() -> impl Strategy<Value = Isometry3<f64>> {
    (0.2..0.55f64, 0.0..40f64, 0.0..360f64, -180.0..180f64, -0.04..0.04f64, -0.03..0.03f64).prop_map(
        |(distance, tilt_deg, azimuth_deg, roll_deg, x, y)| {
            let az = azimuth_deg.to_radians();
            let axis = Unit::new_normalize(Vector3::new(az.cos(), az.sin(), 0.0));
            let r = Rotation3::from_axis_angle(&axis, tilt_deg.to_radians())
                * Rotation3::from_axis_angle(&Vector3::z_axis(), roll_deg.to_radians());
            Isometry3::from_parts(Translation3::new(x, y, distance), UnitQuaternion::from_rotation_matrix(&r))
        },
    )
}

/// A rigid motion of the scene in the camera frame: a turn of up to 0.4 rad about
/// any axis through `centre`, then a shift of up to 4 cm.
fn motion_about(centre: Vector3<f64>) -> impl Strategy<Value = Isometry3<f64>> {
    (
        0.0..std::f64::consts::PI,
        0.0..std::f64::consts::TAU,
        0.0..0.4f64,
        [-0.04..0.04f64, -0.04..0.04f64, -0.04..0.04f64],
    )
        .prop_map(move |(polar, azimuth, angle, [dx, dy, dz])| {
            let axis = Unit::new_normalize(Vector3::new(
                polar.sin() * azimuth.cos(),
                polar.sin() * azimuth.sin(),
                polar.cos(),
            ));
            let turn = UnitQuaternion::from_axis_angle(&axis, angle);
            // x -> turn (x - c) + c + shift
            let t = centre - turn * centre + Vector3::new(dx, dy, dz);
            Isometry3::from_parts(Translation3::from(t), turn)
        })
}

/// A scene and a motion of it that keeps the outlet in view.
fn scene_and_motion() -> impl Strategy<Value = (Isometry3<f64>, Isometry3<f64>)> {
    outlet_pose().prop_flat_map(|truth| (Just(truth), motion_about(truth.translation.vector)))
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Solver {
    Normal,
    Plane,
    Mono,
}

fn solve(
    solver: Solver,
    truth: &Isometry3<f64>,
    m: &[Point2<f64>],
    px: &[Point2<f64>],
    sigma_px: f64,
    plane_covariance_scale: f64,
) -> Result<OutletPose, TestCaseError> {
    let cam = camera();
    let obs = Observations::uniform(m, px, &cam, sigma_px);
    let result = match solver {
        Solver::Normal => solve_normal(&obs, &(truth.rotation * Vector3::z()), 0.0),
        Solver::Plane => solve_plane(&obs, &wall(truth, plane_covariance_scale)),
        Solver::Mono => solve_mono(&obs),
    };
    match result {
        Ok(p) => Ok(p),
        // A view whose mirror pose explains the pixels as well: mono says so, rightly.
        Err(outlet_pose::PoseError::Ambiguous { .. }) => Err(TestCaseError::reject("mono ambiguous")),
        Err(e) => panic!("{solver:?} at {truth}: {e}"),
    }
}

/// Largest distance between corresponding holes (m).
fn hole_distance(a: &[Point3<f64>], b: &[Point3<f64>]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).norm()).fold(0.0, f64::max)
}

fn solvers() -> impl Strategy<Value = Solver> {
    prop_oneof![Just(Solver::Normal), Just(Solver::Plane), Just(Solver::Mono)]
}

fn template() -> impl Strategy<Value = &'static str> {
    prop_oneof![Just("2x1"), Just("2x2")]
}

/// 64 cases, or `PROPTEST_CASES` for a longer search.
fn cases() -> u32 {
    std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(64)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), max_global_rejects: 4096, ..ProptestConfig::default() })]

    /// Moving the outlet and its wall by an isometry moves the solved pose, and
    /// every hole, by the same isometry; both equal the truth on exact pixels.
    #[test]
    fn rigid_motion_of_the_scene_moves_the_solution_with_it(
        (truth, motion) in scene_and_motion(),
        solver in solvers(),
        name in template(),
    ) {
        let m = model(name);
        let moved = motion * truth;
        let (Some(px), Some(moved_px)) = (pixels(&truth, &m, &camera()), pixels(&moved, &m, &camera())) else {
            return Err(TestCaseError::reject("outlet out of view"));
        };
        let before = solve(solver, &truth, &m, &px, 0.2, 1.0)?;
        let after = solve(solver, &moved, &m, &moved_px, 0.2, 1.0)?;

        // The solution moved with the scene.
        let carried: Vec<Point3<f64>> = before.holes_cam_m.iter().map(|h| motion * h).collect();
        let e = hole_distance(&after.holes_cam_m, &carried);
        prop_assert!(e < 1e-8, "{solver:?}: holes {e:e} m from the moved solution");
        let turn = (motion * before.pose).rotation.angle_to(&after.pose.rotation);
        prop_assert!(turn < 1e-7, "{solver:?}: pose turned {turn:e} rad from the moved solution");

        // And both are the truth.
        for (pose, sol) in [(&truth, &before), (&moved, &after)] {
            let exact: Vec<Point3<f64>> = m.iter().map(|h| pose * hole_m(h)).collect();
            let e = hole_distance(&sol.holes_cam_m, &exact);
            prop_assert!(e < 1e-9, "{solver:?}: holes {e:e} m from the truth");
            prop_assert!(pose.rotation.angle_to(&sol.pose.rotation) < 1e-8);
            prop_assert!((pose.translation.vector - sol.pose.translation.vector).norm() < 1e-9);
            prop_assert!(sol.rms_px < 1e-6);
        }
    }

    /// The predicted covariance is linear in the pixels' noise variance: sigma
    /// times k gives k² times every hole's covariance (plane mode: with the
    /// plane's covariance also times k², since it is the other input). Not mono:
    /// its covariance carries the mirror pose by the odds the pixels give it,
    /// which noisier pixels raise.
    #[test]
    fn scaling_the_pixel_noise_scales_the_covariance_by_its_square(
        truth in outlet_pose(),
        solver in prop_oneof![Just(Solver::Normal), Just(Solver::Plane)],
        name in template(),
        sigma_px in 0.05..1.0f64,
        k in 0.1..10.0f64,
    ) {
        let m = model(name);
        let Some(px) = pixels(&truth, &m, &camera()) else {
            return Err(TestCaseError::reject("outlet out of view"));
        };
        let base = solve(solver, &truth, &m, &px, sigma_px, 1.0)?;
        let scaled = solve(solver, &truth, &m, &px, k * sigma_px, k * k)?;
        for (i, (a, b)) in base.covariances.iter().zip(&scaled.covariances).enumerate() {
            let expected: Matrix3<f64> = a * (k * k);
            let relative = (b - expected).norm() / expected.norm();
            prop_assert!(relative < 1e-9, "{solver:?} hole {i}: relative error {relative:e}\n{b}\nvs k² x\n{a}");
            prop_assert!(a.symmetric_eigenvalues().min() >= -1e-12 * a.norm(), "{solver:?} hole {i}: {a}");
        }
    }
}
