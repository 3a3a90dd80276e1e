//! The three services as real processes: a rendered frame and its stereo cloud
//! go in through shared memory, hole poses come out, within 1 mm of the truth.

mod common;

use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{CloudHeader, FrameHeader, HolePosesMsg, PixelFormat, SCHEMA_VERSION, service};
use std::time::{Duration, Instant};

#[test]
fn frames_and_clouds_in_hole_poses_out_under_a_millimetre() -> Result<(), Box<dyn std::error::Error>> {
    let domain = common::domain("pipeline");
    let mut services = common::Services::start(
        &domain,
        &[&["detector", "--template", "2x1"], &["normal"], &["pose", "--template", "2x1"]],
    )?;
    let camera = CameraModel::default_vga();
    let scene = common::frontal_scene("fw_2x1white", &camera, 25.0)?;
    let frame = outlet_sim::render_frame(&scene, "x");
    let pixels = frame.frame.image.as_raw();
    let cloud: Vec<f32> = frame.cloud.iter().flatten().copied().collect();

    let node = shm::node(&domain, "test")?;
    let frames = shm::frames(&node)?;
    let clouds = shm::clouds(&node)?;
    let poses = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?;
    let frame_pub = frames.publisher_builder().initial_max_slice_len(pixels.len()).create()?;
    let cloud_pub = clouds.publisher_builder().initial_max_slice_len(cloud.len()).create()?;
    let frame_note = shm::events(&node, service::FRAMES)?.notifier_builder().create()?;
    let cloud_note = shm::events(&node, service::CLOUDS)?.notifier_builder().create()?;
    let pose_sub = poses.subscriber_builder().create()?;

    let start_time = Instant::now();
    let mut id = 0u64;
    let pose = loop {
        assert!(start_time.elapsed() < Duration::from_secs(40), "no plane-mode hole poses from the pipeline");
        assert!(services.all_running(), "a service died");
        id += 1;
        let stamp = id * 1_000_000;
        // The cloud first: the pose service joins a detection with the plane closest in time.
        let mut c = cloud_pub.loan_slice_uninit(cloud.len())?;
        *c.user_header_mut() = CloudHeader {
            schema_version: SCHEMA_VERSION,
            reserved: 0,
            frame_id: id,
            capture_time_ns: stamp,
            points: (cloud.len() / 3) as u64,
        };
        c.write_from_slice(&cloud).send()?;
        cloud_note.notify()?;
        std::thread::sleep(Duration::from_millis(50));
        let mut f = frame_pub.loan_slice_uninit(pixels.len())?;
        *f.user_header_mut() = FrameHeader::new(id, stamp, PixelFormat::Rgb8, &camera);
        f.write_from_slice(pixels).send()?;
        frame_note.notify()?;
        let wait = Instant::now();
        let mut got = None;
        while wait.elapsed() < Duration::from_millis(400) {
            if let Some(s) = pose_sub.receive()?
                && s.payload().mode == 3
            {
                got = Some(*s.payload());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        if let Some(p) = got {
            break p;
        }
    };
    assert_eq!(pose.hole_count, 6);
    for (k, truth) in frame.truth.holes.iter().enumerate() {
        let t = truth.position_m.ok_or("truth position")?;
        let e = (0..3).map(|i| (pose.positions_m[k][i] - t[i]).powi(2)).sum::<f64>().sqrt();
        assert!(e < 0.001, "hole {k}: {:.3} mm off", e * 1000.0);
        assert!(pose.covariances_m2[k][0] > 0.0);
    }
    Ok(())
}
