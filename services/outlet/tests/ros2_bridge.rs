//! `outlet serve ros2-bridge` as a process between ROS 2 and the services: a
//! ROS 2 participant in this test plays the camera driver (sensor_msgs/Image,
//! CameraInfo, PointCloud2 of a rendered scene) and the consumer of the results
//! (geometry_msgs/PoseArray on /outlet/holes, PoseStamped, DiagnosticArray);
//! detector, normal and pose run as processes on iceoryx2 in between.
//!
//! LOOPBACK ONLY: every DDS participant here is confined to the loopback
//! interface. The bridge runs with `[ros2] interfaces = ["lo"]` and this test's
//! participant is built the same way (`outlet_ros2_bridge::bridge::context`): a
//! rustdds DomainParticipant whose only network is 127.0.0.1, with no multicast
//! (`lo` is not multicast-capable) and discovery by unicast to 127.0.0.1. Each
//! test has its own DDS domain id (from the process id, in 1..=200) and its own
//! iceoryx2 domain.

mod common;

use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{HeartbeatMsg, PixelFormat};
use outlet_ros2_bridge::Ros2Config;
use outlet_ros2_bridge::bridge::{self, SENSOR_QOS};
use outlet_ros2_bridge::convert::{camera_info_of, cloud_of, image_of, ns_to_time};
use outlet_ros2_bridge::msgs::{CameraInfo, DiagnosticArray, Header, Image, PointCloud2, PoseArray, PoseStamped};
use outlet_ros2_bridge::ros2_client::dds::{Context, Node, Publisher};
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

type TestResult = Result<(), Box<dyn std::error::Error>>;

fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// A DDS domain id of this test process alone, one per test (`offset` 0 or 1), in 1..=200.
fn dds_domain(offset: u32) -> u16 {
    (1 + (std::process::id() % 100) * 2 + offset) as u16
}

/// The sidecar's configuration for a test: its DDS domain, loopback only.
fn config_file(dir: &tempfile::TempDir, domain: &str, dds_domain: u16) -> std::io::Result<PathBuf> {
    let path = dir.path().join("outlet.toml");
    std::fs::write(
        &path,
        format!(
            "domain = \"{domain}\"\nheartbeat_ms = 200\n\n[pose]\n# A detection waits for the wall plane of its \
             own frame.\nplane_wait_ms = 2000.0\n\n[ros2]\ndomain_id = {dds_domain}\n# Loopback only.\ninterfaces = \
             [\"lo\"]\n"
        ),
    )?;
    Ok(path)
}

/// The test's ROS 2 side: a camera driver and a consumer, on loopback only.
struct Peer {
    image: Publisher<Image>,
    info: Publisher<CameraInfo>,
    points: Publisher<PointCloud2>,
    holes: outlet_ros2_bridge::ros2_client::dds::Subscription<PoseArray>,
    pose: outlet_ros2_bridge::ros2_client::dds::Subscription<PoseStamped>,
    diagnostics: outlet_ros2_bridge::ros2_client::dds::Subscription<DiagnosticArray>,
    _node: Node,
    _context: Context,
}

impl Peer {
    fn new(dds_domain: u16) -> Result<Self, Box<dyn std::error::Error>> {
        // The same confinement as the bridge's: the loopback interface only.
        let config = Ros2Config { domain_id: dds_domain, interfaces: vec!["lo".into()], ..Ros2Config::default() };
        let context = bridge::context(&config)?;
        let mut node = bridge::node(&context, "outlet_test_camera")?;
        let t = &config.topics;
        Ok(Self {
            // Images as camera drivers send them: best-effort.
            image: bridge::publisher(&mut node, &t.image, &SENSOR_QOS)?,
            info: bridge::publisher(&mut node, &t.camera_info, &bridge::RESULT_QOS)?,
            points: bridge::publisher(&mut node, &t.points, &bridge::RESULT_QOS)?,
            holes: bridge::subscription(&mut node, &t.holes, &bridge::RESULT_QOS)?,
            pose: bridge::subscription(&mut node, &t.pose, &bridge::RESULT_QOS)?,
            diagnostics: bridge::subscription(&mut node, &t.diagnostics, &bridge::RESULT_QOS)?,
            _node: node,
            _context: context,
        })
    }
}

fn header(stamp_ns: u64) -> Header {
    Header { stamp: ns_to_time(stamp_ns), frame_id: "camera_optical_frame".into() }
}

#[test]
fn images_from_ros2_give_hole_poses_on_ros2_within_a_millimetre() -> TestResult {
    let domain = common::domain("ros2-e2e");
    let dds_domain = dds_domain(0);
    let dir = tempfile::tempdir()?;
    let config = config_file(&dir, &domain, dds_domain)?;
    let config = config.to_str().ok_or("config path")?;
    let mut services = common::Services::start(
        &domain,
        &[
            &["--config", config, "ros2-bridge"],
            &["--config", config, "detector", "--template", "2x1"],
            &["--config", config, "normal"],
            &["--config", config, "pose", "--template", "2x1"],
        ],
    )?;
    let camera = CameraModel::default_vga();
    let scene = common::frontal_scene("fw_2x1white", &camera, 25.0)?;
    let frame = outlet_sim::render_frame(&scene, "x");
    let truth: Vec<[f64; 3]> = frame.truth.holes.iter().filter_map(|h| h.position_m).collect();
    assert_eq!(truth.len(), 6);
    let peer = Peer::new(dds_domain)?;

    let started = Instant::now();
    let mut sent_stamps = Vec::new();
    let mut answers = Vec::new();
    let (holes, pose) = 'found: loop {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no PoseArray within 1 mm in 60 s; answers (stamp, worst error mm): {answers:?}"
        );
        assert!(services.all_running(), "a service died");
        // One capture: camera info, the cloud first (the pose service joins a
        // detection with the plane closest in time), then the image, bgr8 with
        // padded rows, all with the same stamp.
        let stamp = now_ns();
        sent_stamps.push(stamp);
        let _ = peer.info.publish(camera_info_of(&camera, header(stamp)));
        let _ = peer.points.publish(cloud_of(header(stamp), &frame.cloud));
        std::thread::sleep(Duration::from_millis(50));
        let image = image_of(header(stamp), 640, 480, frame.frame.image.as_raw(), PixelFormat::Bgr8, 640 * 3 + 16)
            .ok_or("image")?;
        let _ = peer.image.publish(image);
        let wait = Instant::now();
        while wait.elapsed() < Duration::from_millis(1500) {
            while let Ok(Some((m, _))) = peer.holes.take() {
                let worst = m
                    .poses
                    .iter()
                    .zip(&truth)
                    .map(|(p, t)| {
                        ((p.position.x - t[0]).powi(2) + (p.position.y - t[1]).powi(2) + (p.position.z - t[2]).powi(2))
                            .sqrt()
                    })
                    .fold(0.0, f64::max);
                answers.push((m.header.stamp, worst * 1e3));
                if m.poses.len() == truth.len() && worst < 0.001 {
                    // Its PoseStamped comes with it, the same stamp.
                    let deadline = Instant::now() + Duration::from_secs(5);
                    while Instant::now() < deadline {
                        if let Ok(Some((p, _))) = peer.pose.take()
                            && p.header.stamp == m.header.stamp
                        {
                            break 'found (m, p);
                        }
                        std::thread::sleep(Duration::from_millis(10));
                    }
                    return Err("a PoseArray without its PoseStamped".into());
                }
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    eprintln!("answers (stamp, worst hole error in mm): {answers:?}");
    // Stamped with the capture time of an image we sent, in the configured frame.
    assert!(sent_stamps.iter().any(|&s| ns_to_time(s) == holes.header.stamp), "stamp {:?}", holes.header.stamp);
    assert_eq!(holes.header.frame_id, "camera_optical_frame");
    assert_eq!(pose.header.frame_id, "camera_optical_frame");
    // Every hole has the outlet's orientation, a unit quaternion.
    let q = pose.pose.orientation;
    assert!(((q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) - 1.0).abs() < 1e-9);
    assert!(holes.poses.iter().all(|p| p.orientation == q));

    // Diagnostics from every service's heartbeat, the bridge's included.
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut names = std::collections::BTreeSet::new();
    while Instant::now() < deadline && names.len() < 4 {
        while let Ok(Some((d, _))) = peer.diagnostics.take() {
            names.extend(d.status.iter().map(|s| s.name.clone()));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    for name in ["outlet/ros2-bridge", "outlet/detector", "outlet/normal", "outlet/pose"] {
        assert!(names.contains(name), "{name} missing from the diagnostics: {names:?}");
    }
    Ok(())
}

/// The heartbeats of `service` waiting: the newest kept, every rejection reason noted.
fn take_beats(
    sub: &iceoryx2::port::subscriber::Subscriber<iceoryx2::prelude::ipc::Service, HeartbeatMsg, ()>,
    service: &str,
    newest: &mut Option<HeartbeatMsg>,
    reasons: &mut std::collections::BTreeSet<String>,
) {
    while let Ok(Some(s)) = sub.receive() {
        if s.payload().service_name() == service {
            reasons.insert(s.payload().last_rejection().to_string());
            *newest = Some(*s.payload());
        }
    }
}

#[test]
fn malformed_images_are_counted_as_rejected_and_the_bridge_goes_on() -> TestResult {
    let domain = common::domain("ros2-reject");
    let dds_domain = dds_domain(1);
    let dir = tempfile::tempdir()?;
    let config = config_file(&dir, &domain, dds_domain)?;
    let config = config.to_str().ok_or("config path")?;
    let mut services = common::Services::start(&domain, &[&["--config", config, "ros2-bridge"]])?;
    let node = shm::node(&domain, "test")?;
    let beats = shm::heartbeats(&node)?.subscriber_builder().create()?;
    let frames = shm::frames(&node)?.subscriber_builder().create()?;
    let peer = Peer::new(dds_domain)?;
    let camera = CameraModel::default_vga();
    let rgb = vec![128u8; 640 * 480 * 3];

    let started = Instant::now();
    let mut beat = None;
    let mut reasons = std::collections::BTreeSet::new();
    let (mut rejected_encoding, mut rejected_short, mut good_frame) = (false, false, None);
    while !(rejected_encoding && rejected_short && good_frame.is_some()) {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "in 30 s: rejections {reasons:?}, a frame {good_frame:?}; the bridge's last heartbeat {beat:?}"
        );
        assert!(services.all_running(), "the bridge died");
        let stamp = now_ns();
        let _ = peer.info.publish(camera_info_of(&camera, header(stamp)));
        std::thread::sleep(Duration::from_millis(20));
        let good = image_of(header(stamp), 640, 480, &rgb, PixelFormat::Rgb8, 1920).ok_or("image")?;
        let yuv = Image { encoding: "yuv422".into(), step: 1280, ..good.clone() };
        let mut short = good.clone();
        short.data.truncate(1920 * 100);
        // Each bad one, then a good one after it: the bridge must go on.
        // Each bad one a heartbeat period (200 ms) before the next, then a good
        // one: the bridge must go on.
        for (image, good) in [(yuv, false), (short, false), (good, true)] {
            let _ = peer.image.publish(image);
            std::thread::sleep(Duration::from_millis(300));
            while let Ok(Some(f)) = frames.receive() {
                if good {
                    good_frame = Some((*f.user_header(), f.payload().len()));
                }
            }
        }
        take_beats(&beats, "ros2-bridge", &mut beat, &mut reasons);
        rejected_encoding = reasons.iter().any(|r| r.contains("yuv422"));
        rejected_short = reasons.iter().any(|r| r.contains("bytes of data"));
    }
    let (header, len) = good_frame.ok_or("frame")?;
    assert_eq!((header.width, header.height, header.stride), (640, 480, 1920));
    assert_eq!(PixelFormat::from_code(header.pixel_format), Some(PixelFormat::Rgb8));
    assert_eq!(header.intrinsics, [camera.fx, camera.fy, camera.cx, camera.cy]);
    assert!(header.validate(len).is_ok());
    let b = beat.ok_or("heartbeat")?;
    assert!(b.rejected >= 2 && b.outputs >= 1, "{b:?}");
    assert!(services.all_running(), "the bridge keeps serving");
    Ok(())
}
