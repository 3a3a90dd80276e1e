//! Poses an arm can trust (issue 14): covariances that hold over many noisy
//! views, a hole caught by a shadow edge dropped, per-hole pixel sigmas used,
//! and mono's mirror ambiguity told rather than hidden.

use nalgebra::{Isometry3, Matrix2, Point2, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector2, Vector3};
use outlet_pose::{Observations, OutletPose, PlaneMeasurement, PoseError, solve_mono, solve_normal, solve_plane};
use outlet_protocol::{CameraModel, OutletGeometry};

/// Chi-square, 3 degrees of freedom, 99.9% point.
const CHI2_3_999: f64 = 16.27;

fn camera() -> CameraModel {
    CameraModel::default_vga()
}

fn pose(distance: f64, tilt_deg: f64, azimuth_deg: f64, roll_deg: f64) -> Isometry3<f64> {
    let az = azimuth_deg.to_radians();
    let axis = Unit::new_normalize(Vector3::new(az.cos(), az.sin(), 0.0));
    let r = Rotation3::from_axis_angle(&axis, tilt_deg.to_radians())
        * Rotation3::from_axis_angle(&Vector3::z_axis(), roll_deg.to_radians());
    Isometry3::from_parts(Translation3::new(0.01, -0.01, distance), UnitQuaternion::from_rotation_matrix(&r))
}

fn model(name: &str) -> Vec<Point2<f64>> {
    OutletGeometry::builtin(name).expect("builtin").holes.iter().map(|h| h.position()).collect()
}

fn hole(truth: &Isometry3<f64>, m: &Point2<f64>) -> Point3<f64> {
    truth * Point3::new(m.x / 1000.0, m.y / 1000.0, 0.0)
}

fn pixels(truth: &Isometry3<f64>, model: &[Point2<f64>]) -> Vec<Point2<f64>> {
    model.iter().map(|m| camera().project(&hole(truth, m)).expect("in front")).collect()
}

fn nees(sol: &OutletPose, truth: &Isometry3<f64>, model: &[Point2<f64>]) -> Vec<f64> {
    sol.holes_cam_m
        .iter()
        .zip(&sol.covariances)
        .zip(model)
        .map(|((h, c), m)| {
            let e = h - hole(truth, m);
            (e.transpose() * c.try_inverse().expect("invertible") * e)[0]
        })
        .collect()
}

/// Issue 14's test of a set of NEES values (3 dof): mean within [0.7, 1.4] x 3,
/// at most 1% beyond the 99.9% point, none beyond 25.
fn holds(values: &[f64], max_allowed: f64) -> Result<(), String> {
    let mean = values.iter().sum::<f64>() / values.len() as f64 / 3.0;
    let beyond = values.iter().filter(|v| **v > CHI2_3_999).count() as f64 / values.len() as f64;
    let max = values.iter().copied().fold(0.0, f64::max);
    if (0.7..=1.4).contains(&mean) && beyond <= 0.01 && max <= max_allowed {
        Ok(())
    } else {
        Err(format!("mean {mean:.2} x 3, {:.2}% beyond 16.27, max {max:.1}", beyond * 100.0))
    }
}

struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    fn gauss(&mut self) -> f64 {
        (-2.0 * self.unit().ln()).sqrt() * (std::f64::consts::TAU * self.unit()).cos()
    }
}

/// Noisy views as the detector and stereo give them: every hole its own pixel
/// sigma (0.08-0.5 px, known to the solver; as the detector's, the whole of its
/// error: its own noise is `OWN_NOISE_SHARE` of it), a slot's noise 2 times larger along
/// its length than across it in variance (its shape known to the solver), a
/// shift and a scale common to every hole of the sizes the solver assumes for
/// the outlet's size in the image, the wall plane drawn from its own covariance.
/// Returns each mode's NEES values over `frames` views.
fn noisy_views(frames: usize, seed: u64) -> [Vec<f64>; 3] {
    let mut rng = Rng(seed);
    let mut out: [Vec<f64>; 3] = Default::default();
    for f in 0..frames {
        let name = if f % 2 == 0 { "2x1" } else { "2x2" };
        let m = model(name);
        let truth = pose(rng.range(0.2, 0.5), rng.range(0.0, 40.0), rng.range(0.0, 360.0), rng.range(-20.0, 20.0));
        let clean = pixels(&truth, &m);
        let sigmas: Vec<f64> = m.iter().map(|_| rng.range(0.08, 0.5)).collect();
        let mut sorted = sigmas.clone();
        sorted.sort_by(f64::total_cmp);
        // Pixels per mm of the face: the holes' spread in the image over theirs on the face.
        let spread = |p: &[Point2<f64>]| {
            let c = p.iter().fold(Vector2::zeros(), |a, q| a + q.coords) / p.len() as f64;
            p.iter().map(|q| (q.coords - c).norm_squared()).sum::<f64>().sqrt()
        };
        let px_per_mm = spread(&clean) / spread(&m);
        let common_sigma = outlet_pose::COMMON_SIGMA_FRACTION * sorted[sorted.len() / 2] * px_per_mm
            / outlet_pose::COMMON_REFERENCE_PX_PER_MM;
        let common = Point2::new(common_sigma * rng.gauss(), common_sigma * rng.gauss()).coords;
        let centre = clean.iter().fold(Vector2::zeros(), |a, q| a + q.coords) / clean.len() as f64;
        let radius =
            (clean.iter().map(|q| (q.coords - centre).norm_squared()).sum::<f64>() / clean.len() as f64).sqrt();
        let scale = outlet_pose::COMMON_SCALE_SHARE * common_sigma / radius * rng.gauss();
        // Slots (every hole but each receptacle's third) with their length along
        // the outlet's roll, seen roughly so: variance 4/3 along, 2/3 across.
        let along = (truth.rotation * Vector3::y()).xy().normalize();
        let slot = along * along.transpose() * (4.0 / 3.0) + Matrix2::identity() * (2.0 / 3.0)
            - along * along.transpose() * (2.0 / 3.0);
        let shapes: Vec<Matrix2<f64>> =
            (0..m.len()).map(|k| if k % 3 == 2 { Matrix2::identity() } else { slot }).collect();
        let px: Vec<Point2<f64>> = clean
            .iter()
            .zip(&sigmas)
            .zip(&shapes)
            .map(|((p, s), shape)| {
                let l = shape.cholesky().expect("positive definite").l();
                p + l * Vector2::new(rng.gauss(), rng.gauss()) * (*s * outlet_pose::OWN_NOISE_SHARE)
                    + common
                    + (p.coords - centre) * scale
            })
            .collect();
        let obs = Observations {
            model_mm: &m,
            pixels: &px,
            camera: &camera(),
            pixel_sigma: 0.25,
            pixel_sigmas: Some(&sigmas),
            pixel_shapes: Some(&shapes),
        };
        let n = truth.rotation * Vector3::z();
        let d_face = n.dot(&truth.translation.vector);
        let (sigma_tilt, sigma_d) = (0.004, 0.0002);
        let wall = PlaneMeasurement::new(n, d_face + 0.005, sigma_tilt, sigma_d, 0.005);
        let measured = PlaneMeasurement {
            normal: Unit::new_normalize(
                n + wall.tangent[0] * sigma_tilt * rng.gauss() + wall.tangent[1] * sigma_tilt * rng.gauss(),
            ),
            distance_m: wall.distance_m + sigma_d * rng.gauss(),
            ..wall
        };
        let sigma_normal = 0.017;
        let [e1, e2] = outlet_pose::tangent_basis(&n);
        let noisy_normal = (n + e1 * sigma_normal * rng.gauss() + e2 * sigma_normal * rng.gauss()).normalize();
        let results = [solve_plane(&obs, &measured), solve_normal(&obs, &noisy_normal, sigma_normal), solve_mono(&obs)];
        for (values, result) in out.iter_mut().zip(results) {
            match result {
                Ok(sol) => values.extend(nees(&sol, &truth, &m)),
                Err(PoseError::Ambiguous { .. }) => {}
                Err(e) => panic!("frame {f}: {e}"),
            }
        }
    }
    out
}

#[test]
fn covariances_hold_over_noisy_views_and_fail_when_halved() {
    let [plane, normal, mono] = noisy_views(300, 14);
    // Every mode holds the hard limit; mono only with the mirror pose carried
    // by its odds (without it: max 33.5 here, a far view tilted the wrong way).
    for (mode, values, max_allowed) in [("plane", &plane, 25.0), ("normal", &normal, 25.0), ("mono", &mono, 25.0)] {
        assert!(values.len() > 1000, "{mode}: only {} holes solved", values.len());
        holds(values, max_allowed).unwrap_or_else(|e| panic!("{mode}: {e}"));
        // A covariance half the size doubles every NEES: the test must see it.
        let halved: Vec<f64> = values.iter().map(|v| v * 2.0).collect();
        assert!(holds(&halved, max_allowed).is_err(), "{mode}: a covariance 2x too small passed");
    }
}

#[test]
fn a_hole_caught_by_a_shadow_edge_is_dropped_in_plane_mode() {
    // Rendered fw_2x1white view 184 (seed 1), the demo's frame 185: 21 cm away,
    // 7 degrees off-axis; the upper hot slot refined 6.6 px off its centre.
    let m = model("2x1");
    let truth = pose(0.21, 7.0, 30.0, 3.0);
    let mut px = pixels(&truth, &m);
    px[1] += Vector2::new(2.64, -6.03);
    let cam = camera();
    let obs = Observations::uniform(&m, &px, &cam, 0.25);
    let n = truth.rotation * Vector3::z();
    let wall = PlaneMeasurement::new(n, n.dot(&truth.translation.vector) + 0.005, 0.004, 0.0002, 0.005);
    let sol = solve_plane(&obs, &wall).expect("plane");
    assert_eq!(sol.outliers, vec![1], "the displaced hole is the one dropped");
    assert!(sol.rms_px < 0.01, "the kept holes fit: {} px", sol.rms_px);
    for (k, v) in nees(&sol, &truth, &m).iter().enumerate() {
        assert!(*v < CHI2_3_999, "hole {k}: NEES {v:.1}");
    }
    // Mono drops it too, where it can.
    let mono = solve_mono(&obs);
    if let Ok(mono) = mono {
        assert_eq!(mono.outliers, vec![1]);
    }
}

#[test]
fn per_hole_sigmas_weigh_the_holes() {
    let m = model("2x1");
    let truth = pose(0.3, 20.0, 60.0, 0.0);
    let mut px = pixels(&truth, &m);
    px[4].x += 2.0;
    let n = truth.rotation * Vector3::z();
    let wall = PlaneMeasurement::new(n, n.dot(&truth.translation.vector) + 0.005, 0.004, 0.0002, 0.005);
    // Hole 4 known to be poor (3 px): it is no outlier and hardly moves the pose.
    let mut sigmas = vec![0.1; m.len()];
    sigmas[4] = 3.0;
    let obs = Observations {
        model_mm: &m,
        pixels: &px,
        camera: &camera(),
        pixel_sigma: 0.1,
        pixel_sigmas: Some(&sigmas),
        pixel_shapes: None,
    };
    let sol = solve_plane(&obs, &wall).expect("plane");
    assert!(sol.outliers.is_empty());
    let err = sol.holes_cam_m.iter().zip(&m).map(|(h, mm)| (h - hole(&truth, mm)).norm()).fold(0.0, f64::max);
    assert!(err < 2e-5, "{:.3} mm", err * 1e3);
    // Without its own sigma it would be an outlier at 0.1 px.
    let flat = Observations { pixel_sigmas: None, ..obs };
    assert_eq!(solve_plane(&flat, &wall).expect("plane").outliers, vec![4]);
    // Entries that are not positive fall back to `pixel_sigma`.
    let bad = [f64::NAN, 0.0, -1.0, 0.1, 0.1, 0.1];
    assert_eq!(Observations { pixel_sigmas: Some(&bad), ..obs }.sigma_of(0), 0.1);
}

#[test]
fn a_slot_surer_across_than_along_is_weighed_by_axis() {
    // Hole 0 is 2 px off along y; its shape says y is the uncertain axis
    // (variance 1.9 of 2) at a sigma of 0.4 px: 0.55 px along y, 0.13 across.
    // Read as the same on both axes (0.4 px) the offset is an outlier; read with
    // the shape it is 3.6 of its sigmas along y, and kept.
    let m = model("2x1");
    let truth = pose(0.3, 20.0, 60.0, 0.0);
    let mut px = pixels(&truth, &m);
    px[0].y += 2.0;
    let n = truth.rotation * Vector3::z();
    let wall = PlaneMeasurement::new(n, n.dot(&truth.translation.vector) + 0.005, 0.004, 0.0002, 0.005);
    let sigmas = vec![0.4; m.len()];
    let mut shapes = vec![Matrix2::identity(); m.len()];
    shapes[0] = Matrix2::new(0.1, 0.0, 0.0, 1.9);
    let obs = Observations {
        model_mm: &m,
        pixels: &px,
        camera: &camera(),
        pixel_sigma: 0.4,
        pixel_sigmas: Some(&sigmas),
        pixel_shapes: Some(&shapes),
    };
    let shaped = solve_plane(&obs, &wall).expect("plane");
    assert!(shaped.outliers.is_empty(), "dropped {:?}", shaped.outliers);
    let round = solve_plane(&Observations { pixel_shapes: None, ..obs }, &wall).expect("plane");
    assert_eq!(round.outliers, vec![0]);
    // Moved 2 px across instead, the same hole is an outlier with its shape.
    let mut across = pixels(&truth, &m);
    across[0].x += 2.0;
    let sideways = solve_plane(&Observations { pixels: &across, ..obs }, &wall).expect("plane");
    assert_eq!(sideways.outliers, vec![0]);
    // Shapes that are not usable read as the identity; others are scaled to trace 2.
    let bad =
        [Matrix2::new(f64::NAN, 0.0, 0.0, 1.0), Matrix2::new(1.0, 2.0, 2.0, 1.0), Matrix2::new(2.0, 0.0, 0.0, 2.0)];
    let checked = Observations { pixel_shapes: Some(&bad), ..obs };
    assert_eq!(checked.shape_of(0), Matrix2::identity());
    assert_eq!(checked.shape_of(1), Matrix2::identity());
    assert_eq!(checked.shape_of(2), Matrix2::identity());
    assert_eq!(checked.shape_of(5), Matrix2::identity());
}

#[test]
fn mono_says_ambiguous_when_the_mirror_explains_the_pixels() {
    let m = model("2x1");
    // 40 cm away, 25 degrees off-axis, 0.3 px of noise: the mirror pose often
    // fits the pixels about as well, and far enough from the truth to matter.
    let far = pose(0.4, 25.0, 30.0, 0.0);
    let clean = pixels(&far, &m);
    let mut rng = Rng(7);
    let (mut ambiguous, mut solved) = (0, 0);
    for _ in 0..200 {
        let px: Vec<Point2<f64>> =
            clean.iter().map(|p| Point2::new(p.x + 0.3 * rng.gauss(), p.y + 0.3 * rng.gauss())).collect();
        let cam = camera();
        let obs = Observations::uniform(&m, &px, &cam, 0.3);
        match solve_mono(&obs) {
            Err(PoseError::Ambiguous { best_cost, other_cost }) => {
                let factor = (best_cost / 6.0 / outlet_pose::MONO_OWN_NOISE_SHARE.powi(2)).max(1.0);
                assert!(other_cost - best_cost < outlet_pose::MONO_AMBIGUITY_LLR * factor + 1e-9);
                ambiguous += 1;
            }
            Ok(_) => solved += 1,
            Err(e) => panic!("{e}"),
        }
    }
    assert!(ambiguous >= 10, "{ambiguous} of 200 ambiguous ({solved} solved)");
    assert!(solved >= 10, "{solved} of 200 solved");
    // Near and oblique: the mirror is far worse, and the pose is the truth.
    let near = pose(0.22, 35.0, 30.0, 0.0);
    let near_px = pixels(&near, &m);
    let cam = camera();
    let obs = Observations::uniform(&m, &near_px, &cam, 0.25);
    let sol = solve_mono(&obs).expect("unambiguous");
    let err = sol.holes_cam_m.iter().zip(&m).map(|(h, mm)| (h - hole(&near, mm)).norm()).fold(0.0, f64::max);
    assert!(err < 1e-9);
}

#[test]
fn a_face_further_from_the_wall_than_nominal_is_covered_by_its_prior() {
    // The face stands 7 mm ahead of the wall, the template says 5: the plane
    // puts the holes 2 mm too deep. Only the face-offset prior covers that.
    let m = model("2x1");
    let truth = pose(0.3, 20.0, 60.0, 0.0);
    let px = pixels(&truth, &m);
    let cam = camera();
    let obs = Observations::uniform(&m, &px, &cam, 0.15);
    let n = truth.rotation * Vector3::z();
    let wall = PlaneMeasurement::new(n, n.dot(&truth.translation.vector) + 0.007, 0.002, 0.0002, 0.005);
    let worst =
        |w: &PlaneMeasurement| nees(&solve_plane(&obs, w).expect("plane"), &truth, &m).into_iter().fold(0.0, f64::max);
    assert!(worst(&wall) > 25.0, "without the prior the error bars miss: {}", worst(&wall));
    let covered = wall.with_model_error(1.15e-3, 0.0, 0.0);
    assert!(worst(&covered) < CHI2_3_999, "with it they hold: {}", worst(&covered));
    // Nothing added, nothing changed.
    assert_eq!(wall.with_model_error(0.0, 0.0, 0.0), wall);
}
