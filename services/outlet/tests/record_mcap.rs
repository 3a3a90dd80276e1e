//! MCAP recordings against a reader and a writer nobody here wrote: Foxglove's
//! Python `mcap` and `mcap-ros2-support` (tests/mcap_interop.py).
//!
//! - `outlet record` of the simulated camera and the pipeline: every image,
//!   camera info and cloud decodes, in Rust and in mcap_ros2, to exactly what the
//!   renderer made, and the hole poses recorded are within 1 mm of the truth.
//! - A ROS 2 bag written by `mcap_ros2.writer` from `outlet render` scenes
//!   (rgb8, bgr8 and mono8 images, clouds with 20-byte points) goes through
//!   `outlet replay` into detector, normal and pose: hole poses within 1 mm.
//!
//! Python 3 with the packages of tests/requirements.txt is required: the
//! interpreter named by `OUTLET_PYTHON`, else the project's `.venv/bin/python`,
//! which `scripts/test.sh` creates. Without it these tests fail, they do not skip.

mod common;

use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{HeartbeatMsg, HolePosesMsg, pose_status, service};
use outlet_ros2_bridge::cdr;
use outlet_ros2_bridge::convert;
use outlet_ros2_bridge::msgs::{CameraInfo, Image, PointCloud2};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// A guard against a hang, not a measure: far beyond what any step takes.
const HANG_GUARD: Duration = Duration::from_secs(300);

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> PathBuf {
    std::env::var_os("OUTLET_PYTHON").map_or_else(|| repo().join(".venv/bin/python"), PathBuf::from)
}

/// tests/mcap_interop.py with `args`; its stdout as JSON.
fn interop(args: &[&std::ffi::OsStr]) -> Result<Value, Box<dyn std::error::Error>> {
    let python = python();
    let out = Command::new(&python).arg(repo().join("tests/mcap_interop.py")).args(args).output().map_err(|e| {
        format!(
            "{} (Python with mcap and mcap-ros2-support) could not be run: {e}; scripts/test.sh creates it, or set \
             OUTLET_PYTHON",
            python.display()
        )
    })?;
    if !out.status.success() {
        return Err(
            format!("{} tests/mcap_interop.py: {}", python.display(), String::from_utf8_lossy(&out.stderr)).into()
        );
    }
    Ok(serde_json::from_slice(&out.stdout)?)
}

fn outlet(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_outlet"));
    c.args(args);
    c
}

/// Each hole's distance from the truth (m), template order.
fn hole_errors(pose: &HolePosesMsg, truth: &[[f64; 3]]) -> Vec<f64> {
    truth
        .iter()
        .zip(&pose.positions_m)
        .map(|(t, p)| (0..3).map(|i| (p[i] - t[i]).powi(2)).sum::<f64>().sqrt())
        .collect()
}

/// The simulated camera's view `index` of fw_2x1white at seed 1, as `outlet
/// serve sim-camera --views 1` renders it (and sends it again and again).
fn sim_view(camera: &CameraModel, index: u64) -> Result<outlet_sim::RenderedFrame, String> {
    let scene = outlet_sim::sample_scene("fw_2x1white", 1, index, camera).map_err(|e| e.to_string())?;
    Ok(outlet_sim::render_frame(&scene, &format!("sim-{index}")))
}

#[test]
fn a_recording_of_the_simulated_camera_decodes_to_what_was_rendered_in_rust_and_in_mcap_ros2() -> TestResult {
    let domain = common::domain("record-mcap");
    let dir = tempfile::tempdir()?;
    let vga = CameraModel::default_vga();
    let camera = CameraModel::new(640, 480, [vga.fx, vga.fx, 319.5, 239.5], vga.distortion)?;
    let view = sim_view(&camera, 0)?;
    let mut services = common::Services::start(
        &domain,
        &[
            &["sim-camera", "--scenario", "fw_2x1white", "--seed", "1", "--views", "1", "--rate", "10"],
            &["detector", "--template", "2x1"],
            &["normal"],
            &["pose", "--template", "2x1"],
        ],
    )?;
    let path = dir.path().join("sim.mcap");
    let guard = HANG_GUARD.as_secs().to_string();
    let out = outlet(&["record", "--domain", &domain, "--frames", "30", "--duration", &guard]).arg(&path).output()?;
    assert!(out.status.success(), "outlet record: {}", String::from_utf8_lossy(&out.stderr));
    assert!(services.all_running());
    drop(services);

    // Rust: every message with the mcap crate and the bridge's CDR.
    let bytes = std::fs::read(&path)?;
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    let mut ok_poses = 0;
    for message in mcap::MessageStream::new(&bytes)? {
        let message = message?;
        let topic = message.channel.topic.clone();
        *counts.entry(topic.clone()).or_default() += 1;
        assert!(message.sequence >= 1 || message.channel.topic == "/outlet/heartbeat", "frame ids start at 1");
        match topic.as_str() {
            "/camera/image_raw" => {
                let image: Image = cdr::decode(&message.data)?;
                assert_eq!((image.width, image.height, image.encoding.as_str(), image.step), (640, 480, "rgb8", 1920));
                let differing = |v: &outlet_sim::RenderedFrame| {
                    image.data.iter().zip(v.frame.image.as_raw()).filter(|(a, b)| a != b).count()
                };
                assert!(
                    image.data.len() == view.frame.image.as_raw().len() && differing(&view) == 0,
                    "frame {}: {} bytes differ from the view rendered",
                    message.sequence,
                    differing(&view)
                );
                assert_eq!(convert::time_to_ns(image.header.stamp), Some(message.log_time));
                assert_eq!(image.header.frame_id, "camera_optical_frame");
            }
            "/camera/camera_info" => {
                let info: CameraInfo = cdr::decode(&message.data)?;
                assert_eq!(convert::camera_of(&info)?, camera);
            }
            "/camera/points" => {
                let (stamp, xyz) = convert::xyz_of(&cdr::decode::<PointCloud2>(&message.data)?)?;
                assert_eq!(stamp, message.log_time);
                let differing = |v: &outlet_sim::RenderedFrame| {
                    let want = v.cloud.iter().flatten();
                    xyz.iter().zip(want).filter(|(a, b)| a != b && !(a.is_nan() && b.is_nan())).count()
                };
                assert!(
                    xyz.len() == 3 * view.cloud.len() && differing(&view) == 0,
                    "cloud {}: {} of {} values differ from the view rendered",
                    message.sequence,
                    differing(&view),
                    xyz.len()
                );
            }
            "/outlet/hole_poses" => {
                let v: Value = serde_json::from_slice(&message.data)?;
                if v["status"] == "ok" {
                    let frame = v["frame_id"].as_u64().ok_or("frame_id")? as u32;
                    let truth = &view.truth.holes;
                    let holes = v["holes"].as_array().ok_or("holes")?;
                    assert_eq!(holes.len(), truth.len());
                    for (h, t) in holes.iter().zip(truth) {
                        let t = t.position_m.ok_or("truth position")?;
                        let p: Vec<f64> = (0..3).filter_map(|i| h["position_m"][i].as_f64()).collect();
                        let e = (0..3).map(|i| (p[i] - t[i]).powi(2)).sum::<f64>().sqrt();
                        assert!(e < 1e-3, "frame {frame}: a hole {:.3} mm off", e * 1e3);
                        assert!(h["covariance_m2"][0].as_f64().is_some_and(|c| c > 0.0));
                    }
                    ok_poses += 1;
                }
            }
            "/outlet/detections" | "/outlet/wall_plane" | "/outlet/heartbeat" => {
                serde_json::from_slice::<Value>(&message.data)?;
            }
            other => panic!("unexpected topic {other}"),
        }
    }
    assert_eq!(counts.get("/camera/image_raw"), Some(&30));
    assert_eq!(counts.get("/camera/camera_info"), Some(&30));
    assert!(counts.get("/camera/points").is_some_and(|&n| n >= 29), "{counts:?}");
    assert!(ok_poses >= 1, "no hole poses with status ok recorded: {counts:?}");
    assert!(counts.get("/outlet/heartbeat").is_some_and(|&n| n >= 4), "{counts:?}");

    // Python: the same file through mcap_ros2, checked against what was rendered.
    let expected = dir.path().join("expected");
    std::fs::create_dir(&expected)?;
    std::fs::write(expected.join("view0.rgb"), view.frame.image.as_raw())?;
    let xyz: Vec<u8> = view.cloud.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(expected.join("view0.xyz"), xyz)?;
    let k = [camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0];
    let spec = serde_json::json!({"width": 640, "height": 480, "k": k, "d": camera.distortion,
        "frame_id": "camera_optical_frame", "views": 1});
    std::fs::write(expected.join("expected.json"), spec.to_string())?;
    let summary = interop(&["read".as_ref(), path.as_os_str(), expected.as_os_str()])?;
    assert_eq!(summary["images"].as_u64(), Some(30));
    assert_eq!(summary["camera_infos"].as_u64(), Some(30));
    assert_eq!(summary["clouds"].as_u64(), counts.get("/camera/points").map(|&n| n as u64));
    assert_eq!(summary["checked_pixels"].as_u64(), Some(30 * 640 * 480));
    assert!(summary["finite_points"].as_u64().is_some_and(|n| n > 1000), "{summary}");
    for (topic, schema) in [
        ("/camera/image_raw", "sensor_msgs/msg/Image"),
        ("/camera/points", "sensor_msgs/msg/PointCloud2"),
        ("/outlet/hole_poses", "outlet.HolePoses"),
    ] {
        assert_eq!(summary["schemas"][topic][0], schema, "{summary}");
    }
    let python_poses = summary["json"]["/outlet/hole_poses"].as_array().ok_or("hole poses in Python")?;
    assert_eq!(python_poses.iter().filter(|p| p["status"] == "ok").count(), ok_poses);
    Ok(())
}

/// Waits until detector, normal and pose have each published a heartbeat.
fn wait_for_services(services: &mut common::Services, domain: &str) -> TestResult {
    let node = shm::node(domain, "test-beats")?;
    let beats = shm::heartbeats(&node)?.subscriber_builder().create()?;
    let mut seen = BTreeSet::new();
    let started = Instant::now();
    while !["detector", "normal", "pose"].iter().all(|s| seen.contains(*s)) {
        if !services.all_running() || started.elapsed() > HANG_GUARD {
            return Err(format!("the services did not all start (heartbeats from {seen:?})").into());
        }
        while let Some(b) = beats.receive()? {
            let b: &HeartbeatMsg = b.payload();
            seen.insert(b.service_name().to_string());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}

#[test]
fn a_ros2_bag_written_by_mcap_ros2_replays_through_the_sidecar_to_hole_poses_within_a_millimetre() -> TestResult {
    let dir = tempfile::tempdir()?;
    let render = dir.path().join("render");
    let out =
        outlet(&["render", "--scenario", "fw_2x1white", "--count", "3", "--seed", "1", "--threads", "2", "--out"])
            .arg(&render)
            .output()?;
    assert!(out.status.success(), "outlet render: {}", String::from_utf8_lossy(&out.stderr));
    let bag = dir.path().join("bag.mcap");
    let order = interop(&["write".as_ref(), bag.as_os_str(), render.as_os_str(), "3".as_ref()])?;
    let order: Vec<String> = serde_json::from_value(order)?;
    assert_eq!(order.len(), 9);
    let mut truth: BTreeMap<String, Vec<[f64; 3]>> = BTreeMap::new();
    for stem in &order {
        let t: Value = serde_json::from_str(&std::fs::read_to_string(render.join(format!("{stem}.json")))?)?;
        let holes = t["holes"].as_array().ok_or("truth holes")?;
        let positions = holes.iter().map(|h| std::array::from_fn(|i| h["position_m"][i].as_f64().unwrap_or(f64::NAN)));
        truth.insert(stem.clone(), positions.collect());
    }

    let domain = common::domain("replay-mcap");
    let mut services = common::Services::start_2x1_pipeline(&domain)?;
    wait_for_services(&mut services, &domain)?;
    let node = shm::node(&domain, "test-poses")?;
    let poses = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?.subscriber_builder().create()?;
    let mut replay =
        outlet(&["replay", "--domain", &domain]).arg(&bag).stdout(Stdio::null()).stderr(Stdio::piped()).spawn()?;
    let mut got: Vec<HolePosesMsg> = Vec::new();
    let mut ended: Option<Instant> = None;
    let started = Instant::now();
    // Until the replay has ended and the pipeline has had time to answer its last frame.
    while ended.is_none_or(|t| t.elapsed() < Duration::from_secs(3)) {
        assert!(started.elapsed() < HANG_GUARD && services.all_running(), "replay or services stuck or dead");
        while let Some(p) = poses.receive()? {
            got.push(*p.payload());
        }
        if ended.is_none() && replay.try_wait()?.is_some() {
            ended = Some(Instant::now());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let output = replay.wait_with_output()?;
    let log = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "outlet replay: {log}");
    assert!(log.contains("18 frames and clouds (18 per pass)"), "{log}");

    // Frames are numbered from 1 in the bag's order.
    let mut per_scene: BTreeMap<&str, usize> = BTreeMap::new();
    for p in got.iter().filter(|p| p.status == pose_status::OK) {
        let stem = order.get((p.frame_id as usize).wrapping_sub(1)).ok_or("a frame id the bag does not have")?;
        let errors = hole_errors(p, &truth[stem]);
        assert_eq!(p.hole_count as usize, truth[stem].len());
        assert!(errors.iter().all(|e| *e < 1e-3), "{stem} (frame {}): holes {errors:?} m off", p.frame_id);
        assert_eq!(p.mode, 3, "the clouds of the bag give the wall plane");
        *per_scene.entry(stem).or_default() += 1;
    }
    assert_eq!(
        per_scene.len(),
        3,
        "every scene (rgb8, bgr8, mono8) has hole poses: {per_scene:?} of {} results",
        got.len()
    );
    Ok(())
}
