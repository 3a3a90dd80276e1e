//! What the `outlet` command shares with other programs and tests: the built-in
//! templates (trained from rendered views), the sidecar's configuration, the
//! counters behind each service's heartbeat, and MCAP recordings.

pub mod config;
pub mod health;
pub mod live_view;
pub mod recording;
pub mod templates;

/// What a stereo wall plane's own fit cannot know, one sigma each: how far a real
/// receptacle face stands from the template's nominal offset ahead of the wall
/// (CONTRACT: 5.0 mm; real plates and receptacles put it 3-7 mm), and a
/// calibration bias of the stereo pair on the wall's normal and distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelError {
    pub face_offset_sigma_mm: f64,
    pub plane_tilt_sigma_deg: f64,
    pub plane_distance_sigma_mm: f64,
}

impl ModelError {
    /// The nominal face offset taken as exact and an unbiased stereo pair: true
    /// only of simulated scenes.
    pub const NONE: Self = Self { face_offset_sigma_mm: 0.0, plane_tilt_sigma_deg: 0.0, plane_distance_sigma_mm: 0.0 };
    /// What a robot's stereo and an unknown receptacle give (the default): faces
    /// uniform over 3-7 mm (1.15 mm), a pair's plane 0.3-1 degree and 0.5-2 mm off
    /// the wall (0.48 degrees per axis, 1.32 mm RMS). Without it the plane-mode
    /// error bars were 3.5 times too small on such stereo (BENCHMARKS.md).
    pub const REAL_STEREO: Self =
        Self { face_offset_sigma_mm: 1.15, plane_tilt_sigma_deg: 0.48, plane_distance_sigma_mm: 1.32 };

    /// "FACE_MM,TILT_DEG,DISTANCE_MM", each finite and at least 0.
    pub fn parse(text: &str) -> Result<Self, String> {
        let values: Vec<f64> = text
            .split(',')
            .map(|v| v.trim().parse::<f64>().map_err(|e| format!("model error {text:?}: {v:?}: {e}")))
            .collect::<Result<_, _>>()?;
        match values[..] {
            [f, t, d] if values.iter().all(|v| v.is_finite() && *v >= 0.0) => {
                Ok(Self { face_offset_sigma_mm: f, plane_tilt_sigma_deg: t, plane_distance_sigma_mm: d })
            }
            _ => Err(format!(
                "model error {text:?}: want FACE_MM,TILT_DEG,DISTANCE_MM, three finite values of at least 0"
            )),
        }
    }
}

impl Default for ModelError {
    fn default() -> Self {
        Self::REAL_STEREO
    }
}

/// The wall plane fitted to a stereo cloud as the pose's measurement, with the
/// outlet's nominal face offset (its geometry's) and what the fit cannot know
/// (`model_error`): what the pose service, `outlet detect --points`, `outlet
/// eval` and its NEES table all solve plane mode from.
pub fn plane_measurement(
    plane: &outlet_normal::WallPlane,
    geometry: &outlet_protocol::OutletGeometry,
    model_error: &ModelError,
) -> outlet_pose::PlaneMeasurement {
    outlet_pose::PlaneMeasurement {
        normal: plane.normal,
        distance_m: plane.distance_m,
        covariance: plane.covariance,
        tangent: plane.tangent,
        face_offset_m: geometry.face_offset_mm / 1000.0,
    }
    .with_model_error(
        model_error.face_offset_sigma_mm / 1e3,
        model_error.plane_tilt_sigma_deg.to_radians(),
        model_error.plane_distance_sigma_mm / 1e3,
    )
}

/// [`plane_measurement`] with the receptacle face's offset measured from the
/// cloud (`face`, ahead of the same fitted plane) where the stereo saw it: the
/// measurement and the nominal offset (with its `face_offset_sigma_mm`) are
/// combined by their variances. A nominal taken as exact (sigma 0) stays exact.
pub fn plane_measurement_with_face(
    plane: &outlet_normal::WallPlane,
    geometry: &outlet_protocol::OutletGeometry,
    model_error: &ModelError,
    face: Option<&outlet_normal::FaceOffset>,
) -> outlet_pose::PlaneMeasurement {
    let nominal_m = geometry.face_offset_mm / 1000.0;
    let nominal_var = (model_error.face_offset_sigma_mm / 1e3).powi(2);
    let (offset_m, sigma_m) = match face {
        Some(f) if nominal_var > 0.0 && f.sigma_m > 0.0 && f.offset_m.is_finite() => {
            let (wn, wf) = (1.0 / nominal_var, 1.0 / f.sigma_m.powi(2));
            ((nominal_m * wn + f.offset_m * wf) / (wn + wf), (1.0 / (wn + wf)).sqrt())
        }
        _ => (nominal_m, nominal_var.sqrt()),
    };
    outlet_pose::PlaneMeasurement {
        normal: plane.normal,
        distance_m: plane.distance_m,
        covariance: plane.covariance,
        tangent: plane.tangent,
        face_offset_m: offset_m,
    }
    .with_model_error(
        sigma_m,
        model_error.plane_tilt_sigma_deg.to_radians(),
        model_error.plane_distance_sigma_mm / 1e3,
    )
}

/// Plane mode from a stereo cloud and the plane fitted to it: solved with the
/// nominal face, then, where the cloud has points on the face around the holes
/// that pose puts, solved again with the face's offset as measured there (see
/// `outlet_normal::measure_face`). Returns the pose and the face measurement
/// it used, if any.
pub fn solve_plane_with_cloud(
    obs: &outlet_pose::Observations,
    plane: &outlet_normal::WallPlane,
    cloud: &[[f32; 3]],
    geometry: &outlet_protocol::OutletGeometry,
    model_error: &ModelError,
) -> Result<(outlet_pose::OutletPose, Option<outlet_normal::FaceOffset>), outlet_pose::PoseError> {
    let first = outlet_pose::solve_plane(obs, &plane_measurement(plane, geometry, model_error))?;
    if model_error.face_offset_sigma_mm <= 0.0 {
        return Ok((first, None));
    }
    let holes: Vec<nalgebra::Point2<f64>> = geometry.holes.iter().map(|h| h.position()).collect();
    match outlet_normal::measure_face(cloud, plane, &first.pose, &holes, &outlet_normal::FaceParams::default()) {
        Some(face) => {
            let measurement = plane_measurement_with_face(plane, geometry, model_error, Some(&face));
            outlet_pose::solve_plane(obs, &measurement).map(|pose| (pose, Some(face)))
        }
        None => Ok((first, None)),
    }
}

/// A detection's holes as the pose solvers take them: the template's hole
/// positions (mm), the detected pixels and each hole's own sigma from the
/// detector's fit.
pub struct DetectedHoles {
    pub model_mm: Vec<nalgebra::Point2<f64>>,
    pub pixels: Vec<nalgebra::Point2<f64>>,
    pub sigmas_px: Vec<f64>,
    /// Each hole's pixel covariance shape (trace 2).
    pub shapes: Vec<nalgebra::Matrix2<f64>>,
}

impl DetectedHoles {
    pub fn new(detection: &outlet_detector::detect::Detection, geometry: &outlet_protocol::OutletGeometry) -> Self {
        Self {
            model_mm: geometry.holes.iter().map(|h| h.position()).collect(),
            pixels: detection.holes.iter().map(|h| h.pixel).collect(),
            sigmas_px: detection.holes.iter().map(|h| h.sigma_px).collect(),
            shapes: detection.holes.iter().map(|h| h.shape).collect(),
        }
    }

    /// The observations, `pixel_sigma` standing for a hole without a sigma of its own.
    pub fn observations<'a>(
        &'a self,
        camera: &'a outlet_protocol::CameraModel,
        pixel_sigma: f64,
    ) -> outlet_pose::Observations<'a> {
        outlet_pose::Observations {
            model_mm: &self.model_mm,
            pixels: &self.pixels,
            camera,
            pixel_sigma,
            pixel_sigmas: Some(&self.sigmas_px),
            pixel_shapes: Some(&self.shapes),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_error_is_three_finite_sigmas_of_at_least_zero() {
        assert_eq!(
            ModelError::parse("1.15, 0.48,1.32"),
            Ok(ModelError { face_offset_sigma_mm: 1.15, plane_tilt_sigma_deg: 0.48, plane_distance_sigma_mm: 1.32 })
        );
        assert_eq!(ModelError::parse("0,0,0"), Ok(ModelError::NONE));
        for bad in ["", "1,2", "1,2,3,4", "1,-2,3", "1,NaN,3", "1,inf,3", "a,b,c"] {
            let e = ModelError::parse(bad).expect_err(bad);
            assert!(e.contains("model error"), "{bad}: {e}");
        }
    }
}
