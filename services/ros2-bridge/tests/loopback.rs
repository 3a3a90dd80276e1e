//! The bridge's DDS side against a second ros2-client participant in this
//! process: images, camera info and clouds reach the bridge's inputs, hole
//! poses, markers, diagnostics and the debug images reach a subscriber, with
//! the ROS 2 types and QoS; the debug image is wanted only once a subscriber is there.
//!
//! LOOPBACK ONLY: both participants are built with `interfaces = ["lo"]`, i.e.
//! a rustdds DomainParticipant whose only network is 127.0.0.1 (no multicast:
//! `lo` is not multicast-capable; discovery is unicast to 127.0.0.1). The DDS
//! domain id is this test process's own (from its pid, in 1..=200).

use outlet_protocol::CameraModel;
use outlet_protocol::wire::{
    DetectionMsg, FrameHeader, HeartbeatMsg, HoleMsg, HolePosesMsg, MAX_HOLES, PixelFormat, SCHEMA_VERSION,
    WallPlaneMsg,
};
use outlet_ros2_bridge::bridge::{self, Stop};
use outlet_ros2_bridge::debug_image::{DebugImage, DebugImages};
use outlet_ros2_bridge::markers;
use outlet_ros2_bridge::msgs::{
    CameraInfo, CompressedImage, Detection3DArray, DiagnosticArray, Header, Image, Marker, MarkerArray, PointCloud2,
    PointField, PoseArray, PoseStamped, TFMessage, Time,
};
use outlet_ros2_bridge::ros2_client::QosProfile;
use outlet_ros2_bridge::{Bridge, Input, Ros2Config};
use std::sync::mpsc;
use std::time::{Duration, Instant};

fn loopback_config() -> Ros2Config {
    Ros2Config {
        domain_id: (1 + std::process::id() % 200) as u16,
        interfaces: vec!["lo".into()],
        ..Ros2Config::default()
    }
}

fn stamp() -> Header {
    Header { stamp: Time { sec: 1_700_000_000, nanosec: 5 }, frame_id: "cam".into() }
}

#[test]
fn interface_names_and_addresses_resolve_and_unknown_ones_are_refused() {
    let lo = bridge::interface_addresses(&["lo".into()]).expect("lo");
    assert_eq!(lo, vec![std::net::IpAddr::from([127, 0, 0, 1])]);
    assert_eq!(bridge::interface_addresses(&["127.0.0.1".into()]).expect("address"), lo);
    let e = bridge::interface_addresses(&["no-such-if0".into()]).expect_err("unknown");
    assert!(e.to_string().contains("no-such-if0"), "{e}");
    assert!(bridge::interface_addresses(&["10.254.254.254".into()]).is_err(), "not an address of this machine");
}

#[test]
fn messages_cross_dds_on_loopback_both_ways() {
    let config = loopback_config();
    let mut bridge = Bridge::new(&config).expect("bridge");
    let inputs = bridge.take_inputs().expect("inputs");
    let (stop_handle, stop) = Stop::new();
    let (tx, rx) = mpsc::channel();
    let runner = std::thread::spawn(move || {
        inputs.run(stop, |input| {
            let _ = tx.send(input);
        })
    });

    // The peer: another participant, loopback only as well.
    let context = bridge::context(&config).expect("peer context");
    let mut peer = bridge::node(&context, "test_peer").expect("peer node");
    let topics = &config.topics;
    let sensor = QosProfile::subscription_default();
    let image_pub = bridge::publisher::<Image>(&mut peer, &topics.image, &sensor).expect("image publisher");
    let compressed_pub =
        bridge::publisher::<CompressedImage>(&mut peer, &topics.image_compressed, &sensor).expect("compressed");
    let info_pub = bridge::publisher::<CameraInfo>(&mut peer, &topics.camera_info, &bridge::RESULT_QOS).expect("info");
    let cloud_pub = bridge::publisher::<PointCloud2>(&mut peer, &topics.points, &bridge::RESULT_QOS).expect("cloud");
    let holes_sub = bridge::subscription::<PoseArray>(&mut peer, &topics.holes, &bridge::RESULT_QOS).expect("holes");
    let pose_sub = bridge::subscription::<PoseStamped>(&mut peer, &topics.pose, &bridge::RESULT_QOS).expect("pose");
    let diag_sub =
        bridge::subscription::<DiagnosticArray>(&mut peer, &topics.diagnostics, &bridge::RESULT_QOS).expect("diag");
    let tf_sub = bridge::subscription::<TFMessage>(&mut peer, &topics.tf, &bridge::TF_QOS).expect("tf");
    let det_sub =
        bridge::subscription::<Detection3DArray>(&mut peer, &topics.detections, &bridge::RESULT_QOS).expect("det");
    let marker_sub =
        bridge::subscription::<MarkerArray>(&mut peer, &topics.markers, &bridge::RESULT_QOS).expect("markers");
    // Nobody watches the debug image yet: the bridge would make none.
    assert!(!bridge.debug_subscribers().any());
    // The debug images, read best-effort as image viewers often do.
    let debug_sub = bridge::subscription::<Image>(&mut peer, &topics.debug_image, &sensor).expect("debug image");
    let debug_jpeg_sub =
        bridge::subscription::<CompressedImage>(&mut peer, &topics.debug_image_compressed, &sensor).expect("jpeg");

    // A small PNG on image_transport's compressed topic: decoded to rgb8.
    let small = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([(x * 4) as u8, (y * 5) as u8, 77]));
    let mut png = Vec::new();
    small.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).expect("png");
    let compressed = CompressedImage { header: stamp(), format: "png".into(), data: png };
    let image = Image {
        header: stamp(),
        height: 480,
        width: 640,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 1920,
        data: (0..1920 * 480).map(|v| (v % 251) as u8).collect(),
    };
    let info = CameraInfo {
        header: stamp(),
        height: 480,
        width: 640,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0],
        ..CameraInfo::default()
    };
    let cloud = PointCloud2 {
        header: stamp(),
        height: 1,
        width: 3,
        fields: ["x", "y", "z"]
            .iter()
            .enumerate()
            .map(|(k, n)| PointField { name: n.to_string(), offset: 4 * k as u32, datatype: 7, count: 1 })
            .collect(),
        is_bigendian: false,
        point_step: 12,
        row_step: 36,
        data: (0..9).flat_map(|v| (v as f32).to_le_bytes()).collect(),
        is_dense: true,
    };
    let mut positions_m = [[0.0; 3]; MAX_HOLES];
    positions_m[0] = [0.01, 0.02, 0.5];
    positions_m[1] = [0.03, 0.02, 0.5];
    let mut poses = HolePosesMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 2,
        frame_id: 9,
        capture_time_ns: 1_700_000_000_000_000_005,
        published_ns: 0,
        mode: 3,
        status: 1,
        outlier_mask: 0,
        reserved: 0,
        rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        translation_m: [0.02, 0.02, 0.5],
        kinds: [0; MAX_HOLES],
        positions_m,
        covariances_m2: [[0.0; 9]; MAX_HOLES],
    };
    poses.kinds[..2].copy_from_slice(&[1, 2]);
    poses.covariances_m2[1] = [4e-8, 1e-9, 0.0, 1e-9, 4e-8, 0.0, 0.0, 0.0, 9e-8];
    let mut scores = [0.0; MAX_HOLES];
    scores[..2].copy_from_slice(&[0.9, 0.8]);
    let plane = WallPlaneMsg {
        schema_version: SCHEMA_VERSION,
        inliers: 500,
        frame_id: 9,
        capture_time_ns: poses.capture_time_ns,
        normal: [0.0, 0.0, 1.0],
        distance_m: 0.505,
        tangent: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        covariance: [0.0; 9],
    };
    let debug_image = debug_image_of(&poses);
    let mut beat = HeartbeatMsg::new("detector", 1, 0);
    beat.published_ns = 1_700_000_000_000_000_000;
    beat.output_rate_hz = 10.0;

    let (mut got_image, mut got_info, mut got_cloud) = (None, None, None);
    let (mut got_holes, mut got_pose, mut got_diag) = (None, None, None);
    let (mut got_tf, mut got_det, mut got_decoded) = (None, None, None);
    let (mut got_markers, mut got_debug, mut got_jpeg) = (None, None, None);
    let started = Instant::now();
    while [got_image.is_none(), got_info.is_none(), got_cloud.is_none(), got_decoded.is_none()].iter().any(|&b| b)
        || got_holes.is_none()
        || got_pose.is_none()
        || got_diag.is_none()
        || got_tf.is_none()
        || got_det.is_none()
        || got_markers.is_none()
        || got_debug.is_none()
        || got_jpeg.is_none()
    {
        assert!(started.elapsed() < Duration::from_secs(30), "nothing crossed in 30 s");
        // Discovery takes a moment; until both sides are matched, send again.
        let _ = image_pub.publish(image.clone());
        let _ = compressed_pub.publish(compressed.clone());
        let _ = info_pub.publish(info.clone());
        let _ = cloud_pub.publish(cloud.clone());
        bridge.publish_poses(&poses, Some(&scores), Some(&plane)).expect("poses");
        // As the sidecar does: a debug image only once someone subscribes.
        let watching = bridge.debug_subscribers();
        if watching.any() {
            bridge.publish_debug_image(debug_image.clone(), watching).expect("debug image");
        }
        let array = outlet_ros2_bridge::convert::diagnostics_of(&[beat], beat.published_ns, 3_000_000_000, "test");
        bridge.publish_diagnostics(array).expect("diagnostics");
        let wait = Instant::now();
        while wait.elapsed() < Duration::from_millis(200) {
            match rx.recv_timeout(Duration::from_millis(20)) {
                Ok(Input::Image(m)) if m.width == 64 => got_decoded = Some(m),
                Ok(Input::Image(m)) => got_image = Some(m),
                Ok(Input::CameraInfo(m)) => got_info = Some(*m),
                Ok(Input::Points(m)) => got_cloud = Some(m),
                Ok(Input::Undecodable { topic, reason }) => panic!("{topic}: {reason}"),
                Err(_) => {}
            }
            got_holes = got_holes.or(holes_sub.take().ok().flatten().map(|(m, _)| m));
            got_pose = got_pose.or(pose_sub.take().ok().flatten().map(|(m, _)| m));
            got_diag = got_diag.or(diag_sub.take().ok().flatten().map(|(m, _)| m));
            got_tf = got_tf.or(tf_sub.take().ok().flatten().map(|(m, _)| m));
            got_det = got_det.or(det_sub.take().ok().flatten().map(|(m, _)| m));
            got_markers = got_markers.or(marker_sub.take().ok().flatten().map(|(m, _)| m));
            got_debug = got_debug.or(debug_sub.take().ok().flatten().map(|(m, _)| m));
            got_jpeg = got_jpeg.or(debug_jpeg_sub.take().ok().flatten().map(|(m, _)| m));
        }
    }
    assert_eq!(got_image.as_ref(), Some(&image), "a 900 kB image crosses whole");
    let decoded = got_decoded.expect("the compressed image");
    assert_eq!((decoded.width, decoded.height, decoded.encoding.as_str(), decoded.step), (64, 48, "rgb8", 192));
    assert_eq!(decoded.header, compressed.header);
    assert_eq!(decoded.data, small.into_raw(), "the PNG's pixels, exactly");
    assert_eq!(got_info.as_ref(), Some(&info));
    assert_eq!(got_cloud.as_ref(), Some(&cloud));
    let holes = got_holes.expect("holes");
    assert_eq!(holes.header.frame_id, "camera_optical_frame");
    assert_eq!(holes.header.stamp, Time { sec: 1_700_000_000, nanosec: 5 });
    assert_eq!(holes.poses.len(), 2);
    assert_eq!(holes.poses[1].position.x, 0.03);
    assert_eq!(holes.poses[1].orientation.w, 1.0);
    assert_eq!(got_pose.expect("pose").pose.position.x, 0.02);
    let diag = got_diag.expect("diagnostics");
    assert_eq!(diag.status[0].name, "outlet/detector");
    let tf = got_tf.expect("tf");
    let children: Vec<&str> = tf.transforms.iter().map(|t| t.child_frame_id.as_str()).collect();
    assert_eq!(children, ["outlet", "outlet/hole_0", "outlet/hole_1"]);
    assert_eq!(tf.transforms[0].header, holes.header);
    assert_eq!(tf.transforms[2].transform.translation.x, 0.03);
    let det = got_det.expect("detections");
    assert_eq!(det.header, holes.header);
    let classes: Vec<(&str, f64)> = det
        .detections
        .iter()
        .map(|d| (d.results[0].hypothesis.class_id.as_str(), d.results[0].hypothesis.score))
        .collect();
    assert_eq!(classes, [("power", 0.9), ("ground", 0.8)]);
    let c = &det.detections[1].results[0].pose.covariance;
    assert_eq!([c[0], c[1], c[7], c[14], c[21]], [4e-8, 1e-9, 4e-8, 9e-8, 1e6]);

    // The markers: a sphere at each published hole position, the plate, the wall.
    let m = got_markers.expect("markers");
    assert_eq!(m.markers[0].action, Marker::DELETEALL);
    let spheres: Vec<&Marker> = m.markers.iter().filter(|m| m.ns == markers::HOLES_NS).collect();
    assert_eq!(spheres.len(), 2);
    for (sphere, pose) in spheres.iter().zip(&holes.poses) {
        assert_eq!(sphere.type_, Marker::SPHERE);
        assert_eq!(sphere.pose.position, pose.position);
        assert_eq!(sphere.header, holes.header);
    }
    // Hole 1's covariance: sigmas 0.2 (x, y) and 0.3 mm (z) about, 3 sigma each way.
    let mut d = [spheres[1].scale.x, spheres[1].scale.y, spheres[1].scale.z];
    d.sort_by(f64::total_cmp);
    assert!((d[2] - 6.0 * 9e-8f64.sqrt()).abs() < 1e-9, "{d:?}");
    assert_eq!(spheres[0].color, markers::kind_color(outlet_protocol::HoleKind::Power));
    assert_eq!(spheres[1].color, markers::kind_color(outlet_protocol::HoleKind::Ground));
    assert!(m.markers.iter().any(|m| m.ns == markers::PLATE_NS && m.type_ == Marker::CUBE));
    let wall = m.markers.iter().find(|m| m.ns == markers::WALL_NS).expect("the wall");
    assert_eq!(wall.pose.position.z, 0.505);

    // The debug image, exactly as drawn, and its JPEG.
    let debug = got_debug.expect("debug image");
    assert_eq!((debug.width, debug.height, debug.encoding.as_str(), debug.step), (640, 480, "rgb8", 1920));
    assert_eq!(debug.header, holes.header, "the frame's capture time, the camera frame");
    assert_eq!(debug.data, debug_image.rgb.as_raw().clone());
    let jpeg = got_jpeg.expect("compressed debug image");
    assert_eq!(jpeg.header, holes.header);
    let decoded = outlet_ros2_bridge::convert::image_of_compressed(&jpeg).expect("a JPEG");
    assert_eq!((decoded.width, decoded.height), (640, 480));

    stop_handle.stop();
    runner.join().expect("the inputs thread ends on stop");
}

/// The debug image of `poses`' frame: a grey 640x480 frame, a detection of
/// its two holes at their pixels, joined and drawn as the sidecar does.
fn debug_image_of(poses: &HolePosesMsg) -> DebugImage {
    let camera = CameraModel::new(640, 480, [525.0, 525.0, 319.5, 239.5], [0.0; 5]).expect("camera");
    let header = FrameHeader::new(poses.frame_id, poses.capture_time_ns, PixelFormat::Rgb8, &camera);
    let mut debug = DebugImages::default();
    debug.add_frame(&header, &vec![90; 640 * 480 * 3]).expect("frame");
    let mut holes = [HoleMsg::default(); MAX_HOLES];
    for (k, hole) in holes.iter_mut().enumerate().take(2) {
        let [x, y, z] = poses.positions_m[k];
        let pixel = camera.project(&nalgebra::Point3::new(x, y, z)).expect("in front");
        *hole = HoleMsg {
            kind: poses.kinds[k],
            refined: 1,
            pixel: [pixel.x, pixel.y],
            score: 0.9,
            sigma_px: 0.3,
            shape: [0.0; 3],
        };
    }
    let detection = DetectionMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 2,
        frame_id: poses.frame_id,
        capture_time_ns: poses.capture_time_ns,
        score: 2,
        reserved: 0,
        detect_ms: 1.0,
        width: 640,
        height: 480,
        intrinsics: [camera.fx, camera.fy, camera.cx, camera.cy],
        distortion: camera.distortion,
        holes,
    };
    assert!(debug.detection(&detection).is_empty(), "it waits for the poses");
    let image = debug.poses(poses).expect("joined");
    assert_ne!(image.rgb.as_raw(), &vec![90; 640 * 480 * 3], "something is drawn");
    image
}
