//! Parameters of the wall-plane fit.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

/// Disparity noise of the reference stereo camera (pixels, one sigma).
pub const REFERENCE_DISPARITY_SIGMA_PX: f64 = 0.15;
/// Baseline of the reference stereo camera (metres).
pub const REFERENCE_BASELINE_M: f64 = 0.09;
/// Focal length of the reference stereo camera (pixels, 640x480).
pub const REFERENCE_FOCAL_PX: f64 = 525.0;

/// How the wall plane is fitted to a stereo cloud (camera frame, metres).
///
/// **Noise model.** Stereo measures depth through disparity, so a point's error
/// lies along its line of sight and grows with the square of its depth:
/// `sigma_z(z) = sigma_at_1m · z²` (metres, `z` in metres) with
/// `sigma_at_1m = disparity_sigma / (focal · baseline)`. A point `X` on the plane
/// `n · X = d` that slides along its ray by `δz` leaves the plane by
/// `δz · (n · X) / z = δz · d / z`, so the plane residual of a point has
///
/// ```text
/// sigma_r(X) = sigma_z(z) · d / z = sigma_at_1m · z · d       (metres)
/// ```
///
/// which is `sigma_z` on a wall facing the camera and less on an oblique one.
/// Every threshold and weight of the fit is in units of this `sigma_r`, times a
/// scale factor that the fit estimates from the data (see
/// [`estimate_noise_scale`](Self::estimate_noise_scale)) unless told not to.
///
/// **Defaults** are for the reference camera: 640x480, f = 525 px, a 9 cm
/// baseline and 0.15 px disparity noise, so `sigma_at_1m` = 0.15 / (525 · 0.09)
/// = 3.17 mm: 0.13 mm at 20 cm, 0.29 mm at 30 cm, 0.79 mm at 50 cm. See
/// [`PlaneParams::for_stereo`] for another camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PlaneParams {
    /// Depth noise at 1 m along the line of sight (metres); scales as z².
    /// Default 3.17e-3 (the reference camera above).
    pub sigma_at_1m: f64,
    /// Estimate the noise scale factor from the data (default `true`): the
    /// residuals behind the wall (where no plate or face can be) give a robust
    /// half-normal scale, bounded to [`NOISE_SCALE_RANGE`](Self::NOISE_SCALE_RANGE)
    /// times the model. With `false` the model is taken as exact.
    pub estimate_noise_scale: bool,
    /// Most MSAC hypotheses (default 500). The search stops earlier once
    /// [`confidence`](Self::confidence) is reached: about 25 hypotheses when the
    /// wall holds 65% of the points, 150 at 35%.
    pub max_iterations: usize,
    /// Probability that at least one hypothesis was drawn from wall points only
    /// (default 0.999), for the adaptive stop of MSAC.
    pub confidence: f64,
    /// How many points (drawn at random) score each hypothesis, and serve for the
    /// local refinement and the noise scale (default 2048). The final fit uses
    /// every point.
    pub sample_size: usize,
    /// Inlier band of the MSAC score (truncated quadratic cost), in sigmas of the
    /// model (default 3).
    pub msac_threshold_sigmas: f64,
    /// Tuning constant `c` of the Tukey biweight used by the refinement, in
    /// (estimated) sigmas (default 2.5): points beyond `c` sigmas have no weight
    /// and are not inliers. A plate standing `D` sigmas proud over a fraction
    /// `ε` of the points pulls the fit towards it by about 0.025 sigma at `D` =
    /// 3.8, ε = 0.3 (0.09 sigma at `D` = 3.2), where `c` = 3 doubles that and a
    /// hard ±2.5-sigma band quadruples it; efficiency (64%) matters little with
    /// thousands of points.
    pub inlier_sigmas: f64,
    /// Most passes over every point after the local refinement on the sample
    /// (default 6). Each pass takes a Newton step; the refinement stops after a
    /// step shorter than half the plane's standard deviation, which takes two
    /// passes on the rendered clouds.
    pub max_refine_iterations: usize,
    /// Least fraction of the valid points (in the region of interest) that must be
    /// inliers of the final plane (default 0.2); otherwise
    /// [`PlaneError::NoDominantPlane`](crate::PlaneError::NoDominantPlane).
    pub min_inlier_fraction: f64,
    /// Least number of valid points (default 20, at least 4).
    pub min_points: usize,
    /// A cloud of more points is thinned to every k-th point first (default
    /// 16 384, at least `sample_size`): past that the plane's own error is far
    /// below what the stereo's calibration leaves, and the passes over every
    /// point were most of the fit's time (2.2 ms for a 640x480 cloud, 8.5 ms for
    /// 1280x960), which sits between a frame and its hole poses. Neighbouring
    /// stereo points share their matching window and are not independent
    /// anyway; the covariance is that of the points used.
    pub max_points: usize,
    /// Region of interest: only points within `radius` (metres) of `centre`
    /// (camera frame, metres) take part. Choose it wide enough that the wall, not
    /// the plate, dominates: a radius of 12 cm or more around a 2-gang plate.
    pub roi: Option<(Point3<f64>, f64)>,
    /// Seed of the sampling: the same cloud and parameters give the same plane.
    pub seed: u64,
}

impl PlaneParams {
    /// Bounds of the estimated noise scale factor, relative to the model.
    pub const NOISE_SCALE_RANGE: (f64, f64) = (0.05, 10.0);

    /// Parameters for a stereo camera of focal length `focal_px` (pixels),
    /// baseline `baseline_m` (metres) and disparity noise `disparity_sigma_px`
    /// (pixels, one sigma); the rest as [`Default`].
    pub fn for_stereo(focal_px: f64, baseline_m: f64, disparity_sigma_px: f64) -> Self {
        Self { sigma_at_1m: disparity_sigma_px / (focal_px * baseline_m), ..Self::default() }
    }

    /// The same parameters restricted to the points within `radius_m` of
    /// `centre` (camera frame, metres).
    pub fn with_roi(self, centre: Point3<f64>, radius_m: f64) -> Self {
        Self { roi: Some((centre, radius_m)), ..self }
    }

    /// Model depth noise (metres, one sigma, along the line of sight) at depth
    /// `z_m` (metres).
    pub fn depth_sigma_m(&self, z_m: f64) -> f64 {
        self.sigma_at_1m * z_m * z_m
    }

    /// Model noise of the plane residual (metres, one sigma) of a point at depth
    /// `z_m` on a plane at distance `distance_m` from the camera.
    pub fn residual_sigma_m(&self, z_m: f64, distance_m: f64) -> f64 {
        self.sigma_at_1m * z_m * distance_m.abs()
    }

    /// Checks that every value makes sense; the message names the first that
    /// does not.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 { Ok(()) } else { Err(format!("{name} must be finite and positive, got {v}")) }
        };
        positive("sigma_at_1m", self.sigma_at_1m)?;
        positive("msac_threshold_sigmas", self.msac_threshold_sigmas)?;
        positive("inlier_sigmas", self.inlier_sigmas)?;
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(format!("confidence must lie in (0, 1), got {}", self.confidence));
        }
        if !(0.0..=1.0).contains(&self.min_inlier_fraction) {
            return Err(format!("min_inlier_fraction must lie in [0, 1], got {}", self.min_inlier_fraction));
        }
        if self.max_iterations == 0 {
            return Err("max_iterations must be at least 1".into());
        }
        if self.max_refine_iterations == 0 {
            return Err("max_refine_iterations must be at least 1".into());
        }
        if self.sample_size < 16 {
            return Err(format!("sample_size must be at least 16, got {}", self.sample_size));
        }
        if self.max_points < self.sample_size {
            return Err(format!(
                "max_points must be at least sample_size ({}), got {}",
                self.sample_size, self.max_points
            ));
        }
        if self.min_points < 4 {
            return Err(format!("min_points must be at least 4, got {}", self.min_points));
        }
        if let Some((centre, radius)) = self.roi {
            if !centre.coords.iter().all(|v| v.is_finite()) {
                return Err(format!("roi centre must be finite, got {centre}"));
            }
            positive("roi radius", radius)?;
        }
        Ok(())
    }
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            sigma_at_1m: REFERENCE_DISPARITY_SIGMA_PX / (REFERENCE_FOCAL_PX * REFERENCE_BASELINE_M),
            estimate_noise_scale: true,
            max_iterations: 500,
            confidence: 0.999,
            sample_size: 2048,
            msac_threshold_sigmas: 3.0,
            inlier_sigmas: 2.5,
            max_refine_iterations: 6,
            min_inlier_fraction: 0.2,
            min_points: 20,
            max_points: 16_384,
            roi: None,
            seed: 0x5EED_0F0A,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_noise_is_the_reference_stereo_camera() {
        let p = PlaneParams::default();
        assert!((p.sigma_at_1m - 3.1746e-3).abs() < 1e-7);
        assert!((p.depth_sigma_m(0.3) - 0.2857e-3).abs() < 1e-7);
        assert!((p.residual_sigma_m(0.3, 0.3) - p.depth_sigma_m(0.3)).abs() < 1e-15);
        assert_eq!(PlaneParams::for_stereo(525.0, 0.09, 0.15), p);
        assert!(p.validate().is_ok());
    }

    #[test]
    fn nonsense_parameters_are_named() {
        let bad = PlaneParams { sigma_at_1m: f64::NAN, ..Default::default() };
        assert!(bad.validate().unwrap_err().contains("sigma_at_1m"));
        let bad = PlaneParams::default().with_roi(Point3::origin(), -1.0);
        assert!(bad.validate().unwrap_err().contains("roi radius"));
        let bad = PlaneParams { confidence: 1.0, ..Default::default() };
        assert!(bad.validate().unwrap_err().contains("confidence"));
    }
}
