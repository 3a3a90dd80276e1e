//! `outlet serve detector` as a real process: frames in through shared memory,
//! detections out; frames with a zero width or an unknown pixel format are
//! rejected and the service goes on.

mod common;

use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{DetectionMsg, FrameHeader, PixelFormat, service};
use std::time::{Duration, Instant};

#[test]
fn frames_in_detections_out_and_bad_frames_are_rejected() -> Result<(), Box<dyn std::error::Error>> {
    let domain = common::domain("servedetec");
    let mut services = common::Services::start(&domain, &[&["detector", "--template", "2x1"]])?;
    let camera = CameraModel::default_vga();
    let scene = common::frontal_scene("orange2x1", &camera, 20.0)?;
    let frame = outlet_sim::render_frame(&scene, "x");
    let pixels = frame.frame.image.as_raw();

    let node = shm::node(&domain, "test")?;
    let frames = shm::frames(&node)?;
    let frame_events = shm::events(&node, service::FRAMES)?;
    let detections = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?;
    let publisher = frames.publisher_builder().initial_max_slice_len(pixels.len()).create()?;
    let notifier = frame_events.notifier_builder().create()?;
    let subscriber = detections.subscriber_builder().create()?;

    let send = |header: FrameHeader| -> Result<(), Box<dyn std::error::Error>> {
        let mut sample = publisher.loan_slice_uninit(pixels.len())?;
        *sample.user_header_mut() = header;
        sample.write_from_slice(pixels).send()?;
        notifier.notify()?;
        Ok(())
    };
    let next = |deadline: Duration| -> Result<Option<DetectionMsg>, Box<dyn std::error::Error>> {
        let start = Instant::now();
        while start.elapsed() < deadline {
            if let Some(s) = subscriber.receive()? {
                return Ok(Some(*s.payload()));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(None)
    };
    let good = |id: u64| FrameHeader::new(id, id * 1000, PixelFormat::Rgb8, &camera);

    // Until the service is up (it trains its template first), frames go unheard.
    let start = Instant::now();
    let first = loop {
        assert!(start.elapsed() < Duration::from_secs(30), "no detection from the service");
        assert!(services.all_running(), "the service died");
        send(good(1))?;
        if let Some(d) = next(Duration::from_millis(500))? {
            break d;
        }
    };
    assert_eq!(first.hole_count, 6, "the 2x1 outlet is found");
    for (hole, truth) in first.holes.iter().zip(&frame.truth.holes) {
        let e = ((hole.pixel[0] - truth.pixel[0]).powi(2) + (hole.pixel[1] - truth.pixel[1]).powi(2)).sqrt();
        assert!(e < 1.0, "hole {e} px off");
    }
    while next(Duration::from_millis(300))?.is_some() {}

    send(FrameHeader { width: 0, ..good(2) })?;
    send(FrameHeader { pixel_format: 77, ..good(3) })?;
    send(good(4))?;
    let after = next(Duration::from_secs(5))?.ok_or("no detection after the bad frames")?;
    assert_eq!(after.frame_id, 4, "the bad frames gave nothing");
    assert!(services.all_running(), "the service keeps running");
    Ok(())
}
