//! No silent fall-back (issue 14): a stereo cloud of another wall (the true one
//! moved 5 cm back) cannot explain the detected holes. The pose service used
//! to solve such a detection in mono and say nothing; now the result says
//! `plane_mismatch` and carries no pose and no holes.

mod common;

use outlet_protocol::wire::pose_status;
use std::time::Duration;

#[test]
fn a_plane_that_cannot_explain_the_holes_gives_plane_mismatch_and_no_pose() -> Result<(), Box<dyn std::error::Error>> {
    let domain = common::domain("posestatus");
    let mut services = common::Services::start_2x1_pipeline(&domain)?;
    // The sim camera's 640x480 camera is the default VGA one.
    let camera = outlet_protocol::CameraModel::default_vga();
    let scene = common::frontal_scene("fw_2x1white", &camera, 20.0)?;
    let frame = outlet_sim::render_frame(&scene, "frontal");
    let pixels = frame.frame.image.as_raw();
    // Every point 5 cm further along its ray: a wall behind the outlet's.
    let cloud: Vec<f32> = frame.cloud.iter().flat_map(|p| p.map(|v| v * (1.0 + 0.05 / p[2].max(0.05)))).collect();

    // The detector trains its template at start (cached afterwards).
    let pose = common::feed_until(&mut services, &camera, pixels, &cloud, Duration::from_secs(300), |p| {
        p.mode == 3 && p.status != pose_status::OK
    })?;
    assert_eq!(pose.status, pose_status::PLANE_MISMATCH);
    assert_eq!(pose.hole_count, 0, "no holes in a result without a pose");
    assert!(pose.translation_m.iter().all(|v| v.is_nan()), "{:?}", pose.translation_m);
    Ok(())
}
