use super::*;
use outlet_protocol::wire::{HoleMsg, MAX_HOLES, PixelFormat};
use outlet_ros2_bridge::msgs::Time;
use std::collections::BTreeMap;
use std::io::Cursor;

fn camera() -> CameraModel {
    CameraModel::new(6, 4, [300.0, 301.0, 2.5, 1.5], [-0.2, 0.05, 0.001, -0.001, 0.0]).expect("camera")
}

fn frame(id: u64, format: PixelFormat, stride: u32) -> (FrameHeader, Vec<u8>) {
    let mut h = FrameHeader::new(id, 1_000_000_000 * id + 5, format, &camera());
    h.stride = stride;
    (h, (0..stride * 4).map(|v| (v * 7 + id as u32) as u8).collect())
}

fn cloud(id: u64) -> (CloudHeader, Vec<f32>) {
    let xyz = vec![0.1, -0.2, 0.5, f32::NAN, f32::NAN, f32::NAN, 0.3, 0.0, id as f32];
    let h = CloudHeader {
        schema_version: SCHEMA_VERSION,
        reserved: 0,
        frame_id: id,
        capture_time_ns: 1_000_000_000 * id + 5,
        points: 3,
    };
    (h, xyz)
}

fn hole_poses() -> HolePosesMsg {
    let mut positions_m = [[0.0; 3]; MAX_HOLES];
    positions_m[0] = [0.01, 0.02, 0.4];
    positions_m[1] = [0.02, 0.02, 0.4];
    let mut covariances_m2 = [[0.0; 9]; MAX_HOLES];
    covariances_m2[1][0] = 1e-8;
    HolePosesMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 2,
        frame_id: 2,
        capture_time_ns: 2_000_000_005,
        published_ns: 2_050_000_000,
        mode: 3,
        status: pose_status::OK,
        outlier_mask: 0b10,
        reserved: 0,
        rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        translation_m: [0.0, 0.0, 0.4],
        kinds: [1; MAX_HOLES],
        positions_m,
        covariances_m2,
    }
}

/// A recording of two frames (rgb8 with padded rows, mono8), two clouds and one
/// of each result.
fn recorded() -> Vec<u8> {
    let mut r = Recorder::new(Cursor::new(Vec::new()), &Ros2Config::default()).expect("recorder");
    let (c1, xyz1) = cloud(1);
    r.cloud(&c1, &xyz1).expect("cloud");
    let (f1, p1) = frame(1, PixelFormat::Rgb8, 20);
    r.frame(&f1, &p1).expect("frame");
    let (f2, p2) = frame(2, PixelFormat::Mono8, 6);
    r.frame(&f2, &p2).expect("frame");
    let (c2, xyz2) = cloud(2);
    r.cloud(&c2, &xyz2).expect("cloud");
    r.hole_poses(&hole_poses()).expect("poses");
    let detection = DetectionMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 1,
        frame_id: 2,
        capture_time_ns: 2_000_000_005,
        score: 6,
        reserved: 0,
        detect_ms: 12.0,
        width: 6,
        height: 4,
        intrinsics: [300.0, 301.0, 2.5, 1.5],
        distortion: [0.0; 5],
        holes: [HoleMsg { kind: 2, refined: 1, pixel: [3.0, 2.0], score: 0.9, sigma_px: 0.1, shape: [0.0; 3] };
            MAX_HOLES],
    };
    r.detection(&detection).expect("detection");
    r.heartbeat(&HeartbeatMsg::new("detector", 42, 7)).expect("heartbeat");
    assert_eq!(r.counts, [2, 2, 1, 1, 0, 1]);
    r.finish().expect("finish").into_inner()
}

fn channels(bytes: &[u8]) -> Result<Channels> {
    choose_channels(&scan(bytes, "mem.mcap")?, &TopicChoice::default(), "mem.mcap")
}

fn samples(bytes: &[u8], channels: &Channels) -> Result<Vec<(u64, Sample)>> {
    let mut p = Player::new(bytes, "mem.mcap", channels);
    let mut out = Vec::new();
    while let Some(s) = p.next_sample()? {
        out.push(s);
    }
    Ok(out)
}

#[test]
fn frames_and_clouds_come_back_as_they_were_recorded() {
    let bytes = recorded();
    let channels = channels(&bytes).expect("channels");
    assert_eq!(channels.image, "/camera/image_raw");
    assert_eq!(channels.camera_info, "/camera/camera_info");
    assert_eq!(channels.points.as_deref(), Some("/camera/points"));
    let got = samples(&bytes, &channels).expect("samples");
    assert_eq!(got.len(), 4);
    let (f1, p1) = frame(1, PixelFormat::Rgb8, 20);
    let (f2, p2) = frame(2, PixelFormat::Mono8, 6);
    assert_eq!(got[1], (1_000_000_005, Sample::Frame { header: f1, pixels: p1 }));
    assert_eq!(got[2], (2_000_000_005, Sample::Frame { header: f2, pixels: p2 }));
    for (k, at) in [(1, 0), (2, 3)] {
        let Sample::Cloud { header, xyz } = &got[at].1 else { panic!("sample {at} is not a cloud") };
        let (want, values) = cloud(k);
        assert_eq!(*header, want);
        assert_eq!(xyz.len(), values.len());
        assert!(xyz.iter().zip(&values).all(|(a, b)| a == b || (a.is_nan() && b.is_nan())));
    }
}

#[test]
fn results_are_json_with_a_schema() {
    let bytes = recorded();
    let mut topics = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).expect("stream") {
        let m = m.expect("message");
        let schema = m.channel.schema.as_ref().expect("every channel has a schema");
        if m.channel.message_encoding == "json" {
            assert_eq!(schema.encoding, "jsonschema");
            serde_json::from_slice::<Value>(&schema.data).expect("the schema is JSON");
            topics.insert(m.channel.topic.clone(), serde_json::from_slice::<Value>(&m.data).expect("JSON"));
        } else {
            assert_eq!((schema.encoding.as_str(), m.channel.message_encoding.as_str()), ("ros2msg", "cdr"));
            assert_eq!(m.log_time, m.publish_time);
        }
    }
    let poses = &topics[topic::HOLE_POSES];
    assert_eq!(poses["status"], "ok");
    assert_eq!(poses["mode"], "plane");
    assert_eq!(poses["holes"][1]["covariance_m2"][0], 1e-8);
    assert_eq!(poses["holes"][1]["outlier"], true);
    assert_eq!(poses["holes"][0]["outlier"], false);
    let detection = &topics[topic::DETECTIONS];
    assert_eq!(detection["holes"].as_array().map(Vec::len), Some(1));
    assert_eq!(detection["holes"][0]["kind"], "ground");
    let beat = &topics[topic::HEARTBEAT];
    assert_eq!((beat["service"].as_str(), beat["pid"].as_u64()), (Some("detector"), Some(42)));
    assert!(beat["latency_p50_ms"].is_null(), "NaN is null");
}

/// An MCAP of `channels` (topic, schema name, message encoding) holding
/// `messages` (channel index, bytes), logged at 0, 1, 2...
fn bag(channels: &[(&str, &str, &str)], messages: &[(usize, Vec<u8>)]) -> Vec<u8> {
    let mut w = mcap::Writer::new(Cursor::new(Vec::new())).expect("writer");
    let ids: Vec<u16> = channels
        .iter()
        .map(|(topic, schema, encoding)| {
            let s = w.add_schema(schema, "ros2msg", b"").expect("schema");
            w.add_channel(s, topic, encoding, &BTreeMap::new()).expect("channel")
        })
        .collect();
    for (k, (channel, data)) in messages.iter().enumerate() {
        let header = MessageHeader { channel_id: ids[*channel], sequence: 0, log_time: k as u64, publish_time: 0 };
        w.write_to_known_channel(&header, data).expect("message");
    }
    w.finish().expect("finish");
    w.into_inner().into_inner()
}

fn info_cdr() -> Vec<u8> {
    let header = Header { stamp: Time { sec: 1, nanosec: 0 }, frame_id: "cam".into() };
    cdr::encode(&convert::camera_info_of(&camera(), header)).expect("cdr")
}

fn image_cdr(data_bytes: usize, encoding: &str) -> Vec<u8> {
    let header = Header { stamp: Time { sec: 1, nanosec: 0 }, frame_id: "cam".into() };
    let image = Image {
        header,
        height: 4,
        width: 6,
        encoding: encoding.into(),
        is_bigendian: 0,
        step: 18,
        data: vec![9; data_bytes],
    };
    cdr::encode(&image).expect("cdr")
}

const IMAGE: (&str, &str, &str) = ("/cam/image_raw", "sensor_msgs/msg/Image", "cdr");
const INFO: (&str, &str, &str) = ("/cam/camera_info", "sensor_msgs/msg/CameraInfo", "cdr");

#[test]
fn a_bag_of_another_tool_is_read_by_schema_name_and_images_wait_for_their_camera() {
    let bytes = bag(&[IMAGE, INFO], &[(0, image_cdr(72, "bgr8")), (1, info_cdr()), (0, image_cdr(72, "bgr8"))]);
    let channels = channels(&bytes).expect("channels");
    assert_eq!((channels.image.as_str(), channels.points.as_ref()), ("/cam/image_raw", None));
    let mut p = Player::new(&bytes[..], "mem.mcap", &channels);
    let Some((2, Sample::Frame { header, pixels })) = p.next_sample().expect("frame") else { panic!("no frame") };
    assert_eq!(
        (header.frame_id, header.pixel_format, header.capture_time_ns),
        (1, PixelFormat::Bgr8 as u32, 1_000_000_000)
    );
    assert_eq!(header.intrinsics, [300.0, 301.0, 2.5, 1.5]);
    assert_eq!(pixels, vec![9; 72]);
    assert!(p.next_sample().expect("end").is_none());
    assert_eq!(p.without_camera, 1);
}

#[test]
fn bad_recordings_are_refused_saying_what_was_wrong() {
    let error = |bytes: &[u8]| match channels(bytes).and_then(|c| samples(bytes, &c)) {
        Ok(_) => panic!("accepted"),
        Err(e) => format!("{e:#}"),
    };
    // An image whose data is shorter than its size says.
    let e = error(&bag(&[IMAGE, INFO], &[(1, info_cdr()), (0, image_cdr(71, "rgb8"))]));
    assert!(e.contains("mem.mcap: message 2 on /cam/image_raw") && e.contains("71 bytes of data"), "{e}");
    // A pixel encoding the pipeline does not read.
    let e = error(&bag(&[IMAGE, INFO], &[(1, info_cdr()), (0, image_cdr(72, "yuv422"))]));
    assert!(e.contains("yuv422"), "{e}");
    // An image channel that is not CDR.
    let e = error(&bag(
        &[("/cam/image_raw", "sensor_msgs/msg/Image", "json"), INFO],
        &[(1, info_cdr()), (0, b"{}".to_vec())],
    ));
    assert!(e.contains("/cam/image_raw") && e.contains("message encoding \"json\""), "{e}");
    // Bytes that are not the message.
    let e = error(&bag(&[IMAGE, INFO], &[(1, info_cdr()), (0, vec![0, 1, 0, 0, 1, 2])]));
    assert!(e.contains("Image does not decode"), "{e}");
    // No camera info, no images, two image topics.
    assert!(error(&bag(&[IMAGE], &[(0, image_cdr(72, "rgb8"))])).contains("no sensor_msgs/msg/CameraInfo"));
    assert!(error(&bag(&[INFO], &[(0, info_cdr())])).contains("no sensor_msgs/msg/Image"));
    let two = bag(
        &[IMAGE, INFO, ("/depth/image", "sensor_msgs/msg/Image", "cdr")],
        &[(1, info_cdr()), (0, image_cdr(72, "rgb8")), (2, image_cdr(72, "16UC1"))],
    );
    let e = error(&two);
    assert!(e.contains("several") && e.contains("/depth/image") && e.contains("--image-topic"), "{e}");
    let choice = TopicChoice { image: Some("/cam/image_raw".into()), points: None };
    let chosen = choose_channels(&scan(&two[..], "two").expect("scan"), &choice, "two").expect("chosen");
    assert_eq!(samples(&two, &chosen).expect("the chosen topic plays").len(), 1);
    // Not MCAP; the old format; an empty file.
    assert!(error(b"\x89PNG\r\n\x1a\n and more bytes").contains("not an MCAP file"));
    assert!(error(b"OUTLETREC\x01").contains("postcard"));
    assert!(error(b"").contains("mem.mcap"));
}

#[test]
fn truncated_recordings_fail_before_anything_plays_and_never_panic() {
    let bytes = recorded();
    for cut in (0..bytes.len() - 1).step_by(37).chain([bytes.len() - 1]) {
        let e = scan(&bytes[..cut], "cut.mcap").expect_err("truncated");
        assert!(format!("{e:#}").starts_with("cut.mcap: "), "{e:#}");
    }
    assert!(scan(&bytes[..bytes.len() - 1], "cut.mcap").is_err_and(|e| format!("{e:#}").contains("truncated")));
}
