//! The pose solvers on synthetic holes: exact without noise, honest covariances
//! with noise, clear errors on degenerate input.

use nalgebra::{Isometry3, Matrix3, Point2, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector2, Vector3};
use outlet_pose::{Mode, Observations, OutletPose, PlaneMeasurement, PoseError, solve_mono, solve_normal, solve_plane};
use outlet_protocol::{CameraModel, OutletGeometry};

fn camera() -> CameraModel {
    CameraModel { distortion: [-0.12, 0.05, 0.001, -0.001, 0.0], ..CameraModel::default_vga() }
}

/// An outlet `distance` m away along the optical axis, tilted `tilt_deg` about an
/// axis in the image plane at `azimuth_deg`, rolled `roll_deg`.
fn pose(distance: f64, tilt_deg: f64, azimuth_deg: f64, roll_deg: f64) -> Isometry3<f64> {
    let az = azimuth_deg.to_radians();
    let axis = Unit::new_normalize(Vector3::new(az.cos(), az.sin(), 0.0));
    let r = Rotation3::from_axis_angle(&axis, tilt_deg.to_radians())
        * Rotation3::from_axis_angle(&Vector3::z_axis(), roll_deg.to_radians());
    Isometry3::from_parts(Translation3::new(0.02, -0.01, distance), UnitQuaternion::from_rotation_matrix(&r))
}

fn model(name: &str) -> Vec<Point2<f64>> {
    OutletGeometry::builtin(name).expect("builtin").holes.iter().map(|h| h.position()).collect()
}

fn pixels(truth: &Isometry3<f64>, model: &[Point2<f64>], cam: &CameraModel) -> Vec<Point2<f64>> {
    model
        .iter()
        .map(|m| cam.project(&(truth * Point3::new(m.x / 1000.0, m.y / 1000.0, 0.0))).expect("in front"))
        .collect()
}

fn wall(truth: &Isometry3<f64>) -> PlaneMeasurement {
    let n = truth.rotation * Vector3::z();
    let d_face = n.dot(&truth.translation.vector);
    PlaneMeasurement::new(n, d_face + 0.005, 0.01, 0.0005, 0.005)
}

fn max_error(sol: &OutletPose, truth: &Isometry3<f64>, model: &[Point2<f64>]) -> f64 {
    model
        .iter()
        .zip(&sol.holes_cam_m)
        .map(|(m, h)| (truth * Point3::new(m.x / 1000.0, m.y / 1000.0, 0.0) - h).norm())
        .fold(0.0, f64::max)
}

#[test]
fn noise_free_holes_give_the_exact_pose_in_every_mode() {
    let cam = camera();
    for name in ["2x1", "2x2"] {
        let m = model(name);
        for (d, tilt, az, roll) in
            [(0.2, 0.0, 0.0, 0.0), (0.35, 25.0, 40.0, 10.0), (0.5, 40.0, 200.0, 180.0), (0.3, 38.0, 90.0, -70.0)]
        {
            let truth = pose(d, tilt, az, roll);
            let px = pixels(&truth, &m, &cam);
            let obs = Observations::uniform(&m, &px, &cam, 0.2);
            let n = truth.rotation * Vector3::z();
            let sols = [
                solve_normal(&obs, &n, 0.0).expect("normal"),
                solve_normal(&obs, &-n, 0.0).expect("normal, other sign"),
                solve_plane(&obs, &wall(&truth)).expect("plane"),
                solve_mono(&obs).expect("mono"),
            ];
            for s in &sols {
                let e = max_error(s, &truth, &m);
                assert!(e < 1e-9, "{name} {:?} at {d} m {tilt} deg: error {e:e} m", s.mode);
                assert!(s.rms_px < 1e-6);
            }
        }
    }
}

#[test]
fn two_holes_determine_pose_with_known_normal() {
    let cam = camera();
    let m = vec![Point2::new(-6.35, -24.05), Point2::new(6.35, -24.05)];
    let truth = pose(0.3, 30.0, 60.0, 15.0);
    let px = pixels(&truth, &m, &cam);
    let obs = Observations::uniform(&m, &px, &cam, 0.2);
    let sol = solve_normal(&obs, &(truth.rotation * Vector3::z()), 0.0).expect("two holes suffice");
    assert!(max_error(&sol, &truth, &m) < 1e-9);
    // Mono needs four.
    assert!(matches!(solve_mono(&obs), Err(PoseError::TooFewHoles { got: 2, needed: 4, .. })));
}

/// The paper's equations written out again, independently, in the form of
/// planar.cpp: rays scaled to ray · n = 1 and centred; the in-plane angle alpha
/// maximising Σ dray · Rot(n, alpha) p, i.e. alpha = atan2(s1, s2); depth C.
fn paper_closed_form(model: &[Point2<f64>], xy: &[Vector2<f64>], n: &Vector3<f64>) -> Vec<Point3<f64>> {
    let rays: Vec<Vector3<f64>> = xy
        .iter()
        .map(|p| {
            let k = Vector3::new(p.x, p.y, 1.0);
            k / k.dot(n)
        })
        .collect();
    let m = rays.len() as f64;
    let ray_c = rays.iter().fold(Vector3::zeros(), |s, r| s + r) / m;
    let mc = model.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / m;
    // The model rotated so that its plane's normal is n, with x towards n × x0.
    let ap = n.cross(&Vector3::x()).normalize();
    let bp = n.cross(&ap);
    let model_cam: Vec<Vector3<f64>> = model
        .iter()
        .map(|p| {
            let q = (p.coords - mc) / 1000.0;
            ap * q.x + bp * q.y
        })
        .collect();
    let (mut s1, mut s2, mut sq) = (0.0, 0.0, 0.0);
    for (r, p) in rays.iter().zip(&model_cam) {
        let dr = r - ray_c;
        s1 += p.cross(&dr).dot(n); // = dr · (n × p), the sin(alpha) term
        s2 += dr.dot(p);
        sq += dr.norm_squared();
    }
    let alpha = s1.atan2(s2);
    let c = (s2 * alpha.cos() + s1 * alpha.sin()) / sq;
    let rot = Rotation3::from_axis_angle(&Unit::new_normalize(*n), alpha);
    model_cam.iter().map(|p| Point3::from(ray_c * c + rot * p)).collect()
}

#[test]
fn the_normal_mode_is_the_papers_formula_on_identical_inputs() {
    let cam = CameraModel { distortion: [0.0; 5], ..camera() };
    let m = model("2x1");
    let truth = pose(0.4, 30.0, 120.0, 5.0);
    let mut px = pixels(&truth, &m, &cam);
    // Noisy pixels: the two must agree on the same imperfect data, not only on exact data.
    for (k, p) in px.iter_mut().enumerate() {
        p.x += 0.4 * ((k * 7 % 5) as f64 - 2.0) / 2.0;
        p.y += 0.3 * ((k * 3 % 4) as f64 - 1.5) / 1.5;
    }
    let obs = Observations::uniform(&m, &px, &cam, 0.2);
    let n = truth.rotation * Vector3::z();
    let sol = solve_normal(&obs, &n, 0.0).expect("normal");
    let xy: Vec<Vector2<f64>> = px.iter().map(|p| cam.undistort_pixel(*p)).collect();
    let paper = paper_closed_form(&m, &xy, &n);
    for (a, b) in sol.holes_cam_m.iter().zip(&paper) {
        assert!((a - b).norm() < 1e-12, "{a} vs {b}");
    }
}

fn monte_carlo(mode: Mode) {
    let cam = camera();
    let m = model("2x1");
    let truth = pose(0.35, 25.0, 30.0, 8.0);
    let clean = pixels(&truth, &m, &cam);
    let sigma_px = 0.3;
    let plane = wall(&truth);
    let n_true = truth.rotation * Vector3::z();
    let mut rng = 12345u64;
    let mut gauss = || {
        // Box-Muller on a small LCG: the test owns its randomness.
        let mut u = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((rng >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (-2.0 * u().ln()).sqrt() * (std::f64::consts::TAU * u()).cos()
    };
    let solve = |px: &[Point2<f64>], plane: &PlaneMeasurement, normal: &Vector3<f64>| {
        let obs = Observations::uniform(&m, px, &cam, sigma_px);
        match mode {
            Mode::Normal => solve_normal(&obs, normal, 0.01),
            Mode::Plane => solve_plane(&obs, plane),
            Mode::Mono => solve_mono(&obs),
        }
    };
    let predicted = solve(&clean, &plane, &n_true).expect("clean solve").covariances;
    let trials = 1000;
    let mut sums = vec![Matrix3::zeros(); m.len()];
    let mut solved = 0;
    for _ in 0..trials {
        // A hole's own noise is the mode's share of its sigma (the rest is
        // common to every hole, which this test does not draw).
        let own = sigma_px
            * if mode == Mode::Mono { outlet_pose::MONO_OWN_NOISE_SHARE } else { outlet_pose::OWN_NOISE_SHARE };
        let px: Vec<Point2<f64>> =
            clean.iter().map(|p| Point2::new(p.x + own * gauss(), p.y + own * gauss())).collect();
        let [e1, e2] = outlet_pose::tangent_basis(&n_true);
        let n = (n_true + e1 * 0.01 * gauss() + e2 * 0.01 * gauss()).normalize();
        let noisy_plane = PlaneMeasurement {
            normal: Unit::new_normalize(n),
            distance_m: plane.distance_m + 0.0005 * gauss(),
            tangent: plane.tangent,
            ..plane
        };
        // The plane's own tangent basis: perturb along it so the model matches.
        let noisy_plane = if mode == Mode::Plane {
            let n = (n_true + plane.tangent[0] * 0.01 * gauss() + plane.tangent[1] * 0.01 * gauss()).normalize();
            PlaneMeasurement { normal: Unit::new_normalize(n), ..noisy_plane }
        } else {
            noisy_plane
        };
        // Mono refuses a frame whose mirror pose is nearly as good: no error to count.
        let sol = match solve(&px, &noisy_plane, &n) {
            Err(outlet_pose::PoseError::Ambiguous { .. }) if mode == Mode::Mono => continue,
            other => other.expect("noisy solve"),
        };
        solved += 1;
        for (i, (h, mm)) in sol.holes_cam_m.iter().zip(&m).enumerate() {
            let e = h - truth * Point3::new(mm.x / 1000.0, mm.y / 1000.0, 0.0);
            sums[i] += e * e.transpose();
        }
    }
    for (i, (s, p)) in sums.iter().zip(&predicted).enumerate() {
        assert!(solved > trials * 9 / 10, "{mode:?}: only {solved} of {trials} solved");
        let empirical = s / solved as f64;
        // Compare the total variance and the largest axis.
        let (te, tp) = (empirical.trace(), p.trace());
        assert!((te / tp - 1.0).abs() < 0.25, "{mode:?} hole {i}: empirical trace {te:e} vs predicted {tp:e}");
        let (le, lp) = (empirical.symmetric_eigenvalues().max(), p.symmetric_eigenvalues().max());
        assert!((le / lp - 1.0).abs() < 0.25, "{mode:?} hole {i}: largest axis {le:e} vs {lp:e}");
    }
}

#[test]
fn predicted_covariance_matches_monte_carlo_in_plane_mode() {
    monte_carlo(Mode::Plane);
}

#[test]
fn predicted_covariance_matches_monte_carlo_in_normal_mode() {
    monte_carlo(Mode::Normal);
}

#[test]
fn predicted_covariance_matches_monte_carlo_in_mono_mode() {
    monte_carlo(Mode::Mono);
}

#[test]
fn degenerate_inputs_give_clear_errors_never_nan() {
    let cam = camera();
    let m = model("2x1");
    let truth = pose(0.3, 10.0, 0.0, 0.0);
    let px = pixels(&truth, &m, &cam);
    let obs = Observations::uniform(&m, &px, &cam, 0.2);
    // A normal lying in the image plane (perpendicular to the line of sight).
    let grazing = Vector3::new(1.0, 0.0, 0.0);
    let e = solve_normal(&obs, &grazing, 0.0).expect_err("grazing normal");
    assert!(matches!(e, PoseError::GrazingNormal { .. }), "{e}");
    assert!(e.to_string().contains("parallel to the image plane"));
    assert!(matches!(solve_normal(&obs, &Vector3::zeros(), 0.0), Err(PoseError::BadNormal)));
    assert!(matches!(solve_normal(&obs, &Vector3::new(f64::NAN, 0.0, 1.0), 0.0), Err(PoseError::BadNormal)));
    // Collinear holes: a line of four.
    let line: Vec<Point2<f64>> = (0..4).map(|k| Point2::new(k as f64 * 10.0, 0.0)).collect();
    let lpx = pixels(&truth, &line, &cam);
    let lobs = Observations::uniform(&line, &lpx, &cam, 0.2);
    assert!(matches!(solve_mono(&lobs), Err(PoseError::Collinear)));
    // Empty and non-finite inputs.
    let empty = Observations::uniform(&[], &[], &cam, 0.2);
    assert!(matches!(solve_plane(&empty, &wall(&truth)), Err(PoseError::TooFewHoles { got: 0, .. })));
    let mut bad = px.clone();
    bad[2].x = f64::NAN;
    let bobs = Observations::uniform(&m, &bad, &cam, 0.2);
    assert!(matches!(solve_mono(&bobs), Err(PoseError::NonFinite { index: 2 })));
    let nan_plane = PlaneMeasurement { distance_m: f64::NAN, ..wall(&truth) };
    assert!(matches!(solve_plane(&obs, &nan_plane), Err(PoseError::BadPlane)));
    assert!(matches!(
        solve_normal(&Observations { pixel_sigma: 0.0, ..obs }, &(truth.rotation * Vector3::z()), 0.0),
        Err(PoseError::BadSigma(_))
    ));
    // Whatever is returned is finite.
    for s in
        [solve_normal(&obs, &(truth.rotation * Vector3::z()), 0.01), solve_plane(&obs, &wall(&truth)), solve_mono(&obs)]
            .into_iter()
            .flatten()
    {
        assert!(s.holes_cam_m.iter().all(|h| h.coords.iter().all(|v| v.is_finite())));
        assert!(s.covariances.iter().all(|c| c.iter().all(|v| v.is_finite())));
    }
}

#[test]
fn a_stereo_plane_of_another_wall_is_refused_even_with_wide_priors() {
    // Error bars as wide as real stereo needs (a face 1.15 mm, the plane 0.48
    // degrees and 1.32 mm uncertain) leave the pixels free to pull the pose off
    // the measured plane; a wall 5 cm behind the outlet must not be absorbed.
    let cam = camera();
    let m = model("2x1");
    let truth = pose(0.3, 20.0, 30.0, 5.0);
    let px = pixels(&truth, &m, &cam);
    let obs = Observations::uniform(&m, &px, &cam, 0.2);
    let real = |p: PlaneMeasurement| p.with_model_error(1.15e-3, 0.48f64.to_radians(), 1.32e-3);
    let right = real(wall(&truth));
    let sol = solve_plane(&obs, &right).expect("the outlet's own wall");
    assert!(max_error(&sol, &truth, &m) < 2e-4, "{}", max_error(&sol, &truth, &m));
    let behind = real(PlaneMeasurement { distance_m: right.distance_m + 0.05, ..wall(&truth) });
    match solve_plane(&obs, &behind) {
        Err(PoseError::PlaneDisagrees { chi2 }) => assert!(chi2 > outlet_pose::MAX_PLANE_DISAGREEMENT, "{chi2}"),
        other => panic!("a wall 5 cm behind the outlet gave {other:?}"),
    }
    // A plane turned 5 degrees (about 7 sigma of the prior) is refused as well.
    let turned = Rotation3::from_axis_angle(&Vector3::x_axis(), 5f64.to_radians()) * (truth.rotation * Vector3::z());
    let tilted = real(PlaneMeasurement::new(turned, right.distance_m, 0.01, 0.0005, 0.005));
    assert!(matches!(solve_plane(&obs, &tilted), Err(PoseError::PlaneDisagrees { .. })));
}
