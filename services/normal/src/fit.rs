//! The wall plane: MSAC on a sample, local refinement and noise scale on the
//! sample, then Newton steps of a Tukey-biweight M-estimate on every point, and
//! the sandwich covariance of that estimate.

use crate::moments::{Moments, NewtonSums, Weighting, newton_sums, reweighted_moments};
use crate::params::PlaneParams;
use crate::rng::SplitMix64;
use nalgebra::{Matrix3, Matrix3x4, Point3, Unit, Vector3, Vector4};
use serde::{Deserialize, Serialize};

/// The wall as fitted: `normal · X = distance_m` in the camera frame (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WallPlane {
    /// Unit normal in the camera frame, pointing away from the camera (into the
    /// wall), so that `distance_m >= 0` (zero only for a plane through the camera
    /// centre, seen edge on: no wall).
    pub normal: Unit<Vector3<f64>>,
    /// Distance of the plane from the camera centre (metres): `normal · X = distance_m`.
    pub distance_m: f64,
    /// Covariance of `(δa, δb, δd)` (rad², rad·m, m²) where the normal is
    /// perturbed as `normalize(normal + δa·tangent[0] + δb·tangent[1])` and the
    /// distance as `distance_m + δd`. The sandwich covariance of the M-estimate:
    /// it scales with the residuals actually seen, so it stays honest when the
    /// noise differs from the model. It assumes independent point errors.
    pub covariance: Matrix3<f64>,
    /// Two unit vectors in the plane, `(tangent[0], tangent[1], normal)` right-handed.
    pub tangent: [Vector3<f64>; 2],
    /// Points within the inlier band of the final plane (of the whole cloud: counted
    /// in the points fitted, scaled back where the cloud was thinned).
    pub inliers: usize,
    /// RMS plane residual of the inliers (metres).
    pub rms_m: f64,
}

impl WallPlane {
    /// Signed distance of `p` (camera frame, metres) from the plane: positive
    /// behind the wall surface, negative in front of it (on the camera's side).
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.distance_m
    }

    /// Standard deviation (metres) of the plane's position along its normal at
    /// the point `p` (camera frame, metres), e.g. at the outlet: the distance
    /// error at the camera centre combined with the tilt's lever arm.
    pub fn signed_distance_sigma_m(&self, p: &Point3<f64>) -> f64 {
        let j = Vector3::new(self.tangent[0].dot(&p.coords), self.tangent[1].dot(&p.coords), -1.0);
        (j.transpose() * self.covariance * j)[0].max(0.0).sqrt()
    }

    /// The plane as the JSON record of `CONTRACT.md`.
    pub fn to_plane_json(&self) -> outlet_protocol::truth::PlaneJson {
        outlet_protocol::truth::PlaneJson { normal: self.normal.into_inner().into(), distance_m: self.distance_m }
    }
}

/// Why no wall plane could be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlaneError {
    #[error(
        "too few valid points: {valid} finite points in front of the camera (and inside the region of interest), \
         {needed} needed"
    )]
    TooFewPoints { valid: usize, needed: usize },
    #[error(
        "no dominant plane: the best plane holds {best_inliers} of {valid} valid points, fewer than \
         min_inlier_fraction asks (points scattered, collinear, or far noisier than the stereo model)"
    )]
    NoDominantPlane { best_inliers: usize, valid: usize },
    #[error("invalid plane parameters: {0}")]
    InvalidParams(String),
}

/// A unit-normal plane `n · X = d` with `d >= 0` (camera frame, metres).
#[derive(Debug, Clone, Copy)]
struct Plane {
    n: Vector3<f64>,
    d: f64,
}

impl Plane {
    /// Oriented away from the camera.
    fn oriented(n: Vector3<f64>, d: f64) -> Self {
        if d < 0.0 { Self { n: -n, d: -d } } else { Self { n, d } }
    }
    fn is_finite(&self) -> bool {
        self.n.iter().all(|v| v.is_finite()) && self.d.is_finite()
    }

    /// The weighting of a pass about `origin`: residual sigma `kappa · z`,
    /// Tukey's constant `c`.
    fn weighting(&self, origin: &Vector3<f64>, kappa: f64, c: f64) -> Weighting {
        Weighting { origin: *origin, n: self.n, dc: self.d - self.n.dot(origin), kappa, c }
    }
}

/// Walls closer than this to the camera centre are treated as this far when
/// scaling the noise (metres): it keeps the noise model away from zero.
const MIN_NOISE_DISTANCE_M: f64 = 1e-3;
/// The refinement stops after a Newton step shorter than this, in the plane's
/// own standard deviations (Mahalanobis length): the error left after such a
/// step is far smaller (a step of 0.14 leaves 1e-6 on a rendered cloud).
const STEP_TOLERANCE_SIGMAS: f64 = 0.5;
/// The Newton Hessian's least curvature relative to the reweighting's normal
/// matrix. With Gaussian noise it is `E ψ' / E w`: 0.53 at c = 2.5 sigmas (no
/// damping), 0.19 when the noise is twice the band's assumption.
const MIN_RELATIVE_CURVATURE: f64 = 0.25;
/// Most reweighting steps on the sample per noise-scale round.
const MAX_LOCAL_ITERATIONS: usize = 25;
/// Reweighting on the sample stops after a step shorter than this (in the
/// metric of its normal matrix, about the sample's standard deviations).
const LOCAL_TOLERANCE_SIGMAS: f64 = 0.05;
/// Median of the absolute value of a standard normal variable.
const HALF_NORMAL_MEDIAN: f64 = 0.674_489_750_196_08;

pub use outlet_protocol::math::tangent_basis;

/// Fits the dominant plane of a stereo cloud (camera frame, metres): the wall.
///
/// Points that are not finite, lie at `z <= 0`, or fall outside the region of
/// interest are ignored. The stages:
/// 1. MSAC (truncated quadratic cost in model sigmas) on a random sample of
///    [`PlaneParams::sample_size`] points, stopping adaptively;
/// 2. Tukey-reweighted least squares on the sample from the best hypothesis,
///    and the noise scale from the residuals behind the wall (twice);
/// 3. Newton steps of the same M-estimate over every point, weights
///    `1 / sigma_r²` (see [`PlaneParams`]), until a step is shorter than half
///    the plane's standard deviation (two passes as a rule, at most
///    [`PlaneParams::max_refine_iterations`]); the last pass gives the inliers,
///    the RMS and the sandwich covariance.
///
/// Never panics and never returns a non-finite value.
pub fn fit_wall_plane(points: &[[f32; 3]], params: &PlaneParams) -> Result<WallPlane, PlaneError> {
    params.validate().map_err(PlaneError::InvalidParams)?;
    let thinned: Vec<[f32; 3]>;
    // Thinned among the valid points: a sparse cloud (most entries NaN) keeps them all.
    let all_valid = points.iter().filter(|p| is_valid(p)).count();
    let stride = all_valid.div_ceil(params.max_points);
    let points = if stride > 1 {
        thinned = points.iter().filter(|p| is_valid(p)).step_by(stride).copied().collect();
        &thinned[..]
    } else {
        points
    };
    let mut rng = SplitMix64::new(params.seed);
    let Cloud { points, valid, sample } = Cloud::new(points, params, &mut rng);
    if valid < params.min_points {
        return Err(PlaneError::TooFewPoints { valid, needed: params.min_points });
    }
    // Counts are reported for the whole cloud, thinned or not.
    let whole = |n: usize| if valid == 0 { n } else { (n as f64 * all_valid as f64 / valid as f64).round() as usize };
    let no_plane = |best_inliers| PlaneError::NoDominantPlane { best_inliers: whole(best_inliers), valid: all_valid };
    // Every sum is taken about this point, so that the f64 moments keep their digits.
    let origin = sample.iter().fold(Vector3::zeros(), |s, p| s + to_vector(p)) / sample.len() as f64;
    if !origin.iter().all(|v| v.is_finite()) {
        return Err(no_plane(0));
    }

    let Some(mut plane) = msac(&sample, &origin, params, &mut rng) else {
        return Err(no_plane(0));
    };
    let c = params.inlier_sigmas;
    let mut scale = 1.0;
    let rounds = if params.estimate_noise_scale { 3 } else { 1 };
    for round in 0..rounds {
        // Reweighting converges linearly (by about 0.47 a step at c = 2.5, slower
        // when the noise is larger than assumed): iterate until the step is small
        // against the sample's own precision.
        for _ in 0..MAX_LOCAL_ITERATIONS {
            let weighting = plane.weighting(&origin, noise_kappa(params, &plane, scale), c);
            let (moments, inliers) = reweighted_moments(&sample, &weighting);
            // Inliers of the sample, counted as a share of every valid point.
            let share = inliers * valid / sample.len();
            let (next, moved2) = gauss_newton_step(&moments, &plane, &origin).ok_or_else(|| no_plane(share))?;
            plane = next;
            if moved2 < LOCAL_TOLERANCE_SIGMAS * LOCAL_TOLERANCE_SIGMAS {
                break;
            }
        }
        if round + 1 < rounds {
            scale = estimate_noise_scale(&sample, &origin, &plane, params).unwrap_or(scale);
        }
    }

    // Newton steps of the M-estimate on every point. Reweighting alone would
    // contract the error by only about 0.47 a pass (Tukey, c = 2.5) and leave the
    // sample's scatter in the result; Newton's steps shrink it quadratically (on a
    // rendered cloud: 28, then 0.14, then 1e-6 standard deviations). The pass whose
    // step is below STEP_TOLERANCE_SIGMAS gives the inliers, the RMS and the
    // covariance; its step is still taken.
    let mut passes = 0;
    let (sums, covariance) = loop {
        let weighting = plane.weighting(&origin, noise_kappa(params, &plane, scale), c);
        passes += 1;
        // The first pass over a large cloud starts from the sample's plane, many
        // of its own standard deviations away: it cannot be the last.
        let last_possible = passes > 1 || valid <= params.sample_size || passes >= params.max_refine_iterations;
        let sums = newton_sums(&points, &weighting, last_possible);
        if sums.inliers < 4 || (sums.inliers as f64) < params.min_inlier_fraction * valid as f64 {
            return Err(no_plane(sums.inliers));
        }
        let tangent = tangent_basis(&plane.n);
        let t = tangent_jacobian(&tangent, &origin);
        let covariance = match last_possible {
            true => Some(sandwich_covariance(&sums, &t).ok_or_else(|| no_plane(sums.inliers))?),
            false => None,
        };
        // The reweighting's normal matrix, from the sample, scaled to every point:
        // the floor of the Newton step's curvature.
        let (moments, sample_inliers) = reweighted_moments(&sample, &weighting);
        let reweighted = t * moments.matrix() * t.transpose() * (sums.inliers as f64 / sample_inliers.max(1) as f64);
        let step = newton_step(&sums, &t, &reweighted).ok_or_else(|| no_plane(sums.inliers))?;
        plane = apply_step(&plane, &tangent, &step).ok_or_else(|| no_plane(sums.inliers))?;
        if let Some(covariance) = covariance {
            let converged = covariance
                .try_inverse()
                .is_some_and(|info| step.dot(&(info * step)) < STEP_TOLERANCE_SIGMAS * STEP_TOLERANCE_SIGMAS);
            if converged || passes >= params.max_refine_iterations {
                break (sums, covariance);
            }
        }
    };
    // The last step turned the normal by a fraction of its standard deviation:
    // the covariance holds in the new tangent basis to that fraction squared.
    let tangent = tangent_basis(&plane.n);
    let inliers = sums.inliers;
    let rms_m = (sums.r2 / inliers as f64).sqrt();

    let out = WallPlane {
        normal: Unit::new_unchecked(plane.n),
        distance_m: plane.d,
        covariance,
        tangent,
        inliers: whole(inliers),
        rms_m,
    };
    let finite = plane.is_finite()
        && covariance.iter().all(|v| v.is_finite())
        && (0..3).all(|i| covariance[(i, i)] >= 0.0)
        && tangent.iter().all(|e| e.iter().all(|v| v.is_finite()))
        && rms_m.is_finite();
    if finite { Ok(out) } else { Err(no_plane(inliers)) }
}

fn to_vector(p: &[f32; 3]) -> Vector3<f64> {
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

fn is_valid(p: &[f32; 3]) -> bool {
    p[0].is_finite() && p[1].is_finite() && p[2].is_finite() && p[2] > 0.0
}

/// The points the fit runs on, and the sample that MSAC scores.
struct Cloud<'a> {
    /// Every input point, or only the valid ones; the passes skip invalid points.
    points: std::borrow::Cow<'a, [[f32; 3]]>,
    valid: usize,
    sample: Vec<[f32; 3]>,
}

impl<'a> Cloud<'a> {
    fn new(points: &'a [[f32; 3]], params: &PlaneParams, rng: &mut SplitMix64) -> Self {
        use std::borrow::Cow;
        let points: Cow<'a, [[f32; 3]]> = match params.roi {
            None => Cow::Borrowed(points),
            Some((centre, radius)) => {
                let r2 = radius * radius;
                let inside = |p: &[f32; 3]| is_valid(p) && (to_vector(p) - centre.coords).norm_squared() <= r2;
                Cow::Owned(points.iter().filter(|p| inside(p)).copied().collect())
            }
        };
        let valid = points.iter().filter(|p| is_valid(p)).count();
        let sample = if valid <= params.sample_size || valid * 4 < points.len() {
            // Few valid points, or too few for drawing by rejection: draw from a copy.
            let compact: Vec<[f32; 3]> = points.iter().filter(|p| is_valid(p)).copied().collect();
            if valid <= params.sample_size {
                return Self { points: Cow::Owned(compact.clone()), valid, sample: compact };
            }
            (0..params.sample_size).map(|_| compact[rng.below(valid)]).collect()
        } else {
            // At least a quarter of the points are valid: draw by rejection.
            let mut sample = Vec::with_capacity(params.sample_size);
            while sample.len() < params.sample_size {
                let p = points[rng.below(points.len())];
                if is_valid(&p) {
                    sample.push(p);
                }
            }
            sample
        };
        Self { points, valid, sample }
    }
}

/// `kappa` such that a point at depth `z` has residual sigma `kappa · z`.
fn noise_kappa(params: &PlaneParams, plane: &Plane, scale: f64) -> f64 {
    scale * params.sigma_at_1m * plane.d.max(MIN_NOISE_DISTANCE_M)
}

/// Best hypothesis by the MSAC cost `Σ min(u², k²)`, `u` the residual in model
/// sigmas, scored on the sample; `None` when every triple drawn was degenerate.
fn msac(sample: &[[f32; 3]], origin: &Vector3<f64>, params: &PlaneParams, rng: &mut SplitMix64) -> Option<Plane> {
    let centred: Vec<[f64; 4]> = sample
        .iter()
        .map(|p| {
            let z = p[2] as f64;
            [p[0] as f64 - origin.x, p[1] as f64 - origin.y, z - origin.z, 1.0 / (z * z)]
        })
        .collect();
    let m = centred.len();
    let k2 = params.msac_threshold_sigmas * params.msac_threshold_sigmas;
    let log_miss = (1.0 - params.confidence).ln();
    let mut needed = params.max_iterations;
    let mut best: Option<(Plane, f64)> = None;
    let mut iteration = 0;
    while iteration < needed.min(params.max_iterations) {
        iteration += 1;
        let (i, j, l) = (rng.below(m), rng.below(m), rng.below(m));
        if i == j || j == l || i == l {
            continue;
        }
        let v = |k: usize| Vector3::new(centred[k][0], centred[k][1], centred[k][2]);
        let (a, ab, ac) = (v(i), v(j) - v(i), v(l) - v(i));
        let cross = ab.cross(&ac);
        let norm = cross.norm();
        // Nearly collinear (or NaN) triples give no plane.
        let sound = norm > 1e-6 * ab.norm() * ac.norm();
        if !sound {
            continue;
        }
        let n = cross / norm;
        let dc = n.dot(&a);
        let plane = Plane::oriented(n, dc + n.dot(origin));
        let n = plane.n;
        let dc = plane.d - n.dot(origin);
        let kappa = params.sigma_at_1m * plane.d.max(MIN_NOISE_DISTANCE_M);
        let inv_kappa2 = 1.0 / (kappa * kappa);
        let bound = best.map_or(f64::INFINITY, |(_, cost)| cost);
        let (mut cost, mut inliers) = (0.0, 0usize);
        for chunk in centred.chunks(64) {
            for q in chunk {
                let r = n.x * q[0] + n.y * q[1] + n.z * q[2] - dc;
                let u2 = r * r * q[3] * inv_kappa2;
                if u2 < k2 {
                    cost += u2;
                    inliers += 1;
                } else {
                    cost += k2;
                }
            }
            if cost >= bound {
                break;
            }
        }
        if cost < bound && cost.is_finite() {
            best = Some((plane, cost));
            let w = inliers as f64 / m as f64;
            let miss = 1.0 - w * w * w;
            needed = if miss <= 0.0 {
                0
            } else if miss >= 1.0 {
                params.max_iterations
            } else {
                ((log_miss / miss.ln()).ceil() as usize).max(1)
            };
        }
    }
    best.map(|(plane, _)| plane)
}

/// The noise scale factor from the residuals behind the wall, where only wall
/// points (and rare outliers) lie: their median in model sigmas over the median
/// of a half-normal variable, iterated with a window of 6 estimated sigmas.
fn estimate_noise_scale(
    sample: &[[f32; 3]],
    origin: &Vector3<f64>,
    plane: &Plane,
    params: &PlaneParams,
) -> Option<f64> {
    let kappa = noise_kappa(params, plane, 1.0);
    let dc = plane.d - plane.n.dot(origin);
    let behind: Vec<f64> = sample
        .iter()
        .filter_map(|p| {
            let z = p[2] as f64;
            let r = plane.n.x * (p[0] as f64 - origin.x)
                + plane.n.y * (p[1] as f64 - origin.y)
                + plane.n.z * (z - origin.z)
                - dc;
            let u = r / (kappa * z);
            (u > 0.0 && u.is_finite()).then_some(u)
        })
        .collect();
    let (lo, hi) = PlaneParams::NOISE_SCALE_RANGE;
    let mut scale = None;
    let mut window = 20.0;
    for _ in 0..4 {
        let mut inside: Vec<f64> = behind.iter().copied().filter(|&u| u < window).collect();
        if inside.len() < 8 {
            break;
        }
        let mid = inside.len() / 2;
        let (_, median, _) = inside.select_nth_unstable_by(mid, f64::total_cmp);
        let s = (*median / HALF_NORMAL_MEDIAN).clamp(lo, hi);
        scale = Some(s);
        window = 6.0 * s;
    }
    scale
}

/// Rows `(e1; e2; -e3)` of the map from centred homogeneous points `[X - o; 1]`
/// to the Jacobian of the residual in `(δa, δb, δd)`.
fn tangent_jacobian(tangent: &[Vector3<f64>; 2], origin: &Vector3<f64>) -> Matrix3x4<f64> {
    let [e1, e2] = tangent;
    Matrix3x4::new(
        e1.x,
        e1.y,
        e1.z,
        e1.dot(origin), //
        e2.x,
        e2.y,
        e2.z,
        e2.dot(origin), //
        0.0,
        0.0,
        0.0,
        -1.0,
    )
}

/// The reweighted Gauss-Newton step from the moments of a pass, taken, and its
/// squared length in the metric of the normal matrix.
fn gauss_newton_step(moments: &Moments, plane: &Plane, origin: &Vector3<f64>) -> Option<(Plane, f64)> {
    let tangent = tangent_basis(&plane.n);
    let t = tangent_jacobian(&tangent, origin);
    let m = moments.matrix();
    let h = Vector4::new(plane.n.x, plane.n.y, plane.n.z, -(plane.d - plane.n.dot(origin)));
    let normal_matrix = t * m * t.transpose();
    let step = -normal_matrix.cholesky()?.solve(&(t * (m * h)));
    let moved2 = step.dot(&(normal_matrix * step));
    Some((apply_step(plane, &tangent, &step)?, moved2))
}

/// The Newton step in `(δa, δb, δd)` of the M-estimate, its Hessian (from `ψ'`)
/// raised where needed to [`MIN_RELATIVE_CURVATURE`] times the reweighting's
/// normal matrix `reweighted` (Levenberg-Marquardt style): where the noise is
/// much larger than the band, `ψ'` nearly vanishes on average and a pure Newton
/// step from a poor start can run away.
fn newton_step(sums: &NewtonSums, t: &Matrix3x4<f64>, reweighted: &Matrix3<f64>) -> Option<Vector3<f64>> {
    let hessian = t * sums.a.matrix() * t.transpose();
    let gradient = t * sums.gradient;
    let floor = reweighted.cholesky()?.l().try_inverse()?;
    let relative = floor * hessian * floor.transpose();
    let least = relative.symmetric_eigenvalues().min();
    let damping = (MIN_RELATIVE_CURVATURE - least).max(0.0);
    let step = -(hessian + reweighted * damping).cholesky()?.solve(&gradient);
    step.iter().all(|v| v.is_finite()).then_some(step)
}

/// The sandwich covariance `A⁻¹ B A⁻¹` of the M-estimate in `(δa, δb, δd)`,
/// with the small-sample factor `n / (n - 3)`.
fn sandwich_covariance(sums: &NewtonSums, t: &Matrix3x4<f64>) -> Option<Matrix3<f64>> {
    let a = t * sums.a.matrix() * t.transpose();
    let b = t * sums.b.matrix() * t.transpose();
    let a_inv = a.try_inverse()?;
    let n = sums.inliers as f64;
    let covariance = a_inv * b * a_inv * (n / (n - 3.0));
    let covariance = (covariance + covariance.transpose()) * 0.5;
    let sound = covariance.iter().all(|v| v.is_finite()) && (0..3).all(|i| covariance[(i, i)] >= 0.0);
    sound.then_some(covariance)
}

fn apply_step(plane: &Plane, tangent: &[Vector3<f64>; 2], step: &Vector3<f64>) -> Option<Plane> {
    let n = (plane.n + tangent[0] * step[0] + tangent[1] * step[1]).try_normalize(1e-12)?;
    let next = Plane::oriented(n, plane.d + step[2]);
    next.is_finite().then_some(next)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangent_basis_is_orthonormal_and_right_handed() {
        for n in [Vector3::z(), Vector3::x(), Vector3::new(0.3, -0.5, 0.8).normalize(), -Vector3::y()] {
            let [e1, e2] = tangent_basis(&n);
            assert!((e1.norm() - 1.0).abs() < 1e-12 && (e2.norm() - 1.0).abs() < 1e-12);
            assert!(e1.dot(&n).abs() < 1e-12 && e2.dot(&n).abs() < 1e-12 && e1.dot(&e2).abs() < 1e-12);
            assert!((e1.cross(&e2) - n).norm() < 1e-12);
        }
    }

    #[test]
    fn a_gauss_newton_step_from_a_nearby_plane_lands_on_the_exact_plane() {
        let truth = Plane::oriented(Vector3::new(0.1, -0.2, 1.0).normalize(), 0.4);
        let [e1, e2] = tangent_basis(&truth.n);
        let points: Vec<[f32; 3]> = (0..400)
            .map(|i| {
                let (s, t) = ((i % 20) as f64 * 0.01 - 0.1, (i / 20) as f64 * 0.01 - 0.1);
                let p = truth.n * truth.d + e1 * s + e2 * t;
                [p.x as f32, p.y as f32, p.z as f32]
            })
            .collect();
        let origin = Vector3::new(0.0, 0.0, 0.4);
        let start = Plane::oriented((truth.n + e1 * 0.01).normalize(), 0.401);
        let mut plane = start;
        for _ in 0..3 {
            let (moments, _) = reweighted_moments(&points, &plane.weighting(&origin, 1e-3, 1e6));
            plane = gauss_newton_step(&moments, &plane, &origin).expect("step").0;
        }
        assert!((plane.n - truth.n).norm() < 1e-6, "{:?}", plane.n);
        assert!((plane.d - truth.d).abs() < 1e-7);
    }

    #[test]
    fn the_plane_faces_away_from_the_camera() {
        let p = Plane::oriented(-Vector3::z(), -0.3);
        assert_eq!(p.n, Vector3::z());
        assert_eq!(p.d, 0.3);
    }
}
