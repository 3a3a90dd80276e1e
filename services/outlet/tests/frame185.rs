//! The demo's frame 185 (issue 14): `outlet demo` shows view 184 of
//! `fw_2x1white`, seed 1, as frame 185. Its upper hot slot is refined several
//! pixels off its centre (the edge of an occluder's shadow crosses it), and the
//! pose service used to leave the plane for a mono pose 5-31 mm wrong with
//! 1 mm error bars.
//!
//! Then the detector refused that outlet: two of its holes could not be fitted,
//! and a hole is taken from the homography of the others only when five were
//! fitted (four fix a homography and check nothing). Should a later detector
//! fit all six and report it, or be allowed to predict from four, its plane
//! pose must be within a millimetre and 5 sigma of the truth on every hole.

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

    // Shipped: refused (too few holes fitted to predict the others), or found
    // with every hole fitted; either way no confident mistake.
    let shipped = Detector::new(template.clone(), DetectorParams::default());
    let report = shipped.detect(&frame.frame.image, Some(&camera));
    match &report.detection {
        Some(d) => {
            // Found: every hole fitted, or one predicted from at least the five
            // fitted holes the shipped detector asks for (since session 11's
            // outline fit, five are fitted here); either way within a
            // millimetre and 5 sigma.
            let fitted = d.holes.iter().filter(|h| h.refined).count();
            assert!(
                fitted >= DetectorParams::default().min_fitted_for_prediction,
                "frame 185 reported with only {fitted} holes fitted"
            );
            plane_pose_within_a_millimetre_and_5_sigma(&frame, &camera, d, &shipped)?;
        }
        None => {
            let why = report.rejected.clone().unwrap_or_default();
            assert!(why.contains("too few to predict"), "{why}");
        }
    }

    let permissive = Detector::new(template, DetectorParams { min_fitted_for_prediction: 4, ..Default::default() });
    let detection = permissive.detect(&frame.frame.image, Some(&camera)).detection.ok_or("found from 4 holes")?;
    plane_pose_within_a_millimetre_and_5_sigma(&frame, &camera, &detection, &permissive)
}

fn plane_pose_within_a_millimetre_and_5_sigma(
    frame: &outlet_sim::RenderedFrame,
    camera: &outlet_protocol::CameraModel,
    detection: &outlet_detector::detect::Detection,
    detector: &Detector,
) -> Result<(), Box<dyn std::error::Error>> {
    let geometry = &detector.template().geometry;
    let holes = outlet::DetectedHoles::new(detection, geometry);
    let obs = holes.observations(camera, 0.25);
    let plane = outlet_normal::fit_wall_plane(&frame.cloud, &outlet_normal::PlaneParams::default())?;
    let pose = solve_plane(&obs, &outlet::plane_measurement(&plane, geometry, &outlet::ModelError::default()))?;
    for (k, truth) in frame.truth.holes.iter().enumerate() {
        let e = pose.holes_cam_m[k] - nalgebra::Point3::from(truth.position_m.ok_or("truth position")?);
        let c: Matrix3<f64> = pose.covariances[k];
        let sigmas = e.dot(&c.cholesky().ok_or("covariance")?.solve(&e)).sqrt();
        println!("hole {k}: {:.3} mm, {sigmas:.2} sigma", e.norm() * 1e3);
        assert!(e.norm() < 1e-3, "hole {k}: {:.3} mm off", e.norm() * 1e3);
        assert!(sigmas < 5.0, "hole {k}: {sigmas:.1} sigma off");
    }
    Ok(())
}
