//! No silent fall-back (issue 14): a stereo cloud of another wall (the true one
//! moved 5 cm back) cannot explain the detected holes. The pose service used
//! to solve such a detection in mono and say nothing; now the result says
//! `plane_mismatch` and carries no pose and no holes.

mod common;

use outlet_protocol::shm;
use outlet_protocol::wire::{
    CloudHeader, FrameHeader, HolePosesMsg, PixelFormat, SCHEMA_VERSION, pose_status, service,
};
use std::time::{Duration, Instant};

#[test]
fn a_plane_that_cannot_explain_the_holes_gives_plane_mismatch_and_no_pose() -> Result<(), Box<dyn std::error::Error>> {
    let domain = common::domain("posestatus");
    let mut services = common::Services::start(
        &domain,
        &[&["detector", "--template", "2x1"], &["normal"], &["pose", "--template", "2x1"]],
    )?;
    // The sim camera's 640x480 camera is the default VGA one.
    let camera = outlet_protocol::CameraModel::default_vga();
    let scene = outlet_sim::sample_scene("fw_2x1white", 1, 184, &camera)?;
    let frame = outlet_sim::render_frame(&scene, "sim-184");
    let pixels = frame.frame.image.as_raw();
    // Every point 5 cm further along its ray: a wall behind the outlet's.
    let cloud: Vec<f32> = frame.cloud.iter().flat_map(|p| p.map(|v| v * (1.0 + 0.05 / p[2].max(0.05)))).collect();

    let node = shm::node(&domain, "test")?;
    let frame_pub = shm::frames(&node)?.publisher_builder().initial_max_slice_len(pixels.len()).create()?;
    let cloud_pub = shm::clouds(&node)?.publisher_builder().initial_max_slice_len(cloud.len()).create()?;
    let frame_note = shm::events(&node, service::FRAMES)?.notifier_builder().create()?;
    let cloud_note = shm::events(&node, service::CLOUDS)?.notifier_builder().create()?;
    let pose_sub = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?.subscriber_builder().create()?;

    let started = Instant::now();
    let mut id = 0u64;
    let pose = loop {
        // The detector trains its template at start (cached afterwards).
        assert!(started.elapsed() < Duration::from_secs(300), "no hole poses from the pipeline");
        assert!(services.all_running(), "a service died");
        id += 1;
        let stamp = id * 1_000_000;
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
                && s.payload().status != pose_status::OK
            {
                got = Some(*s.payload());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        if let Some(p) = got {
            break p;
        }
    };
    assert_eq!(pose.status, pose_status::PLANE_MISMATCH);
    assert_eq!(pose.hole_count, 0, "no holes in a result without a pose");
    assert!(pose.translation_m.iter().all(|v| v.is_nan()), "{:?}", pose.translation_m);
    Ok(())
}
