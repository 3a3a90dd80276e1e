//! A rendered frame crosses iceoryx2 shared memory with its header, arrives
//! intact, passes the header checks, and the outlet is found in it.

use iceoryx2::prelude::*;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::CameraModel;
use outlet_protocol::wire::{FrameHeader, PixelFormat, WireError};

#[test]
fn a_rendered_frame_crosses_shared_memory_intact() -> Result<(), Box<dyn std::error::Error>> {
    let camera = CameraModel::default_vga();
    let scene = outlet_sim::sample_scene("orange2x1", 3, 0, &camera)?;
    let frame = outlet_sim::render_frame(&scene, "x");
    let pixels = frame.frame.image.as_raw();

    let node = NodeBuilder::new().create::<ipc::Service>()?;
    // A name of this process's own: tests may run side by side.
    let name = format!("outlet/test/frames/{}", std::process::id());
    let service = node
        .service_builder(&name.as_str().try_into()?)
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .open_or_create()?;
    let publisher = service.publisher_builder().initial_max_slice_len(pixels.len()).create()?;
    let subscriber = service.subscriber_builder().create()?;

    let mut sample = publisher.loan_slice_uninit(pixels.len())?;
    *sample.user_header_mut() = FrameHeader::new(42, 1_700_000_000_000_000_000, PixelFormat::Rgb8, &camera);
    sample.write_from_slice(pixels).send()?;

    let received = subscriber.receive()?.ok_or("no sample arrived")?;
    let (format, camera_rx) = received.user_header().validate(received.payload().len())?;
    assert_eq!(format, PixelFormat::Rgb8);
    assert_eq!(camera_rx, camera);
    assert_eq!(received.user_header().frame_id, 42);
    assert_eq!(received.payload(), pixels.as_slice());

    // The detector reads the pixels where they lie in shared memory's copy.
    let image = image::RgbImage::from_raw(camera.width, camera.height, received.payload().to_vec()).ok_or("size")?;
    let template = outlet::templates::builtin("2x1")?;
    let report = Detector::new(template, DetectorParams::default()).detect(&image, Some(&camera_rx));
    assert!(report.detection.is_some(), "the outlet is found in the frame that crossed");

    // A header that lies about its size is refused, not trusted.
    let mut short = publisher.loan_slice_uninit(16)?;
    *short.user_header_mut() = FrameHeader::new(43, 0, PixelFormat::Rgb8, &camera);
    short.write_from_fn(|_| 0).send()?;
    let bad = subscriber.receive()?.ok_or("no sample arrived")?;
    assert!(matches!(bad.user_header().validate(bad.payload().len()), Err(WireError::ShortFrame { frame_id: 43, .. })));
    Ok(())
}
