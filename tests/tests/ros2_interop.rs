//! The ROS 2 bridge against an independent DDS implementation: Eclipse Cyclone
//! DDS through its Python package `cyclonedds` (tests/ros2_interop.py) plays a
//! ROS 2 camera driver publishing `sensor_msgs/Image`, `CameraInfo` and
//! `PointCloud2` of rendered scenes, and a ROS 2 node reading
//! `geometry_msgs/PoseArray` and `PoseStamped`, `/tf` (`tf2_msgs/TFMessage`) and
//! `vision_msgs/Detection3DArray`; `outlet serve ros2-bridge` feeds the images to
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
use outlet_tests::{Sidecar, domain, outlet_exe, wait_for};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// How many scenes go through the bridge.
const SCENES: usize = 3;
/// A scene is used only when `outlet detect` finds its holes this close to the truth (m).
const DETECT_TOLERANCE_M: f64 = 0.5e-3;

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

/// Renders fw_2x1white views into `dir/all` and copies into `dir/scenes` the
/// first `SCENES` whose holes `outlet detect` finds (plane mode, within
/// `DETECT_TOLERANCE_M` of the truth): the bridge answers only detected views.
fn detectable_scenes(dir: &Path) -> Result<PathBuf, Box<dyn std::error::Error>> {
    let exe = outlet_exe()?;
    let all = dir.join("all");
    let scenes = dir.join("scenes");
    let _ = std::fs::remove_dir_all(&scenes);
    std::fs::create_dir_all(&scenes)?;
    let out = Command::new(&exe)
        .args(["render", "--scenario", "fw_2x1white", "--count", "8", "--seed", "1", "--threads", "2", "--out"])
        .arg(&all)
        .output()?;
    assert!(out.status.success(), "outlet render: {}", String::from_utf8_lossy(&out.stderr));

    let mut stems: Vec<String> = std::fs::read_dir(&all)?
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.strip_suffix(".camera.yaml").map(String::from))
        .collect();
    stems.sort();
    let mut manifest = String::new();
    let mut truths = Vec::new();
    for stem in &stems {
        let truth: serde_json::Value = serde_json::from_slice(&std::fs::read(all.join(format!("{stem}.json")))?)?;
        let image = truth["image"].as_str().ok_or("truth without an image")?.to_string();
        let line = serde_json::json!({
            "image": image, "camera": format!("{stem}.camera.yaml"), "points": format!("{stem}.ply"), "template": "2x1"
        });
        manifest.push_str(&format!("{line}\n"));
        truths.push(truth);
    }
    std::fs::write(all.join("manifest.jsonl"), manifest)?;
    let out = Command::new(&exe).arg("detect").arg("--batch").arg(all.join("manifest.jsonl")).arg("--json").output()?;
    assert!(out.status.success(), "outlet detect: {}", String::from_utf8_lossy(&out.stderr));

    let mut kept = Vec::new();
    for ((stem, truth), line) in stems.iter().zip(&truths).zip(String::from_utf8(out.stdout)?.lines()) {
        let found: serde_json::Value = serde_json::from_str(line)?;
        let holes = found["holes"].as_array().cloned().unwrap_or_default();
        let expected = truth["holes"].as_array().cloned().unwrap_or_default();
        let close = found["found"] == true
            && found["pose"]["mode"] == "plane"
            && !expected.is_empty()
            && holes.len() == expected.len()
            && holes.iter().zip(&expected).all(|(h, t)| {
                let d2: f64 = (0..3)
                    .map(|j| {
                        (h["position_m"][j].as_f64().unwrap_or(f64::NAN) - t["position_m"][j].as_f64().unwrap_or(0.0))
                            .powi(2)
                    })
                    .sum();
                d2.sqrt() < DETECT_TOLERANCE_M
            });
        if close && kept.len() < SCENES {
            let image = truth["image"].as_str().ok_or("truth without an image")?;
            for name in
                [image.to_string(), format!("{stem}.json"), format!("{stem}.camera.yaml"), format!("{stem}.ply")]
            {
                std::fs::copy(all.join(&name), scenes.join(&name))?;
            }
            kept.push(stem.clone());
        }
    }
    assert_eq!(kept.len(), SCENES, "only {kept:?} of {stems:?} were detected within {DETECT_TOLERANCE_M} m");
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
    let config = sidecar.logs.join("outlet.toml");
    std::fs::write(
        &config,
        format!(
            r#"domain = "{domain}"
heartbeat_ms = 200

[detector]
template = "2x1"

[pose]
template = "2x1"
# A detection waits for the wall plane of its own frame.
plane_wait_ms = 2000.0

[ros2]
domain_id = {dds_domain}
interfaces = ["lo"]
frame_id = "camera_optical_frame"
"#
        ),
    )?;
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
