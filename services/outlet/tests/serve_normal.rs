//! `outlet serve normal` as a real process: clouds in through shared memory,
//! wall planes out; an all-NaN cloud is rejected and the service goes on.

mod common;

use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{CloudHeader, SCHEMA_VERSION, WallPlaneMsg, service};
use std::time::{Duration, Instant};

#[test]
fn clouds_in_planes_out_and_bad_clouds_are_rejected() -> Result<(), Box<dyn std::error::Error>> {
    let domain = common::domain("servenorma");
    let mut services = common::Services::start(&domain, &[&["normal"]])?;
    let scene = outlet_sim::sample_scene("white2x2", 5, 0, &CameraModel::default_vga())?;
    let frame = outlet_sim::render_frame(&scene, "x");
    let flat: Vec<f32> = frame.cloud.iter().flatten().copied().collect();

    let node = shm::node(&domain, "test")?;
    let clouds = shm::clouds(&node)?;
    let cloud_events = shm::events(&node, service::CLOUDS)?;
    let planes = shm::messages::<WallPlaneMsg>(&node, service::PLANES)?;
    let publisher = clouds.publisher_builder().initial_max_slice_len(flat.len()).create()?;
    let notifier = cloud_events.notifier_builder().create()?;
    let subscriber = planes.subscriber_builder().create()?;

    let send = |frame_id: u64, values: &[f32]| -> Result<(), Box<dyn std::error::Error>> {
        let mut sample = publisher.loan_slice_uninit(values.len())?;
        *sample.user_header_mut() = CloudHeader {
            schema_version: SCHEMA_VERSION,
            reserved: 0,
            frame_id,
            capture_time_ns: frame_id * 1000,
            points: (values.len() / 3) as u64,
        };
        sample.write_from_slice(values).send()?;
        notifier.notify()?;
        Ok(())
    };
    let next_plane = |deadline: Duration| -> Result<Option<WallPlaneMsg>, Box<dyn std::error::Error>> {
        let start = Instant::now();
        while start.elapsed() < deadline {
            if let Some(s) = subscriber.receive()? {
                return Ok(Some(*s.payload()));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(None)
    };

    // Until the service is up, clouds go unheard: send until a plane answers.
    let start = Instant::now();
    let first = loop {
        assert!(start.elapsed() < Duration::from_secs(20), "no plane from the service");
        assert!(services.all_running(), "the service died");
        send(1, &flat)?;
        if let Some(p) = next_plane(Duration::from_millis(300))? {
            break p;
        }
    };
    let truth = frame.truth.wall_plane;
    let n = nalgebra::Vector3::from(first.normal);
    let angle = n.dot(&nalgebra::Vector3::from(truth.normal)).abs().min(1.0).acos().to_degrees();
    assert!(angle < 0.5 && (first.distance_m - truth.distance_m).abs() < 0.001, "{angle} deg, {} m", first.distance_m);
    while next_plane(Duration::from_millis(200))?.is_some() {}

    // An all-NaN cloud is rejected; the next good one still gets its plane.
    send(2, &vec![f32::NAN; flat.len()])?;
    send(3, &flat)?;
    let after = next_plane(Duration::from_secs(5))?.ok_or("no plane after the bad cloud")?;
    assert_eq!(after.frame_id, 3, "the all-NaN cloud gave no plane");
    assert!(services.all_running(), "the service keeps running");
    Ok(())
}
