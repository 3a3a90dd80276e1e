//! The three services as real processes: a rendered frame and its stereo cloud
//! go in through shared memory, hole poses come out, within 1 mm of the truth.

mod common;

use outlet_protocol::CameraModel;
use std::time::Duration;

#[test]
fn frames_and_clouds_in_hole_poses_out_under_a_millimetre() -> Result<(), Box<dyn std::error::Error>> {
    let domain = common::domain("pipeline");
    let mut services = common::Services::start_2x1_pipeline(&domain)?;
    let camera = CameraModel::default_vga();
    let scene = common::frontal_scene("fw_2x1white", &camera, 25.0)?;
    let frame = outlet_sim::render_frame(&scene, "x");
    let pixels = frame.frame.image.as_raw();
    let cloud: Vec<f32> = frame.cloud.iter().flatten().copied().collect();

    let pose = common::feed_until(&mut services, &camera, pixels, &cloud, Duration::from_secs(40), |p| p.mode == 3)?;
    assert_eq!(pose.hole_count, 6);
    for (k, truth) in frame.truth.holes.iter().enumerate() {
        let t = truth.position_m.ok_or("truth position")?;
        let e = (0..3).map(|i| (pose.positions_m[k][i] - t[i]).powi(2)).sum::<f64>().sqrt();
        assert!(e < 0.001, "hole {k}: {:.3} mm off", e * 1000.0);
        assert!(pose.covariances_m2[k][0] > 0.0);
    }
    Ok(())
}
