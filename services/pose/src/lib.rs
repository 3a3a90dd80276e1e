//! Hole positions in the camera frame from detected hole pixels (paper section V
//! and beyond).
//!
//! - [`solve_normal`]: the paper's closed form with the wall normal as a hard
//!   constraint, minimising the residual in the object plane (equations 11-17).
//! - [`solve_plane`]: normal and distance of the wall from stereo, then a maximum
//!   likelihood refinement of the reprojection error with the plane as a prior
//!   weighted by its covariance.
//! - [`solve_mono`]: planar PnP from pixels alone (homography decomposition, both
//!   mirror solutions refined by Levenberg-Marquardt, the better kept).
//!
//! Every solution carries a 3x3 covariance per hole (camera frame, m²), from the
//! pixel noise of the detector and the covariance of the plane.
//!
//! Frames: the camera frame of REP 103 (x right, y down, z forward, metres); the
//! outlet frame of `CONTRACT.md` (holes on the face plane z = 0, z into the wall).

mod closed_form;
mod lm;
mod mono;
mod robust;

pub use robust::{COMMON_REFERENCE_PX_PER_MM, COMMON_SCALE_SHARE, COMMON_SIGMA_FRACTION, OUTLIER_CHI2};

pub use closed_form::closed_form_normal;

use nalgebra::{Isometry3, Matrix2, Matrix3, Point2, Point3, Unit, Vector2, Vector3};
use outlet_protocol::CameraModel;
use serde::{Deserialize, Serialize};

/// What a pose was computed from (the `mode` of `CONTRACT.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    Mono,
    Normal,
    Plane,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Mono => "mono",
            Mode::Normal => "normal",
            Mode::Plane => "plane",
        }
    }
}

/// Why no pose could be computed.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum PoseError {
    #[error("{got} holes given, {needed} needed for the {mode} pose")]
    TooFewHoles { got: usize, needed: usize, mode: &'static str },
    #[error("{model} model holes but {pixels} pixels")]
    CountMismatch { model: usize, pixels: usize },
    #[error("hole {index} has a non-finite pixel or model position")]
    NonFinite { index: usize },
    #[error("the wall normal is not finite or is zero")]
    BadNormal,
    #[error("the wall normal is {angle_deg:.1} degrees from the line of sight: nearly parallel to the image plane")]
    GrazingNormal { angle_deg: f64 },
    #[error("the holes are collinear (or coincide): the pose is not determined")]
    Collinear,
    #[error("the plane is not finite, or its covariance is not positive definite")]
    BadPlane,
    #[error("the pixel noise must be finite and positive, got {0}")]
    BadSigma(f64),
    #[error("no pose puts the outlet in front of the camera")]
    BehindCamera,
    #[error(
        "two poses explain the pixels almost equally (costs {best_cost:.1} and {other_cost:.1}): \
         ambiguous, the outlet is too small or seen too squarely"
    )]
    Ambiguous { best_cost: f64, other_cost: f64 },
    #[error(
        "the holes put their plane {chi2:.1} (chi-square, 3 degrees of freedom) from the stereo plane's \
         measurement: not the outlet's wall, or a wrong hole"
    )]
    PlaneDisagrees { chi2: f64 },
}

/// The most a plane-mode fit may leave in the plane's own residual (whitened
/// normal and distance, chi-square with 3 degrees of freedom; 21.1 is its
/// 99.99% point). The plane is a prior, not a hard constraint: with honest
/// error bars on a real stereo plane (millimetres, tenths of a degree) the
/// pixels could otherwise pull the outlet onto a wall 5 cm away and still
/// fit, so a pose that moves that far from the plane is refused instead.
pub const MAX_PLANE_DISAGREEMENT: f64 = 21.1;

/// The holes as detected: model positions and image pixels.
#[derive(Debug, Clone, Copy)]
pub struct Observations<'a> {
    /// Hole centres in the outlet frame on the face plane (mm).
    pub model_mm: &'a [Point2<f64>],
    /// The same holes in the image as captured (distorted pixels).
    pub pixels: &'a [Point2<f64>],
    pub camera: &'a CameraModel,
    /// Standard deviation of a hole's pixel, each axis (pixels): the default for
    /// holes without one of their own in `pixel_sigmas`.
    pub pixel_sigma: f64,
    /// Each hole's pixel standard deviation (pixels), as the detector's
    /// sub-pixel fit measured it: the whole of the hole's error, of which the
    /// pose takes [`OWN_NOISE_SHARE`] as independent noise and the rest as a
    /// shift and scale common to every hole. An entry that is missing, not
    /// finite or not positive falls back to `pixel_sigma`.
    pub pixel_sigmas: Option<&'a [f64]>,
    /// How each hole's pixel variance divides among the image axes: symmetric,
    /// trace 2, the identity for the same on both (the detector's
    /// `DetectedHole::shape`); hole k's pixel covariance is `sigma_of(k)² ·
    /// shape`. A missing or unusable entry (not finite, not positive definite)
    /// is the identity.
    pub pixel_shapes: Option<&'a [Matrix2<f64>]>,
}

impl<'a> Observations<'a> {
    /// Holes that share one pixel sigma and a round covariance: what a caller
    /// without the detector's per-hole fit (a hand-labelled image, a test) has.
    pub fn uniform(
        model_mm: &'a [Point2<f64>],
        pixels: &'a [Point2<f64>],
        camera: &'a CameraModel,
        pixel_sigma: f64,
    ) -> Self {
        Self { model_mm, pixels, camera, pixel_sigma, pixel_sigmas: None, pixel_shapes: None }
    }

    /// The pixel standard deviation of hole `index` (pixels).
    pub fn sigma_of(&self, index: usize) -> f64 {
        self.pixel_sigmas
            .and_then(|s| s.get(index).copied())
            .filter(|s| s.is_finite() && *s > 0.0)
            .unwrap_or(self.pixel_sigma)
    }

    /// The pixel covariance's shape of hole `index` (trace 2).
    pub fn shape_of(&self, index: usize) -> Matrix2<f64> {
        self.pixel_shapes
            .and_then(|s| s.get(index).copied())
            .map(|s| (s + s.transpose()) * 0.5)
            .filter(|s| s.iter().all(|v| v.is_finite()) && s.trace() > 0.0 && s.determinant() > 0.0 && s[(0, 0)] > 0.0)
            .map(|s| s * (2.0 / s.trace()))
            .unwrap_or_else(Matrix2::identity)
    }
}

/// The wall as stereo measured it: `normal · X = distance_m` in the camera frame,
/// with the covariance of `(δa, δb, δd)` where the normal is perturbed as
/// `normalize(normal + δa·tangent[0] + δb·tangent[1])`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneMeasurement {
    pub normal: Unit<Vector3<f64>>,
    pub distance_m: f64,
    pub covariance: Matrix3<f64>,
    pub tangent: [Vector3<f64>; 2],
    /// How far the receptacle face stands ahead of the wall (m): the holes' plane
    /// is the wall moved this far towards the camera.
    pub face_offset_m: f64,
}

impl PlaneMeasurement {
    /// A plane with an isotropic uncertainty: `sigma_rad` on the normal's
    /// direction, `sigma_m` on the distance.
    pub fn new(normal: Vector3<f64>, distance_m: f64, sigma_rad: f64, sigma_m: f64, face_offset_m: f64) -> Self {
        let normal = Unit::new_normalize(normal);
        let tangent = tangent_basis(&normal);
        let covariance = Matrix3::from_diagonal(&Vector3::new(sigma_rad.powi(2), sigma_rad.powi(2), sigma_m.powi(2)));
        Self { normal, distance_m, covariance, tangent, face_offset_m }
    }

    /// The same plane with what its fit cannot know added to its covariance:
    /// how far a real receptacle face stands from the nominal `face_offset_m`
    /// (`face_offset_sigma_m`: it moves the holes' plane as a distance error
    /// does), and a calibration bias of the stereo pair on the normal
    /// (`tilt_sigma_rad`) and the distance (`distance_sigma_m`). Zero adds
    /// nothing.
    pub fn with_model_error(self, face_offset_sigma_m: f64, tilt_sigma_rad: f64, distance_sigma_m: f64) -> Self {
        let sq = |v: f64| if v.is_finite() { v * v } else { 0.0 };
        let extra = Matrix3::from_diagonal(&Vector3::new(
            sq(tilt_sigma_rad),
            sq(tilt_sigma_rad),
            sq(face_offset_sigma_m) + sq(distance_sigma_m),
        ));
        Self { covariance: self.covariance + extra, ..self }
    }
}

/// A solved outlet pose with its holes.
#[derive(Debug, Clone, PartialEq)]
pub struct OutletPose {
    /// Outlet frame (metres) to camera frame.
    pub pose: Isometry3<f64>,
    pub mode: Mode,
    /// Hole centres in the camera frame (metres), model order.
    pub holes_cam_m: Vec<Point3<f64>>,
    /// Covariance of each hole's position (m²).
    pub covariances: Vec<Matrix3<f64>>,
    /// RMS reprojection error of the holes that weighed (pixels): all but
    /// `outliers`.
    pub rms_px: f64,
    /// Holes (model order) whose pixels the solution could not explain and did
    /// not use; their positions and covariances come from the others through
    /// the outlet's rigid geometry.
    pub outliers: Vec<usize>,
    /// The factor (at least 1) the covariances were scaled by: the kept holes'
    /// cost per degree of freedom, where the pixels were noisier than assumed.
    pub variance_factor: f64,
}

pub use outlet_protocol::math::tangent_basis;

/// Normalised undistorted coordinates of the pixels, each with its 2x2 inverse
/// square-root covariance (whitening) from the pixel noise through the lens.
pub(crate) struct Rays {
    pub xy: Vec<Vector2<f64>>,
    pub whiten: Vec<Matrix2<f64>>,
    pub covariance: Vec<Matrix2<f64>>,
    /// Model points in metres on z = 0.
    pub model: Vec<Point3<f64>>,
    /// Each hole's pixel sigma (pixels).
    pub sigma: Vec<f64>,
    /// d xy / d pixel at each hole (through the lens).
    pub px_to_xy: Vec<Matrix2<f64>>,
    /// The share of each hole's sigma taken as its own, independent noise
    /// ([`OWN_NOISE_SHARE`]); the weights and `sigma` are the whole sigma's.
    pub share: f64,
}

/// The share of a hole's pixel sigma (as the detector reports it: the whole of
/// its error, what it shares with the other holes included) that is its own,
/// independent noise; the shared part is the common shift and scale. The pose
/// is still weighed by the whole sigma; its covariance takes the own noise at
/// this share. Rendered scenes (seed 1000, 1044 frames): the holes' errors about
/// their frame's mean shift were 0.32-0.48 of their sigma squared, whole errors
/// 0.56-0.64, and with the whole sigma as own noise and the common terms on top
/// the NEES means sat at 0.58-0.68 x 3, the depth axis (which the holes' spread
/// decides) covered twice over. 0.8 keeps a margin for holes fitted worse than
/// their residuals show; the variance factor still widens a frame whose
/// residuals exceed it.
pub const OWN_NOISE_SHARE: f64 = 0.8;

/// The own share in mono: its pose is no linear function of the pixels, and
/// what the unscented spread and the mirror's odds do not catch is left to a
/// wider own noise (at 0.8, a sharp 2x1 at 44 cm, 19 degrees off-axis, whose
/// mono depth was 10 mm off, reached a NEES of 27 against issue 14's 25).
pub const MONO_OWN_NOISE_SHARE: f64 = 0.87;

/// The holes as normalised rays, each hole's own noise at `share` of its sigma
/// ([`OWN_NOISE_SHARE`], [`MONO_OWN_NOISE_SHARE`], 1 for a bound).
pub(crate) fn rays(obs: &Observations, needed: usize, mode: &'static str, share: f64) -> Result<Rays, PoseError> {
    let n = obs.model_mm.len();
    if n != obs.pixels.len() {
        return Err(PoseError::CountMismatch { model: n, pixels: obs.pixels.len() });
    }
    if n < needed {
        return Err(PoseError::TooFewHoles { got: n, needed, mode });
    }
    if !(obs.pixel_sigma.is_finite() && obs.pixel_sigma > 0.0) {
        return Err(PoseError::BadSigma(obs.pixel_sigma));
    }
    let cam = obs.camera;
    let mut out = Rays {
        xy: Vec::with_capacity(n),
        whiten: Vec::with_capacity(n),
        covariance: Vec::with_capacity(n),
        model: Vec::with_capacity(n),
        sigma: Vec::with_capacity(n),
        px_to_xy: Vec::with_capacity(n),
        share,
    };
    for (index, (m, p)) in obs.model_mm.iter().zip(obs.pixels).enumerate() {
        if !(m.x.is_finite() && m.y.is_finite() && p.x.is_finite() && p.y.is_finite()) {
            return Err(PoseError::NonFinite { index });
        }
        let xy = cam.undistort_pixel(*p);
        // pixel = K · distort(xy): d xy / d pixel = J_distort⁻¹ · diag(1/fx, 1/fy).
        let jd = cam.distortion_jacobian(xy);
        let jk = Matrix2::new(cam.fx, 0.0, 0.0, cam.fy) * jd;
        let inv = jk.try_inverse().ok_or(PoseError::NonFinite { index })?;
        let sigma = obs.sigma_of(index);
        // The pixel covariance σ² S = σ² L Lᵀ; in normalised coordinates
        // inv σ² S invᵀ, whitened by W = σ⁻¹ L⁻¹ jk (Wᵀ W = cov⁻¹).
        let shape = obs.shape_of(index);
        let l_inv = shape.cholesky().and_then(|c| c.l().try_inverse()).unwrap_or_else(Matrix2::identity);
        let cov = inv * shape * inv.transpose() * sigma.powi(2);
        out.whiten.push(l_inv * jk / sigma);
        out.covariance.push(cov);
        out.sigma.push(sigma);
        out.px_to_xy.push(inv);
        out.xy.push(xy);
        out.model.push(Point3::new(m.x / 1000.0, m.y / 1000.0, 0.0));
    }
    Ok(out)
}

/// Orients a normal away from the camera (into the wall), checking it is usable
/// with these rays: not zero, not grazing.
pub(crate) fn orient_normal(normal: &Vector3<f64>, xy: &[Vector2<f64>]) -> Result<Unit<Vector3<f64>>, PoseError> {
    let n = Unit::try_new(*normal, 1e-12).ok_or(PoseError::BadNormal)?;
    if !n.iter().all(|v| v.is_finite()) {
        return Err(PoseError::BadNormal);
    }
    let centre = xy.iter().fold(Vector2::zeros(), |s, p| s + p) / xy.len().max(1) as f64;
    let sight = Vector3::new(centre.x, centre.y, 1.0).normalize();
    let cos = n.dot(&sight);
    let n = if cos < 0.0 { -n } else { n };
    // Past ~85 degrees the rays meet the plane so obliquely that depth is unstable.
    let angle_deg = cos.abs().clamp(0.0, 1.0).acos().to_degrees();
    if angle_deg > 85.0 {
        return Err(PoseError::GrazingNormal { angle_deg });
    }
    for p in xy {
        if n.dot(&Vector3::new(p.x, p.y, 1.0).normalize()) < 0.05 {
            return Err(PoseError::GrazingNormal { angle_deg });
        }
    }
    Ok(n)
}

pub(crate) fn check_not_collinear(model: &[Point3<f64>]) -> Result<(), PoseError> {
    let c = model.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / model.len() as f64;
    let mut m = Matrix2::zeros();
    for p in model {
        let d = Vector2::new(p.x - c.x, p.y - c.y);
        m += d * d.transpose();
    }
    let eig = m.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if hi <= 1e-12 || lo < 1e-6 * hi { Err(PoseError::Collinear) } else { Ok(()) }
}

/// True when a hole is in front of the camera and finite.
fn in_front(h: &Point3<f64>) -> bool {
    h.z > 0.0 && h.coords.iter().all(|v| v.is_finite())
}

/// Holes in the camera frame and the reprojection RMS (pixels) of the kept ones.
pub(crate) fn holes_and_rms(
    pose: &Isometry3<f64>,
    rays: &Rays,
    camera: &CameraModel,
    pixels: &[Point2<f64>],
    kept: &[bool],
) -> (Vec<Point3<f64>>, f64) {
    let holes: Vec<Point3<f64>> = rays.model.iter().map(|p| pose * p).collect();
    let (mut sum, mut n) = (0.0, 0usize);
    for ((h, px), k) in holes.iter().zip(pixels).zip(kept) {
        if *k {
            sum += camera.project(h).map_or(1e6, |q| (q - px).norm_squared());
            n += 1;
        }
    }
    let rms = (sum / n.max(1) as f64).sqrt();
    (holes, rms)
}

/// The fit with the covariance of errors common to every hole added (a pixel
/// shift, a scale).
fn with_common_errors(fit: lm::Fit, rays: &Rays, kept: &[bool], prior: Option<&lm::Prior>) -> lm::Fit {
    let modes = robust::common_modes(rays, kept);
    match lm::common_covariance(rays, &fit.pose, prior, &modes) {
        Some(c) => lm::Fit { covariance: fit.covariance + c, ..fit },
        None => fit,
    }
}

fn scaled(covariances: Vec<Matrix3<f64>>, factor: f64) -> Vec<Matrix3<f64>> {
    covariances.into_iter().map(|c| c * factor).collect()
}

/// The paper's closed form (section V) with a known wall normal (either sign).
/// Works from two holes. `normal_sigma_rad` is the normal's uncertainty, used for
/// the covariances only.
///
/// Holes the solution cannot explain are dropped (see [`OUTLIER_CHI2`]); the
/// pose is then the maximum-likelihood one of the others with the normal as a
/// prior, started from their closed form.
pub fn solve_normal(obs: &Observations, normal: &Vector3<f64>, normal_sigma_rad: f64) -> Result<OutletPose, PoseError> {
    let mut rays = rays(obs, 2, "normal", OWN_NOISE_SHARE)?;
    let n = orient_normal(normal, &rays.xy)?;
    let sigma = normal_sigma_rad.max(0.0);
    let pose = closed_form_normal(&rays.model, &rays.xy, &n).ok_or(PoseError::Collinear)?;
    let all = vec![true; rays.model.len()];
    // The closed form weighs every hole alike: refit only when one is an outlier.
    let closed = lm::Fit { pose, covariance: nalgebra::Matrix6::identity() };
    let prior = (sigma > 0.0).then(|| lm::Prior {
        normal: n.into_inner(),
        distance_m: 0.0,
        tangent: tangent_basis(&n),
        whiten: Matrix3::from_diagonal(&Vector3::new(1.0 / sigma, 1.0 / sigma, 0.0)),
        with_distance: false,
    });
    let (fit, kept) = robust::refit(&mut rays, 2, 4, |r, kept| {
        if kept.iter().all(|k| *k) {
            return Some(lm::Fit { pose: closed.pose, covariance: closed.covariance });
        }
        let sub = robust::subset(r, kept);
        let start = closed_form_normal(&sub.model, &sub.xy, &n)?;
        lm::refine(r, start, prior.as_ref())
    })
    .ok_or(PoseError::Collinear)?;
    // The normal is fixed to within its prior: the pixels determine 4 parameters.
    let factor = robust::variance_factor(&rays, &fit.pose, &kept, 4);
    let covariances = if kept == all {
        let mut c = closed_form::covariances(&rays, &n, sigma);
        closed_form::add_common_modes(&mut c, &rays, &n, &robust::common_modes(&rays, &kept));
        c
    } else {
        let own = lm::with_own_noise(fit.clone(), &rays, prior.as_ref());
        lm::hole_covariances(&with_common_errors(own, &rays, &kept, prior.as_ref()), &rays.model)
    };
    let (holes_cam_m, rms_px) = holes_and_rms(&fit.pose, &rays, obs.camera, obs.pixels, &kept);
    if !holes_cam_m.iter().all(in_front) {
        return Err(PoseError::BehindCamera);
    }
    Ok(OutletPose {
        pose: fit.pose,
        mode: Mode::Normal,
        holes_cam_m,
        covariances: scaled(covariances, factor),
        rms_px,
        outliers: robust::dropped(&kept),
        variance_factor: factor,
    })
}

/// Normal and distance from stereo: the closed form with the measured distance,
/// then maximum likelihood over the pose with the plane as a prior.
///
/// Holes the solution cannot explain are dropped (see [`OUTLIER_CHI2`]).
pub fn solve_plane(obs: &Observations, plane: &PlaneMeasurement) -> Result<OutletPose, PoseError> {
    let mut rays = rays(obs, 2, "plane", OWN_NOISE_SHARE)?;
    let finite = plane.distance_m.is_finite()
        && plane.face_offset_m.is_finite()
        && plane.covariance.iter().all(|v| v.is_finite())
        && plane.tangent.iter().all(|t| t.iter().all(|v| v.is_finite()));
    let prior_whiten = plane.covariance.cholesky().and_then(|c| c.l().try_inverse());
    let (true, Some(prior_whiten)) = (finite, prior_whiten) else { return Err(PoseError::BadPlane) };
    let n = orient_normal(&plane.normal, &rays.xy)?;
    let sign = if n.dot(&plane.normal) < 0.0 { -1.0 } else { 1.0 };
    // The holes' plane: the wall moved towards the camera by the face offset.
    let d_face = sign * plane.distance_m - plane.face_offset_m;
    if d_face <= 0.0 {
        return Err(PoseError::BehindCamera);
    }
    let start = closed_form::with_distance(&rays.model, &rays.xy, &n, d_face).ok_or(PoseError::Collinear)?;
    let prior = lm::Prior {
        normal: n.into_inner(),
        distance_m: d_face,
        tangent: [plane.tangent[0] * sign, plane.tangent[1] * sign],
        whiten: prior_whiten,
        with_distance: true,
    };
    let (fit, kept) = robust::refit(&mut rays, 3, 3, |r, kept| {
        let begin = if kept.iter().all(|k| *k) {
            start
        } else {
            let sub = robust::subset(r, kept);
            closed_form::with_distance(&sub.model, &sub.xy, &n, d_face).unwrap_or(start)
        };
        lm::refine(r, begin, Some(&prior))
    })
    .ok_or(PoseError::Collinear)?;
    let (holes_cam_m, rms_px) = holes_and_rms(&fit.pose, &rays, obs.camera, obs.pixels, &kept);
    if !holes_cam_m.iter().all(in_front) {
        return Err(PoseError::BehindCamera);
    }
    let chi2 = lm::cost(&rays, &fit.pose, Some(&prior)) - lm::cost(&rays, &fit.pose, None);
    if chi2.is_nan() || chi2 > MAX_PLANE_DISAGREEMENT {
        return Err(PoseError::PlaneDisagrees { chi2 });
    }
    // The plane fixes three of the six parameters.
    let factor = robust::variance_factor(&rays, &fit.pose, &kept, 3);
    let fit = with_common_errors(lm::with_own_noise(fit, &rays, Some(&prior)), &rays, &kept, Some(&prior));
    let covariances = scaled(lm::hole_covariances(&fit, &rays.model), factor);
    Ok(OutletPose {
        pose: fit.pose,
        mode: Mode::Plane,
        holes_cam_m,
        covariances,
        rms_px,
        outliers: robust::dropped(&kept),
        variance_factor: factor,
    })
}

/// How much better (in `-2 log` likelihood) the chosen mono solution must explain
/// the pixels than its mirror: the mirror's posterior odds are `exp(-Δ/2)`, so
/// 2 ln 1000 leaves it at most a 1-in-1000 chance (equal priors).
pub const MONO_AMBIGUITY_LLR: f64 = 13.8;

/// Planar PnP from pixels alone. Both mirror solutions are refined; when the
/// cost of the other exceeds the better one's by less than
/// [`MONO_AMBIGUITY_LLR`] (after dividing by the better one's cost per degree
/// of freedom where that exceeds 1, so that noise larger than `pixel_sigma`
/// does not make a guess look certain), and the two put the holes apart by more
/// than their covariance, the result is [`PoseError::Ambiguous`]: no pose
/// rather than a coin toss with a small covariance. Outliers are dropped as in
/// [`solve_plane`].
pub fn solve_mono(obs: &Observations) -> Result<OutletPose, PoseError> {
    let mut rays = rays(obs, 4, "mono", MONO_OWN_NOISE_SHARE)?;
    check_not_collinear(&rays.model)?;
    let solve = |r: &Rays, kept: &[bool]| -> Option<(mono::Solution, Option<mono::Solution>)> {
        if kept.iter().all(|k| *k) {
            return mono::solve(r);
        }
        // The homography from the kept holes, then both branches refined on all
        // rays (the dropped ones weigh nothing).
        let sub = robust::subset(r, kept);
        let (best, other) = mono::solve(&sub)?;
        let refit = |s: mono::Solution| {
            lm::refine(r, s.fit.pose, None).map(|fit| mono::Solution { cost: lm::cost(r, &fit.pose, None), fit })
        };
        let best = refit(best)?;
        let other = other.and_then(refit);
        Some(match other {
            Some(o) if o.cost < best.cost => (o, Some(best)),
            o => (best, o),
        })
    };
    let (fit, kept) =
        robust::refit(&mut rays, 4, 6, |r, kept| solve(r, kept).map(|(b, _)| b.fit)).ok_or(PoseError::Collinear)?;
    let (best, other) = solve(&rays, &kept).ok_or(PoseError::Collinear)?;
    let fit = if best.cost <= lm::cost(&rays, &fit.pose, None) { best.fit } else { fit };
    let best_cost = lm::cost(&rays, &fit.pose, None);
    let (holes_cam_m, rms_px) = holes_and_rms(&fit.pose, &rays, obs.camera, obs.pixels, &kept);
    if !holes_cam_m.iter().all(in_front) {
        return Err(PoseError::BehindCamera);
    }
    let factor = robust::variance_factor(&rays, &fit.pose, &kept, 6);
    let fit = with_common_errors(lm::with_own_noise(fit, &rays, None), &rays, &kept, None);
    let mut covariances = scaled(lm::hole_covariances(&fit, &rays.model), factor);
    // A small outlet's tilt and depth are no linear function of its pixels: the
    // covariance takes whatever more the pose spreads when solved again.
    if let Some(spread) = unscented_spread(&rays, &kept, &fit.pose) {
        for (c, u) in covariances.iter_mut().zip(spread) {
            // What the re-solved poses spread beyond the linearised covariance.
            let extra = (u * factor - *c).symmetric_eigen();
            let positive = extra.eigenvectors
                * Matrix3::from_diagonal(&extra.eigenvalues.map(|v| v.max(0.0)))
                * extra.eigenvectors.transpose();
            *c += positive;
        }
    }
    if let Some(other) = other {
        let other_holes: Vec<Point3<f64>> = rays.model.iter().map(|p| other.fit.pose * p).collect();
        let other_in_front = other_holes.iter().all(in_front);
        // The mirror counts only where it is a different place for the holes.
        let apart = holes_cam_m.iter().zip(&other_holes).zip(&covariances).any(|((a, b), c)| {
            let e = b - a;
            c.cholesky().is_none_or(|l| e.dot(&l.solve(&e)) > 16.27)
        });
        let delta = ((other.cost - best_cost) / factor).max(0.0);
        if other_in_front && apart && delta < MONO_AMBIGUITY_LLR {
            return Err(PoseError::Ambiguous { best_cost, other_cost: other.cost });
        }
        if other_in_front {
            // The pixels' likelihood has a second peak: the holes are there with
            // the odds exp(-Δ/2) against the chosen pose, and the covariance
            // about the chosen pose carries that share of the other.
            let w = 1.0 / (1.0 + (delta / 2.0).exp());
            for ((c, a), b) in covariances.iter_mut().zip(&holes_cam_m).zip(&other_holes) {
                let d = b - a;
                *c += d * d.transpose() * w;
            }
        }
    }
    Ok(OutletPose {
        pose: fit.pose,
        mode: Mode::Mono,
        holes_cam_m,
        covariances,
        rms_px,
        outliers: robust::dropped(&kept),
        variance_factor: factor,
    })
}

/// Each hole's spread when the pose is solved again with the pixels moved by
/// `±sqrt(L)` along each of the L directions of their noise (every kept hole's
/// two principal axes, the common shift and scale): the unscented transform,
/// which sees where the pose is a nonlinear function of the pixels (a small
/// outlet's tilt and depth) as the linearised covariance does not.
fn unscented_spread(rays: &Rays, kept: &[bool], pose: &Isometry3<f64>) -> Option<Vec<Matrix3<f64>>> {
    let n = rays.xy.len();
    let mut directions = robust::common_modes(rays, kept);
    for k in (0..n).filter(|k| kept.get(*k).copied().unwrap_or(false)) {
        let eig = rays.covariance[k].symmetric_eigen();
        for axis in 0..2 {
            let mut d = vec![nalgebra::Vector2::zeros(); n];
            d[k] = eig.eigenvectors.column(axis) * (eig.eigenvalues[axis].max(0.0).sqrt() * rays.share);
            directions.push(d);
        }
    }
    let l = directions.len() as f64;
    let base: Vec<Point3<f64>> = rays.model.iter().map(|p| pose * p).collect();
    let mut total = vec![Matrix3::zeros(); n];
    let mut moved = robust::subset(rays, &vec![true; n]);
    for d in &directions {
        for sign in [1.0, -1.0] {
            for ((xy, original), dd) in moved.xy.iter_mut().zip(&rays.xy).zip(d) {
                *xy = original + dd * (l.sqrt() * sign);
            }
            let fit = lm::refine(&moved, *pose, None)?;
            for (t, (p, b)) in total.iter_mut().zip(rays.model.iter().zip(&base)) {
                let e = fit.pose * p - b;
                *t += e * e.transpose() / (2.0 * l);
            }
        }
    }
    Some(total)
}

/// The Cramér-Rao bound of each hole's position for a true pose: the covariance an
/// unbiased estimator cannot beat, given the pixel noise and (optionally) the
/// plane's prior. For `outlet eval`.
pub fn cramer_rao(
    obs: &Observations,
    truth: &Isometry3<f64>,
    plane: Option<&PlaneMeasurement>,
    normal_only_sigma_rad: Option<f64>,
) -> Result<Vec<Matrix3<f64>>, PoseError> {
    let rays = rays(obs, 2, "bound", 1.0)?;
    let n = truth.rotation * Vector3::z();
    let d = n.dot(&truth.translation.vector);
    let prior = match (plane, normal_only_sigma_rad) {
        (Some(p), _) => Some(lm::Prior {
            normal: n,
            distance_m: d,
            // The measurement's covariance is in its own tangent basis.
            tangent: if p.normal.dot(&n) < 0.0 { [-p.tangent[0], -p.tangent[1]] } else { p.tangent },
            whiten: p.covariance.cholesky().and_then(|c| c.l().try_inverse()).ok_or(PoseError::BadPlane)?,
            with_distance: true,
        }),
        (None, Some(s)) if s > 0.0 => Some(lm::Prior {
            normal: n,
            distance_m: d,
            tangent: tangent_basis(&n),
            whiten: Matrix3::from_diagonal(&Vector3::new(1.0 / s, 1.0 / s, 0.0)),
            with_distance: false,
        }),
        _ => None,
    };
    let fit = lm::at(&rays, *truth, prior.as_ref()).ok_or(PoseError::Collinear)?;
    Ok(lm::hole_covariances(&fit, &rays.model))
}
