//! The ROS 2 bridge against an independent DDS implementation: Eclipse Cyclone
//! DDS through its Python package `cyclonedds` (tests/ros2_interop.py) plays a
//! ROS 2 camera driver publishing `sensor_msgs/Image`, `CameraInfo` and
//! `PointCloud2` of rendered scenes (three at 640x480, one at 1280x960, one at
//! 1920x1080: 6 MB of rgb8 in fragmented samples), and a ROS 2 node reading
//! `geometry_msgs/PoseArray` and `PoseStamped`, `/tf` (`tf2_msgs/TFMessage`) and
//! `vision_msgs/Detection3DArray` and the debug image (`sensor_msgs/Image`:
//! the frame with the holes drawn); `outlet serve ros2-bridge` feeds the images to
//! detector, normal and pose over iceoryx2 and publishes their hole poses, which
//! must be within a millimetre of the ground truth. This test also reads the
//! pose and detection messages from shared memory, as the bridge does, and
//! checks that each covariance, class and score the Python peer decoded from
//! the Detection3DArray is the one the bridge was given.
//!
//! LOOPBACK ONLY: every DDS participant of this test is confined to the loopback
//! interface. The bridge is configured with `[ros2] interfaces = ["lo"]` (a
//! rustdds participant on the loopback network only), and Cyclone DDS runs with
//! CYCLONEDDS_URI=tests/dds/cyclonedds-loopback.xml (interface `lo`, no
//! multicast, unicast discovery to 127.0.0.1); the script refuses to run without
//! such a configuration. The test has a DDS domain id of its own (from the
//! process id, in 1..=200) and an iceoryx2 domain of its own.
//!
//! Python 3 with `cyclonedds`, `cv2` and `numpy` is required: the interpreter
//! named by `OUTLET_PYTHON`, else the project's `.venv/bin/python`, which
//! `scripts/test.sh` (the README's test command) creates. Without it this test
//! fails, it does not skip.

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use outlet_protocol::shm;
use outlet_protocol::wire::{DetectionMsg, HolePosesMsg, service};
use outlet_tests::scenes::{SceneRequest, detectable_scenes as detectable_scenes_of};
use outlet_tests::{Sidecar, domain, wait_for};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// How many 640x480 scenes go through the bridge (and one 1920x1080).
const SCENES: usize = 3;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace").to_path_buf()
}

/// The Python interpreter of the test peers: `OUTLET_PYTHON`, else the project's venv.
fn python() -> PathBuf {
    std::env::var_os("OUTLET_PYTHON").map_or_else(|| repo().join(".venv/bin/python"), PathBuf::from)
}

/// Python 3 with the packages the script needs, or why not.
fn check_python() -> Result<(), String> {
    let python = python();
    let out = Command::new(&python).args(["-c", "import cyclonedds, cv2, numpy"]).output().map_err(|e| {
        format!(
            "{} is required for the ROS 2 interop test and could not be run ({e}); scripts/test.sh creates it, \
             or set OUTLET_PYTHON",
            python.display()
        )
    })?;
    if !out.status.success() {
        return Err(format!(
            "{} lacks cyclonedds, cv2 or numpy, which the ROS 2 interop test needs (scripts/test.sh installs \
             tests/requirements.txt into .venv): {}",
            python.display(),
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    Ok(())
}

/// Into `dir/scenes`: the first `SCENES` 640x480 fw_2x1white views whose
/// holes `outlet detect` finds (the bridge answers only detected views), and
/// one 1920x1080 view (6 MB of rgb8, about 4 600 RTPS fragments from Cyclone
/// DDS), named `1920x1080_...` so that it sorts first and the script sends it
/// as rgb8, and one 1280x960 view (`hd_1280x960_...`, sorted last).
fn detectable_scenes(dir: &Path) -> Result<PathBuf, Box<dyn std::error::Error>> {
    let scenes = dir.join("scenes");
    let _ = std::fs::remove_dir_all(&scenes);
    let vga = SceneRequest {
        scenario: "fw_2x1white",
        width: 640,
        height: 480,
        cloud_step: 2,
        candidates: 8,
        keep: SCENES,
        prefix: "",
    };
    detectable_scenes_of(dir, &scenes, &vga)?;
    let hd =
        SceneRequest { width: 1920, height: 1080, cloud_step: 6, candidates: 6, keep: 1, prefix: "1920x1080_", ..vga };
    detectable_scenes_of(dir, &scenes, &hd)?;
    // A third size, sorted last (sent as the encoding its place gives it).
    let sxga = SceneRequest { width: 1280, height: 960, cloud_step: 4, keep: 1, prefix: "hd_1280x960_", ..hd };
    detectable_scenes_of(dir, &scenes, &sxga)?;
    Ok(scenes)
}

/// What the bridge read from shared memory, by capture time (ns).
#[derive(Default)]
struct BridgeInputs {
    poses: HashMap<u64, HolePosesMsg>,
    detections: HashMap<u64, DetectionMsg>,
}

impl BridgeInputs {
    fn drain(
        &mut self,
        poses: &Subscriber<ipc::Service, HolePosesMsg, ()>,
        detections: &Subscriber<ipc::Service, DetectionMsg, ()>,
    ) {
        while let Ok(Some(p)) = poses.receive() {
            self.poses.insert(p.payload().capture_time_ns, *p.payload());
        }
        while let Ok(Some(d)) = detections.receive() {
            self.detections.insert(d.payload().capture_time_ns, *d.payload());
        }
    }
}

/// Each frame the Python peer dumped (`--dump`): its classes, scores and 3x3
/// position covariances, as decoded from the Detection3DArray, against the
/// pose and detection messages of the same capture time. How many holes were compared.
fn detections_match_the_bridges_inputs(dump: &serde_json::Value, inputs: &BridgeInputs) -> Result<usize, String> {
    let frames = dump.as_array().ok_or("the dump is not a list")?;
    let mut holes = 0;
    for frame in frames {
        let stamp = &frame["stamp"];
        let (sec, nanosec) = (stamp[0].as_u64().ok_or("stamp")?, stamp[1].as_u64().ok_or("stamp")?);
        let capture_time_ns = sec * 1_000_000_000 + nanosec;
        let poses = inputs.poses.get(&capture_time_ns).ok_or(format!("no hole poses of capture {capture_time_ns}"))?;
        let detection =
            inputs.detections.get(&capture_time_ns).ok_or(format!("no detection of capture {capture_time_ns}"))?;
        let covariances = frame["covariances_m2"].as_array().ok_or("covariances")?;
        let scores = frame["scores"].as_array().ok_or("scores")?;
        let classes = frame["classes"].as_array().ok_or("classes")?;
        if covariances.len() != poses.hole_count as usize {
            return Err(format!("{} covariances, {} holes", covariances.len(), poses.hole_count));
        }
        for (k, ((c, score), class)) in covariances.iter().zip(scores).zip(classes).enumerate() {
            let expected = poses.covariances_m2[k];
            let got: Vec<f64> = c.as_array().ok_or("covariance")?.iter().filter_map(|v| v.as_f64()).collect();
            let scale = expected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if got.len() != 9 || got.iter().zip(&expected).any(|(g, e)| (g - e).abs() > 1e-12 * scale) {
                return Err(format!(
                    "capture {capture_time_ns} hole {k}: covariance {got:?}, the bridge had {expected:?}"
                ));
            }
            let score = score.as_f64().ok_or("score")?;
            // JSON keeps 17 digits; serde_json may read the last one a unit off.
            if (score - detection.holes[k].score).abs() > 1e-12 {
                return Err(format!("hole {k}: score {score}, the detector gave {}", detection.holes[k].score));
            }
            let kind = match poses.kinds[k] {
                1 => "power",
                2 => "ground",
                _ => "?",
            };
            if class.as_str() != Some(kind) {
                return Err(format!("hole {k}: class {class}, the pose message has {kind}"));
            }
            holes += 1;
        }
    }
    Ok(holes)
}

#[test]
fn images_published_by_cyclone_dds_give_hole_poses_on_ros2_within_a_millimetre() -> TestResult {
    // Fails, does not skip, when the independent implementation is missing.
    check_python()?;
    let domain = domain("ros2");
    let mut sidecar = Sidecar::new(&domain)?;
    let scenes = detectable_scenes(&sidecar.logs)?;
    // The bridge's own inputs, read beside it.
    let node = shm::node(&domain, "test")?;
    let pose_sub = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?.subscriber_builder().create()?;
    let detection_sub = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?.subscriber_builder().create()?;
    let mut inputs = BridgeInputs::default();

    // A DDS domain of this run alone, and the bridge on the loopback interface only.
    let dds_domain = 1 + std::process::id() % 200;
    let config = sidecar.write_ros2_loopback_config(dds_domain, "camera_optical_frame")?;
    for service in ["normal", "pose", "detector", "ros2-bridge"] {
        sidecar.start_with_config(&config, service, &[])?;
    }

    // Cyclone DDS on loopback only (the script refuses to run otherwise).
    let cyclone_config = repo().join("tests/dds/cyclonedds-loopback.xml");
    let stdout = std::fs::File::create(sidecar.logs.join("ros2_interop.out"))?;
    let stderr = std::fs::File::create(sidecar.logs.join("ros2_interop.err"))?;
    let mut script = Command::new(python())
        .arg(repo().join("tests/ros2_interop.py"))
        .arg(&scenes)
        .args(["--domain", &dds_domain.to_string(), "--timeout", "60"])
        .args(["--expect-diagnostics", "outlet/detector,outlet/normal,outlet/pose,outlet/ros2-bridge"])
        .args(["--debug-image-topic", "/outlet/debug_image"])
        .arg("--dump")
        .arg(sidecar.logs.join("detections.json"))
        .env("CYCLONEDDS_URI", format!("file://{}", cyclone_config.display()))
        .env("PYTHONUNBUFFERED", "1")
        .stdin(Stdio::null())
        .stdout(stdout)
        .stderr(stderr)
        .spawn()?;
    // Until the script ends, or a service dies (then there is no point waiting).
    let ended = wait_for(Duration::from_secs(600), || {
        inputs.drain(&pose_sub, &detection_sub);
        match script.try_wait() {
            Ok(Some(status)) => Some(Ok(status)),
            _ => sidecar.dead().map(Err),
        }
    });
    inputs.drain(&pose_sub, &detection_sub);
    let status = match &ended {
        Some(Ok(status)) => format!("exited with {status}"),
        Some(Err(service)) => format!("was stopped: the service {service} died"),
        None => "did not finish in 600 s".to_string(),
    };
    if !matches!(ended, Some(Ok(_))) {
        let _ = script.kill();
        let _ = script.wait();
    }
    let dead = sidecar.dead();

    let read = |name: &str| std::fs::read_to_string(sidecar.logs.join(name)).unwrap_or_default();
    let tail = |name: &str| {
        let log = read(name);
        let lines: Vec<&str> = log.lines().collect();
        lines[lines.len().saturating_sub(30)..].join("\n")
    };
    let mut report = format!(
        "tests/ros2_interop.py {status}\n--- its stdout\n{}--- its stderr\n{}--- the last lines of ros2-bridge.log\n{}\n",
        read("ros2_interop.out"),
        read("ros2_interop.err"),
        tail("ros2-bridge.log"),
    );
    if let Some(service) = dead.as_ref().filter(|s| *s != "ros2-bridge") {
        report.push_str(&format!("--- the last lines of {service}.log\n{}\n", tail(&format!("{service}.log"))));
    }
    report.push_str(&format!("(logs in {})", sidecar.logs.display()));
    assert!(matches!(ended, Some(Ok(s)) if s.success()), "{report}");
    assert_eq!(dead, None, "a service died\n{report}");
    eprintln!("{}", read("ros2_interop.out"));
    let dump: serde_json::Value = serde_json::from_str(&read("detections.json"))?;
    let compared = detections_match_the_bridges_inputs(&dump, &inputs).map_err(|e| format!("{e}\n{report}"))?;
    assert!(compared >= 2 * SCENES, "only {compared} holes compared");
    eprintln!("the covariances, scores and classes of {compared} holes are the bridge's inputs");
    Ok(())
}
