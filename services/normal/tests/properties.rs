//! Properties of the wall-plane fit over random walls (proptest):
//! - a rigid motion of the cloud moves the fitted plane with it;
//! - the fit does not depend on the order of the points;
//! - outliers below the breakdown fraction do not move it.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use outlet_normal::{PlaneParams, WallPlane, fit_wall_plane};
use proptest::prelude::*;

/// Depth noise at 1 m of the reference stereo camera (0.15 px, 9 cm, 525 px).
const SIGMA_AT_1M: f64 = 0.15 / (525.0 * 0.09);
/// The image grid the clouds are seen on (every pixel of a camera this size).
const WIDTH: usize = 128;
const HEIGHT: usize = 96;

/// SplitMix64: the tests' own randomness, seeded by proptest.
struct Rng(rand_xoshiro::SplitMix64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(rand_xoshiro::rand_core::SeedableRng::seed_from_u64(seed))
    }
    fn unit(&mut self) -> f64 {
        (rand_xoshiro::rand_core::Rng::next_u64(&mut self.0) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (a, b) = (self.unit().max(1e-300), self.unit());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.unit() * n as f64) as usize).min(n - 1)
    }
}

/// A wall `normal · X = distance_m` (camera frame).
#[derive(Debug, Clone, Copy)]
struct Wall {
    normal: Vector3<f64>,
    distance_m: f64,
}

impl Wall {
    /// The wall after a rigid motion of the scene.
    fn moved(&self, motion: &Isometry3<f64>) -> Wall {
        let normal = motion.rotation * self.normal;
        let on_wall = motion * Point3::from(self.normal * self.distance_m);
        Wall { normal, distance_m: normal.dot(&on_wall.coords) }
    }

    /// The wall as seen on every pixel of a `WIDTH` x `HEIGHT` camera (f = 525 px
    /// at 640 wide), each point slid along its ray by the stereo noise model
    /// times `noise_scale`.
    fn cloud(&self, noise_scale: f64, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = Rng::new(seed);
        let f = 525.0 * WIDTH as f64 / 640.0;
        let (cx, cy) = ((WIDTH as f64 - 1.0) / 2.0, (HEIGHT as f64 - 1.0) / 2.0);
        let mut points = Vec::with_capacity(WIDTH * HEIGHT);
        for v in 0..HEIGHT {
            for u in 0..WIDTH {
                let ray = Vector3::new((u as f64 - cx) / f, (v as f64 - cy) / f, 1.0);
                let z = self.distance_m / self.normal.dot(&ray);
                let z = z * (1.0 + noise_scale * SIGMA_AT_1M * z * rng.gauss());
                let p = ray * z;
                points.push([p.x as f32, p.y as f32, p.z as f32]);
            }
        }
        points
    }
}

/// A wall 20-80 cm away, turned up to 45 degrees about the camera's x and y axes.
fn wall() -> impl Strategy<Value = Wall> {
    (0.2..0.8f64, -45.0..45f64, -45.0..45f64).prop_map(|(distance_m, ay, ax)| {
        let normal = Rotation3::from_axis_angle(&Vector3::x_axis(), ax.to_radians())
            * Rotation3::from_axis_angle(&Vector3::y_axis(), ay.to_radians())
            * Vector3::z();
        Wall { normal, distance_m }
    })
}

/// A rigid motion of the scene: a turn of up to 0.3 rad about any axis through
/// the wall's point on the optical axis, then a shift of up to 5 cm.
fn motion(wall: Wall) -> impl Strategy<Value = Isometry3<f64>> {
    let centre = Vector3::new(0.0, 0.0, wall.distance_m / wall.normal.z);
    (
        0.0..std::f64::consts::PI,
        0.0..std::f64::consts::TAU,
        0.0..0.3f64,
        [-0.05..0.05f64, -0.05..0.05f64, -0.05..0.05f64],
    )
        .prop_map(move |(polar, azimuth, angle, [dx, dy, dz])| {
            let axis = Unit::new_normalize(Vector3::new(
                polar.sin() * azimuth.cos(),
                polar.sin() * azimuth.sin(),
                polar.cos(),
            ));
            let turn = UnitQuaternion::from_axis_angle(&axis, angle);
            Isometry3::from_parts(Translation3::from(centre - turn * centre + Vector3::new(dx, dy, dz)), turn)
        })
}

/// The default parameters: the clouds here (12288 points) are larger than the
/// sample that MSAC scores (2048), so the sample is drawn at random.
fn fit(cloud: &[[f32; 3]]) -> WallPlane {
    fit_with(cloud, &PlaneParams::default())
}

fn fit_with(cloud: &[[f32; 3]], params: &PlaneParams) -> WallPlane {
    fit_wall_plane(cloud, params).unwrap_or_else(|e| panic!("no plane: {e}"))
}

/// The noise scale taken as the model's (not estimated from the random sample).
fn fixed_scale() -> PlaneParams {
    PlaneParams { estimate_noise_scale: false, ..PlaneParams::default() }
}

/// Angle between the fitted and the true normal (rad), and the distance error (m).
fn error(fitted: &WallPlane, truth: &Wall) -> (f64, f64) {
    let cos = fitted.normal.dot(&truth.normal).clamp(-1.0, 1.0);
    (cos.acos(), (fitted.distance_m - truth.distance_m).abs())
}

/// The difference of two fits in standard deviations of the first's covariance
/// (Mahalanobis length of `(δa, δb, δd)` in its tangent basis).
fn sigmas_apart(a: &WallPlane, b: &WallPlane) -> f64 {
    let delta = Vector3::new(a.tangent[0].dot(&b.normal), a.tangent[1].dot(&b.normal), b.distance_m - a.distance_m);
    let info = a.covariance.try_inverse().expect("a positive definite covariance");
    delta.dot(&(info * delta)).max(0.0).sqrt()
}

/// 64 cases, or `PROPTEST_CASES` for a longer search.
fn cases() -> u32 {
    std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(64)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), max_global_rejects: 4096, ..ProptestConfig::default() })]

    /// Moving the cloud by an isometry (the wall kept in front of the camera and
    /// not seen edge on) moves the fitted plane by the same isometry.
    #[test]
    fn rigid_motion_of_the_cloud_moves_the_plane_with_it(
        (truth, motion) in wall().prop_flat_map(|w| (Just(w), motion(w))),
        seed in any::<u64>(),
    ) {
        let cloud = truth.cloud(0.0, seed);
        let moved_cloud: Vec<[f32; 3]> = cloud
            .iter()
            .map(|p| {
                let q = motion * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                [q.x as f32, q.y as f32, q.z as f32]
            })
            .collect();
        let moved = truth.moved(&motion);
        let in_front = moved_cloud.iter().all(|p| p[2] > 0.05);
        // Not edge on: the wall faces the camera within 60 degrees at its centre.
        let centre = moved_cloud[moved_cloud.len() / 2 + WIDTH / 2];
        let sight = Vector3::new(centre[0] as f64, centre[1] as f64, centre[2] as f64).normalize();
        if !in_front || moved.normal.dot(&sight).abs() < 0.5 {
            return Err(TestCaseError::reject("wall behind the camera or edge on"));
        }
        let (before, after) = (fit(&cloud), fit(&moved_cloud));
        // The fit orients its normal into the wall (distance >= 0).
        let expected = if moved.distance_m < 0.0 {
            Wall { normal: -moved.normal, distance_m: -moved.distance_m }
        } else {
            moved
        };
        let carried = Wall { normal: motion.rotation * before.normal.into_inner(), ..expected };
        let (angle, _) = error(&after, &carried);
        prop_assert!(angle < 1e-6, "normal {angle:e} rad from the moved fit");
        let (angle, distance) = error(&after, &expected);
        prop_assert!(angle < 1e-6 && distance < 1e-6, "moved fit {angle:e} rad, {distance:e} m off");
        let (angle, distance) = error(&before, &truth);
        prop_assert!(angle < 1e-6 && distance < 1e-6, "fit {angle:e} rad, {distance:e} m off");
    }

    /// A noisy cloud and the same points shuffled give the same plane: to 0.01
    /// of its standard deviation with the model's noise scale; within its
    /// standard deviation when the scale is estimated, since the scale comes from
    /// a random sample of the points, drawn by index (measured: up to 0.53 sigma
    /// over 400 walls of 12288 points with the default 2048-point sample).
    #[test]
    fn the_fit_does_not_depend_on_the_order_of_the_points(
        truth in wall(),
        seed in any::<u64>(),
        shuffle_seed in any::<u64>(),
    ) {
        let cloud = truth.cloud(1.0, seed);
        let mut shuffled = cloud.clone();
        let mut rng = Rng::new(shuffle_seed);
        for i in (1..shuffled.len()).rev() {
            shuffled.swap(i, rng.below(i + 1));
        }
        let (a, b) = (fit_with(&cloud, &fixed_scale()), fit_with(&shuffled, &fixed_scale()));
        let apart = sigmas_apart(&a, &b);
        prop_assert!(apart < 0.01, "model noise scale: {apart} sigmas apart:\n{a:?}\n{b:?}");
        // Points on the edge of the inlier band may fall either side.
        prop_assert!(a.inliers.abs_diff(b.inliers) <= 2 + a.inliers / 1000, "{} vs {} inliers", a.inliers, b.inliers);
        let (a, b) = (fit(&cloud), fit(&shuffled));
        let apart = sigmas_apart(&a, &b);
        prop_assert!(apart < 1.0, "estimated noise scale: {apart} sigmas apart:\n{a:?}\n{b:?}");
    }

    /// Up to 45% of the points replaced by outliers (depth off by 3-50%, in front
    /// or behind): the plane stays where the wall is. Noise-free walls are fitted
    /// exactly; noisy ones within half a standard deviation of the fit on the
    /// same wall points without the outliers (model noise scale, so that only the
    /// outliers differ between the two; measured over 745 walls: median 1e-6,
    /// 99th percentile 0.09, largest 0.32 sigma).
    #[test]
    fn outliers_below_the_breakdown_fraction_do_not_move_the_plane(
        truth in wall(),
        fraction in 0.0..0.45f64,
        noisy in any::<bool>(),
        seed in any::<u64>(),
    ) {
        let noise_scale = if noisy { 1.0 } else { 0.0 };
        let clean = truth.cloud(noise_scale, seed);
        let mut damaged = clean.clone();
        let mut kept = Vec::with_capacity(clean.len());
        let mut rng = Rng::new(seed ^ 0x5EED);
        for p in damaged.iter_mut() {
            if rng.unit() < fraction {
                let off = 0.03 + 0.47 * rng.unit();
                let factor = if rng.unit() < 0.5 { 1.0 - off } else { 1.0 + off };
                *p = p.map(|v| (v as f64 * factor) as f32);
            } else {
                kept.push(*p);
            }
        }
        if noisy {
            let with_outliers = fit_with(&damaged, &fixed_scale());
            // The same wall points without the outliers.
            let reference = fit_with(&kept, &fixed_scale());
            let apart = sigmas_apart(&reference, &with_outliers);
            prop_assert!(apart < 0.5, "{apart} sigmas from the fit without outliers");
        } else {
            let with_outliers = fit(&damaged);
            let (angle, distance) = error(&with_outliers, &truth);
            prop_assert!(angle < 1e-6 && distance < 1e-6, "{angle:e} rad, {distance:e} m off");
        }
    }
}
