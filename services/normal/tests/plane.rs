//! The wall plane fitted from stereo clouds: accurate on rendered scenes, blind to
//! the plate standing proud, robust to outliers, clear about bad input, and with a
//! covariance that tells the truth.

use nalgebra::{Point3, Vector3};
use outlet_normal::{PlaneError, PlaneParams, WallPlane, fit_wall_plane};
use outlet_protocol::CameraModel;
use outlet_sim::{SCENARIOS, sample_scene};

/// Depth noise at 1 m of the reference stereo camera (0.15 px, 9 cm, 525 px).
const SIGMA_AT_1M: f64 = 0.15 / (525.0 * 0.09);

/// xorshift64* with Box-Muller: the tests' own noise, independent of the crate's.
struct TestRng(u64);

impl TestRng {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) | 1)
    }
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.unit().max(1e-300), self.unit());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

/// A wall seen by a pinhole stereo camera, with the renderer's noise model: each
/// point slides along its ray by a relative `noise_scale · SIGMA_AT_1M · z · ε`.
#[derive(Debug, Clone, Copy)]
struct Wall {
    /// Distance of the wall along its normal (m).
    distance_m: f64,
    /// Rotation of the wall about the camera's y then x axes (degrees).
    tilt_deg: [f64; 2],
    /// A plate this far proud of the wall (m), over a centred image rectangle
    /// holding this fraction of the points.
    plate: Option<(f64, f64)>,
    /// Fraction of points whose depth is off by a uniform factor in 0.5..1.5.
    outliers: f64,
    /// Noise relative to the reference stereo camera.
    noise_scale: f64,
    /// Image grid: every pixel of a `width` x `height` camera with f = 525 * width / 640.
    width: usize,
    height: usize,
}

impl Wall {
    fn frontal(distance_m: f64) -> Self {
        Self { distance_m, tilt_deg: [0.0, 0.0], plate: None, outliers: 0.0, noise_scale: 1.0, width: 320, height: 240 }
    }

    fn normal(&self) -> Vector3<f64> {
        let [ay, ax] = self.tilt_deg.map(f64::to_radians);
        let n = nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), ax)
            * nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), ay)
            * Vector3::z();
        n.normalize()
    }

    /// Camera frame cloud (the image's pixels at stereo step 2 of a camera twice the size).
    fn cloud(&self, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = TestRng::new(seed);
        let n = self.normal();
        let f = 525.0 * self.width as f64 / 640.0;
        let (cx, cy) = ((self.width as f64 - 1.0) / 2.0, (self.height as f64 - 1.0) / 2.0);
        let (half_w, half_h) = match self.plate {
            Some((_, fraction)) => {
                (fraction.sqrt() * self.width as f64 / 2.0, fraction.sqrt() * self.height as f64 / 2.0)
            }
            None => (-1.0, -1.0),
        };
        let mut points = Vec::with_capacity(self.width * self.height);
        for v in 0..self.height {
            for u in 0..self.width {
                let ray = Vector3::new((u as f64 - cx) / f, (v as f64 - cy) / f, 1.0);
                let on_plate = (u as f64 - cx).abs() < half_w && (v as f64 - cy).abs() < half_h;
                let d = if on_plate { self.distance_m - self.plate.map_or(0.0, |p| p.0) } else { self.distance_m };
                let x = ray * (d / n.dot(&ray));
                let scale = if rng.unit() < self.outliers {
                    rng.range(0.5, 1.5)
                } else {
                    1.0 + rng.normal() * self.noise_scale * SIGMA_AT_1M * x.z
                };
                let q = x * scale;
                points.push([q.x as f32, q.y as f32, q.z as f32]);
            }
        }
        points
    }
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.normalize().dot(&b.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
}

fn assert_finite(plane: &WallPlane) {
    assert!(plane.normal.iter().all(|v| v.is_finite()) && (plane.normal.norm() - 1.0).abs() < 1e-9);
    assert!(plane.distance_m.is_finite() && plane.distance_m >= 0.0);
    assert!(plane.covariance.iter().all(|v| v.is_finite()));
    assert!(plane.tangent.iter().all(|e| e.iter().all(|v| v.is_finite())));
    assert!(plane.rms_m.is_finite());
}

#[test]
fn fitted_plane_matches_the_rendered_truth_across_scenarios_and_distances() {
    let camera = CameraModel::default_vga();
    let params = PlaneParams::default();
    let (mut worst_angle, mut worst_distance, mut count) = (0.0f64, 0.0f64, 0);
    // Errors by distance band: 20-30, 30-40, 40-50 cm.
    let mut bands = [(0.0f64, 0.0f64, 0usize); 3];
    for scenario in SCENARIOS {
        for index in 0..8 {
            let scene = sample_scene(scenario, 21, index, &camera).expect("scene");
            let cloud = outlet_sim::stereo_cloud(&scene);
            let truth = outlet_sim::ground_truth(&scene, "x.png").wall_plane;
            let wall = fit_wall_plane(&cloud, &params).unwrap_or_else(|e| panic!("{scenario} #{index}: {e}"));
            assert_finite(&wall);
            let angle = angle_deg(&wall.normal, &truth.normal());
            let distance_error = (wall.distance_m - truth.distance_m).abs();
            assert!(angle < 0.3, "{scenario} #{index}: normal off by {angle:.4} deg");
            assert!(distance_error < 0.5e-3, "{scenario} #{index}: distance off by {:.4} mm", distance_error * 1e3);
            worst_angle = worst_angle.max(angle);
            worst_distance = worst_distance.max(distance_error);
            count += 1;
            let band = (((truth.distance_m - 0.2) / 0.1).floor().clamp(0.0, 2.0)) as usize;
            bands[band] = (bands[band].0.max(angle), bands[band].1.max(distance_error), bands[band].2 + 1);
        }
    }
    println!(
        "{count} rendered clouds: worst normal error {worst_angle:.4} deg, worst distance error {:.4} mm",
        worst_distance * 1e3
    );
    for (k, (angle, distance, n)) in bands.iter().enumerate() {
        println!(
            "  wall {}-{} cm ({n} clouds): worst normal {angle:.4} deg, worst distance {:.4} mm",
            20 + 10 * k,
            30 + 10 * k,
            distance * 1e3
        );
    }
}

#[test]
fn a_plate_standing_proud_over_30_percent_of_the_points_does_not_bias_the_wall() {
    let params = PlaneParams::default();
    let mut worst = 0.0f64;
    for distance_m in [0.2, 0.3, 0.4, 0.5] {
        for tilt_deg in [[0.0, 0.0], [30.0, 10.0]] {
            let wall = Wall { plate: Some((0.003, 0.3)), tilt_deg, ..Wall::frontal(distance_m) };
            let n_true = wall.normal();
            let (mut bias_d, mut bias_centre, mut angle, seeds) = (0.0, 0.0, 0.0, 5);
            for seed in 0..seeds {
                let fit = fit_wall_plane(&wall.cloud(seed), &params).expect("plane");
                assert_finite(&fit);
                bias_d += (fit.distance_m - distance_m) / seeds as f64;
                // The wall point behind the plate's centre, on the optical axis.
                let centre = Point3::from(Vector3::z() * (distance_m / n_true.z));
                bias_centre += fit.signed_distance(&centre) / seeds as f64;
                angle += angle_deg(&fit.normal, &n_true) / seeds as f64;
            }
            println!(
                "wall at {distance_m} m, tilt {tilt_deg:?} deg, plate 3 mm proud over 30%: distance bias {:+.4} mm, \
                 at the plate centre {:+.4} mm, normal {angle:.4} deg",
                bias_d * 1e3,
                bias_centre * 1e3
            );
            assert!(bias_d.abs() < 0.2e-3 && bias_centre.abs() < 0.2e-3, "bias {bias_d} / {bias_centre} m");
            worst = worst.max(bias_d.abs()).max(bias_centre.abs());
        }
    }
    println!("worst plate bias {:.4} mm", worst * 1e3);
}

#[test]
fn the_plate_is_ignored_even_when_stereo_is_three_times_better_or_worse_than_the_model() {
    let params = PlaneParams::default();
    for (distance_m, noise_scale) in [(0.5, 1.0 / 3.0), (0.3, 3.0), (0.2, 3.0)] {
        let wall = Wall { plate: Some((0.003, 0.3)), noise_scale, ..Wall::frontal(distance_m) };
        let fit = fit_wall_plane(&wall.cloud(3), &params).expect("plane");
        let bias = fit.distance_m - distance_m;
        let sigma = noise_scale * SIGMA_AT_1M * distance_m * distance_m;
        println!(
            "wall at {distance_m} m, noise x{noise_scale:.2} ({:.3} mm): bias {:+.4} mm, rms {:.3} mm",
            sigma * 1e3,
            bias * 1e3,
            fit.rms_m * 1e3
        );
        assert!(bias.abs() < 0.2e-3, "bias {bias}");
    }
}

#[test]
fn the_noise_scale_follows_the_data_not_the_model() {
    for noise_scale in [0.2, 1.0, 3.0] {
        let wall = Wall { noise_scale, ..Wall::frontal(0.35) };
        let fit = fit_wall_plane(&wall.cloud(6), &PlaneParams::default()).expect("plane");
        let sigma = noise_scale * SIGMA_AT_1M * 0.35 * 0.35;
        // The RMS of a normal variable cut at 2.5 sigma is 0.955 sigma.
        let ratio = fit.rms_m / sigma;
        println!("noise x{noise_scale}: rms / sigma = {ratio:.3}, inliers {}", fit.inliers);
        assert!((ratio - 0.955).abs() < 0.03, "rms {} vs sigma {sigma}", fit.rms_m);
        assert!(fit.inliers as f64 > 0.97 * (320.0 * 240.0));
    }
}

#[test]
fn forty_percent_outliers_leave_the_wall_where_it_is() {
    let params = PlaneParams::default();
    for (distance_m, tilt_deg) in [(0.25, [0.0, 0.0]), (0.45, [35.0, -15.0])] {
        let wall = Wall { outliers: 0.4, tilt_deg, plate: Some((0.004, 0.15)), ..Wall::frontal(distance_m) };
        let cloud = wall.cloud(11);
        let fit = fit_wall_plane(&cloud, &params).expect("plane");
        assert_finite(&fit);
        let angle = angle_deg(&fit.normal, &wall.normal());
        let error = fit.distance_m - distance_m;
        println!("40% outliers at {distance_m} m: normal {angle:.4} deg, distance {:+.4} mm", error * 1e3);
        assert!(angle < 0.05 && error.abs() < 0.1e-3);
        assert!(fit.inliers > cloud.len() / 3);
    }
}

#[test]
fn nan_points_are_ignored() {
    let wall = Wall::frontal(0.3);
    let mut cloud = wall.cloud(5);
    let clean = fit_wall_plane(&cloud, &PlaneParams::default()).expect("plane");
    let valid = cloud.len();
    for (k, p) in cloud.iter_mut().enumerate() {
        if k % 3 == 0 {
            p[(k / 3) % 3] = f32::NAN;
        }
    }
    cloud.extend([[f32::INFINITY, 0.0, 1.0], [0.0, f32::NEG_INFINITY, 1.0], [0.0, 0.0, -0.5], [0.1, 0.1, 0.0]]);
    let holey = fit_wall_plane(&cloud, &PlaneParams::default()).expect("plane");
    assert_finite(&holey);
    assert!(holey.inliers < valid * 2 / 3 + 1);
    assert!((holey.distance_m - clean.distance_m).abs() < 0.05e-3);
}

#[test]
fn empty_all_nan_and_two_point_clouds_have_too_few_points() {
    let params = PlaneParams::default();
    let nan = vec![[f32::NAN; 3]; 1000];
    let two = vec![[0.0, 0.0, 0.3], [0.01, 0.0, 0.3]];
    for (name, cloud, expected) in [("empty", vec![], 0), ("all NaN", nan, 0), ("two points", two, 2)] {
        match fit_wall_plane(&cloud, &params) {
            Err(e @ PlaneError::TooFewPoints { valid, needed }) => {
                assert_eq!(valid, expected);
                assert_eq!(needed, params.min_points);
                println!("{name}: {e}");
            }
            other => panic!("{name}: {other:?}"),
        }
    }
}

#[test]
fn uniform_random_points_in_a_box_have_no_dominant_plane() {
    let mut rng = TestRng::new(4);
    let cloud: Vec<[f32; 3]> = (0..50_000)
        .map(|_| [rng.range(-0.2, 0.2) as f32, rng.range(-0.15, 0.15) as f32, rng.range(0.25, 0.55) as f32])
        .collect();
    match fit_wall_plane(&cloud, &PlaneParams::default()) {
        Err(e @ PlaneError::NoDominantPlane { best_inliers, valid }) => {
            assert_eq!(valid, cloud.len());
            assert!(best_inliers < valid / 5);
            println!("{e}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn hostile_clouds_give_an_error_or_a_finite_plane_never_a_panic_or_nan() {
    let params = PlaneParams::default();
    let line: Vec<[f32; 3]> = (0..500).map(|i| [i as f32 * 1e-3, 0.0, 0.4]).collect();
    let same: Vec<[f32; 3]> = vec![[0.01, 0.02, 0.4]; 500];
    let huge: Vec<[f32; 3]> = (0..500).map(|i| [(i % 25) as f32 * 1e30, (i / 25) as f32 * 1e30, 3e38]).collect();
    let tiny: Vec<[f32; 3]> = (0..500).map(|i| [(i % 25) as f32 * 1e-30, (i / 25) as f32 * 1e-30, 1e-30]).collect();
    // A plane through the camera centre, seen edge on.
    let edge: Vec<[f32; 3]> = (0..500).map(|i| [0.0, (i % 25) as f32 * 0.01, 0.2 + (i / 25) as f32 * 0.01]).collect();
    let mut mixed = Wall::frontal(0.3).cloud(2);
    mixed.extend([[f32::MAX, f32::MAX, f32::MAX], [f32::MIN_POSITIVE, 0.0, f32::MIN_POSITIVE], [1e-38, 1e-38, 1e-38]]);
    let exact: Vec<[f32; 3]> = Wall { noise_scale: 0.0, ..Wall::frontal(0.3) }.cloud(1);
    let mut rng = TestRng::new(9);
    let wild: Vec<[f32; 3]> = (0..2000)
        .map(|_| {
            [(rng.normal() * 1e6) as f32, (rng.normal() * 1e-6) as f32, if rng.unit() < 0.5 { 1e-20 } else { 1e20 }]
        })
        .collect();
    for (name, cloud) in [
        ("collinear", line),
        ("one point repeated", same),
        ("huge", huge),
        ("tiny", tiny),
        ("edge on", edge),
        ("extreme values", mixed),
        ("noise free", exact),
        ("wild", wild),
    ] {
        match fit_wall_plane(&cloud, &params) {
            Ok(plane) => {
                assert_finite(&plane);
                println!("{name}: plane {:?} at {} m, {} inliers", plane.normal, plane.distance_m, plane.inliers);
            }
            Err(e) => println!("{name}: {e}"),
        }
    }
    for bad in [
        PlaneParams { sigma_at_1m: 0.0, ..Default::default() },
        PlaneParams { inlier_sigmas: f64::INFINITY, ..Default::default() },
        PlaneParams { min_points: 2, ..Default::default() },
        PlaneParams::default().with_roi(Point3::new(f64::NAN, 0.0, 0.0), 0.1),
    ] {
        assert!(matches!(fit_wall_plane(&[[0.0, 0.0, 1.0]], &bad), Err(PlaneError::InvalidParams(_))), "{bad:?}");
    }
}

#[test]
fn a_noise_free_wall_is_fitted_exactly() {
    let wall = Wall { noise_scale: 0.0, tilt_deg: [20.0, -10.0], ..Wall::frontal(0.35) };
    let fit = fit_wall_plane(&wall.cloud(0), &PlaneParams::default()).expect("plane");
    let angle = angle_deg(&fit.normal, &wall.normal());
    assert!(angle < 1e-4 && (fit.distance_m - 0.35).abs() < 1e-7, "{angle} deg, {} m", fit.distance_m);
    assert_eq!(fit.inliers, 320 * 240);
}

#[test]
fn the_same_seed_gives_the_same_plane() {
    let cloud = Wall { outliers: 0.2, plate: Some((0.003, 0.2)), ..Wall::frontal(0.4) }.cloud(8);
    let a = fit_wall_plane(&cloud, &PlaneParams::default()).expect("plane");
    let b = fit_wall_plane(&cloud, &PlaneParams::default()).expect("plane");
    assert_eq!(a, b);
}

#[test]
fn a_region_of_interest_keeps_the_wall_where_another_plane_dominates_the_image() {
    // Left two thirds of the image: a wall 40 cm ahead; right third: a slanted
    // cupboard side 25 cm ahead with 3 times the point density.
    let wall = Wall::frontal(0.4).cloud(1);
    let side = Wall { tilt_deg: [50.0, 0.0], ..Wall::frontal(0.25) }.cloud(2);
    let mut cloud: Vec<[f32; 3]> = wall.into_iter().filter(|p| p[0] < 0.03).collect();
    let side: Vec<[f32; 3]> = side.into_iter().filter(|p| p[0] > 0.05).collect();
    for _ in 0..3 {
        cloud.extend(&side);
    }
    let global = fit_wall_plane(&cloud, &PlaneParams::default()).expect("plane");
    assert!(angle_deg(&global.normal, &Vector3::z()) > 10.0, "the side dominates the whole image");
    let params = PlaneParams::default().with_roi(Point3::new(-0.05, 0.0, 0.4), 0.12);
    let near = fit_wall_plane(&cloud, &params).expect("plane");
    assert!(angle_deg(&near.normal, &Vector3::z()) < 0.05 && (near.distance_m - 0.4).abs() < 0.1e-3, "{near:?}");
}

/// Empirical standard deviations of `(δa, δb, δd)` over many clouds against the
/// mean predicted ones.
fn covariance_check(wall: Wall, params: &PlaneParams, trials: u64) -> ([f64; 3], [f64; 3]) {
    let n_true = wall.normal();
    let [e1, e2] = outlet_normal::tangent_basis(&n_true);
    let mut samples = Vec::new();
    let mut predicted = [0.0; 3];
    for seed in 0..trials {
        let fit =
            fit_wall_plane(&wall.cloud(1000 + seed), params).unwrap_or_else(|e| panic!("{wall:?} seed {seed}: {e}"));
        let dn = fit.normal.into_inner() - n_true;
        samples.push([dn.dot(&e1), dn.dot(&e2), fit.distance_m - wall.distance_m]);
        // The fit's own tangent basis is within a milliradian of the truth's.
        assert!(fit.tangent[0].dot(&e1) > 0.999 && fit.tangent[1].dot(&e2) > 0.999);
        for (k, p) in predicted.iter_mut().enumerate() {
            *p += fit.covariance[(k, k)] / trials as f64;
        }
    }
    let empirical = [0, 1, 2].map(|k| {
        let mean = samples.iter().map(|s| s[k]).sum::<f64>() / trials as f64;
        (samples.iter().map(|s| (s[k] - mean).powi(2)).sum::<f64>() / (trials - 1) as f64).sqrt()
    });
    (empirical, predicted.map(f64::sqrt))
}

#[test]
fn the_predicted_covariance_matches_the_scatter_of_200_noisy_clouds() {
    let small = |w: Wall| Wall { width: 160, height: 120, ..w };
    let cases = [
        ("frontal 30 cm", small(Wall::frontal(0.3)), PlaneParams::default()),
        (
            "tilted 45 cm, plate, 10% outliers",
            small(Wall { tilt_deg: [30.0, 15.0], plate: Some((0.004, 0.2)), outliers: 0.1, ..Wall::frontal(0.45) }),
            PlaneParams::default(),
        ),
        (
            "noise twice the model, scale not estimated",
            small(Wall { noise_scale: 2.0, tilt_deg: [-20.0, 0.0], ..Wall::frontal(0.25) }),
            PlaneParams { estimate_noise_scale: false, ..Default::default() },
        ),
    ];
    for (name, wall, params) in cases {
        let (empirical, predicted) = covariance_check(wall, &params, 200);
        let ratio = [0, 1, 2].map(|k| predicted[k] / empirical[k]);
        println!(
            "{name}: empirical sigma (a, b, d) = ({:.2e}, {:.2e}, {:.2e}), predicted ({:.2e}, {:.2e}, {:.2e}), \
             ratio ({:.3}, {:.3}, {:.3})",
            empirical[0],
            empirical[1],
            empirical[2],
            predicted[0],
            predicted[1],
            predicted[2],
            ratio[0],
            ratio[1],
            ratio[2]
        );
        assert!(ratio.iter().all(|r| (0.8..1.25).contains(r)), "{name}: predicted / empirical {ratio:?}");
    }
}

#[test]
fn a_dense_cloud_is_thinned_for_the_fit_and_a_sparse_one_keeps_every_valid_point() {
    let dense = Wall::frontal(0.4).cloud(3);
    let every = |cloud: &[[f32; 3]]| PlaneParams { max_points: cloud.len(), ..Default::default() };
    // Thinned to 16 384 points or fewer: the same plane within its sigma, counts for the whole cloud.
    let thinned = fit_wall_plane(&dense, &PlaneParams::default()).expect("plane");
    let all = fit_wall_plane(&dense, &every(&dense)).expect("plane");
    let sigma = thinned.covariance[(2, 2)].sqrt();
    assert!((thinned.distance_m - all.distance_m).abs() < 4.0 * sigma, "{} vs {}", thinned.distance_m, all.distance_m);
    assert!((thinned.inliers as f64 / all.inliers as f64 - 1.0).abs() < 0.02, "{} vs {}", thinned.inliers, all.inliers);
    // Thinning costs precision as the square root of the points dropped.
    let ratio = sigma / all.covariance[(2, 2)].sqrt();
    let expected = dense.len().div_ceil(16_384) as f64;
    assert!((ratio / expected.sqrt() - 1.0).abs() < 0.2, "sigma ratio {ratio:.2}, expected {:.2}", expected.sqrt());
    // A sparse cloud (most entries NaN, about 5 000 valid) is not thinned.
    let sparse: Vec<[f32; 3]> =
        dense.iter().enumerate().map(|(k, p)| if k % 15 == 0 { *p } else { [f32::NAN; 3] }).collect();
    assert_eq!(fit_wall_plane(&sparse, &PlaneParams::default()), fit_wall_plane(&sparse, &every(&sparse)));
    let bad = PlaneParams { max_points: 100, ..Default::default() };
    assert!(matches!(fit_wall_plane(&dense, &bad), Err(PlaneError::InvalidParams(e)) if e.contains("max_points")));
}
