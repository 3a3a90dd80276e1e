//! The demo's frame 185 (issue 14): `outlet demo` shows view 184 of
//! `fw_2x1white`, seed 1, as frame 185. Its upper hot slot is refined several
//! pixels off its centre (the edge of an occluder's shadow crosses it), and the
//! pose service used to leave the plane for a mono pose 5-31 mm wrong with
//! 1 mm error bars.
//!
//! Now the detector does not report that outlet at all: two of its holes cannot
//! be fitted, and a hole is taken from the homography of the others only when
//! five were fitted (four fix a homography and check nothing). Allowed to
//! predict from four, the outlet is found, and its plane pose is within a
//! millimetre and 5 sigma of the truth on every hole.

use nalgebra::Matrix3;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_pose::solve_plane;

#[test]
fn the_demos_frame_185_is_refused_or_else_a_plane_pose_within_a_millimetre() -> Result<(), Box<dyn std::error::Error>> {
    // The sim camera's 640x480 camera is the default VGA one.
    let camera = outlet_protocol::CameraModel::default_vga();
    let scene = outlet_sim::sample_scene("fw_2x1white", 1, 184, &camera)?;
    let frame = outlet_sim::render_frame(&scene, "sim-184");
    let template = outlet::templates::builtin("2x1")?;

    let shipped = Detector::new(template.clone(), DetectorParams::default());
    let report = shipped.detect(&frame.frame.image, Some(&camera));
    assert!(report.detection.is_none(), "frame 185 reported with two holes unfitted");
    let why = report.rejected.unwrap_or_default();
    assert!(why.contains("too few to predict"), "{why}");

    let permissive = Detector::new(template, DetectorParams { min_fitted_for_prediction: 4, ..Default::default() });
    let detection = permissive.detect(&frame.frame.image, Some(&camera)).detection.ok_or("found from 4 holes")?;
    let geometry = &permissive.template().geometry;
    let holes = outlet::DetectedHoles::new(&detection, geometry);
    let obs = holes.observations(&camera, 0.25);
    let plane = outlet_normal::fit_wall_plane(&frame.cloud, &outlet_normal::PlaneParams::default())?;
    let pose = solve_plane(&obs, &outlet::plane_measurement(&plane, geometry, &outlet::ModelError::default()))?;
    for (k, truth) in frame.truth.holes.iter().enumerate() {
        let e = pose.holes_cam_m[k] - nalgebra::Point3::from(truth.position_m.ok_or("truth position")?);
        let c: Matrix3<f64> = pose.covariances[k];
        let sigmas = e.dot(&c.cholesky().ok_or("covariance")?.solve(&e)).sqrt();
        assert!(e.norm() < 1e-3, "hole {k}: {:.3} mm off", e.norm() * 1e3);
        assert!(sigmas < 5.0, "hole {k}: {sigmas:.1} sigma off");
    }
    Ok(())
}
