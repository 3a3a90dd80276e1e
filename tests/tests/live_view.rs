//! The live view over the Foxglove WebSocket protocol, as Foxglove would see it:
//! `outlet demo --view PORT` runs the sidecar on the simulated camera, and a
//! Python client (`tests/foxglove_client.py`: the `websockets` package, Google's
//! `protobuf` decoding each channel with the schema the server advertised)
//! subscribes to every channel and reports what it decoded. Checked: the image
//! decodes to the camera's frame, the annotations circle the detector's holes,
//! the 3D scene puts the holes where the pose service did, and every service's
//! heartbeat arrives.
//!
//! The interpreter is `OUTLET_PYTHON`, else the project's `.venv/bin/python`
//! (`scripts/test.sh` creates it from tests/requirements.txt). Without it this
//! test fails, it does not skip.

use outlet_tests::{domain, outlet_exe};
use serde_json::Value;
use std::path::PathBuf;
use std::process::{Command, Stdio};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn python() -> PathBuf {
    std::env::var_os("OUTLET_PYTHON").map_or_else(|| repo().join(".venv/bin/python"), PathBuf::from)
}

/// A port free now on the loopback interface.
fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind a free port");
    l.local_addr().expect("local address").port()
}

fn messages<'a>(report: &'a Value, topic: &str) -> &'a [Value] {
    report["messages"][topic].as_array().map_or(&[], |v| v.as_slice())
}

#[test]
fn a_foxglove_client_sees_image_holes_scene_and_health_during_the_demo() {
    let python = python();
    let probe = Command::new(&python).args(["-c", "import websockets, google.protobuf"]).output();
    assert!(
        probe.as_ref().is_ok_and(|o| o.status.success()),
        "{} must have websockets and protobuf (scripts/test.sh installs tests/requirements.txt into .venv): {probe:?}",
        python.display()
    );
    let exe = outlet_exe().expect("outlet binary");
    let port = free_port();
    let dom = domain("live-view");
    let logs = std::env::temp_dir().join(format!("outlet-live-view-{}", std::process::id()));
    let demo = Command::new(&exe)
        .args(["demo", "--duration", "16", "--json", "--domain", &dom, "--view", &port.to_string()])
        .arg("--logs")
        .arg(&logs)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start outlet demo");
    // The picture in the README: `REGENERATE=1` writes it, else a temporary one.
    let picture = if std::env::var_os("REGENERATE").is_some() {
        repo().join("docs/view/live_view.png")
    } else {
        std::env::temp_dir().join(format!("outlet-live-view-{}.png", std::process::id()))
    };
    if let Some(dir) = picture.parent() {
        std::fs::create_dir_all(dir).expect("picture folder");
    }
    // The client retries its connection until the viewer listens, then listens 8 s.
    let client = Command::new(&python)
        .arg(repo().join("tests/foxglove_client.py"))
        .arg(format!("ws://127.0.0.1:{port}"))
        .arg("8")
        .arg(&picture)
        .output()
        .expect("run the Foxglove client");
    // The demo ends by itself (--duration), stopping its services.
    let demo_out = demo.wait_with_output().expect("demo output");
    let viewer_log = std::fs::read_to_string(logs.join("viewer.log")).unwrap_or_default();
    assert!(
        client.status.success(),
        "client failed: {}\nviewer log:\n{viewer_log}",
        String::from_utf8_lossy(&client.stderr)
    );
    let report: Value = serde_json::from_slice(&client.stdout).expect("the client's JSON");
    assert_eq!(report["subprotocol"], "foxglove.sdk.v1");
    let channels = &report["channels"];
    for (topic, schema) in [
        ("/camera/image", "foxglove.RawImage"),
        ("/camera/calibration", "foxglove.CameraCalibration"),
        ("/outlet/annotations", "foxglove.ImageAnnotations"),
        ("/outlet/scene", "foxglove.SceneUpdate"),
        ("/tf", "foxglove.FrameTransforms"),
        ("/outlet/cloud", "foxglove.PointCloud"),
        ("/outlet/hole_poses", "outlet.HolePoses"),
        ("/outlet/detections", "outlet.Detection"),
        ("/outlet/heartbeat", "outlet.Heartbeat"),
    ] {
        assert_eq!(channels[topic]["schema"], schema, "{topic} advertised as {:?}", channels[topic]);
    }

    // The image: the simulated camera's 640x480 rgb8 frames, whole.
    let images = messages(&report, "/camera/image");
    assert!(images.len() >= 5, "only {} images in 8 s", images.len());
    for im in images {
        assert_eq!((im["width"].as_u64(), im["height"].as_u64()), (Some(640), Some(480)), "{im}");
        assert_eq!(im["encoding"], "rgb8");
        assert_eq!(im["bytes"].as_u64(), Some(im["step"].as_u64().unwrap_or(0) * 480));
        assert_eq!(im["frame_id"], "camera_optical_frame");
    }

    // Annotations circle exactly the detector's holes of the same frame
    // (Foxglove's pixel origin is half a pixel from ours).
    let detections = messages(&report, "/outlet/detections");
    let annotations = messages(&report, "/outlet/annotations");
    let mut matched = 0;
    for d in detections.iter().filter(|d| d["holes"].as_array().is_some_and(|h| !h.is_empty())) {
        let Some(a) = annotations.iter().find(|a| a["stamp_ns"] == d["capture_time_ns"]) else { continue };
        let holes = d["holes"].as_array().expect("holes");
        let circles = a["circles"].as_array().expect("circles");
        assert_eq!(holes.len(), circles.len(), "{a}");
        for (h, c) in holes.iter().zip(circles) {
            let (px, py) = (h["pixel"][0].as_f64().expect("x"), h["pixel"][1].as_f64().expect("y"));
            let (cx, cy) = (c[0].as_f64().expect("x"), c[1].as_f64().expect("y"));
            assert!((cx - px - 0.5).abs() < 1e-9 && (cy - py - 0.5).abs() < 1e-9, "{h} against {c}");
        }
        matched += 1;
    }
    assert!(matched >= 3, "annotations matched to only {matched} detections with holes");

    // The 3D scene puts each hole where the pose service did, at 20-70 cm.
    let poses: Vec<&Value> = messages(&report, "/outlet/hole_poses").iter().filter(|p| p["status"] == "ok").collect();
    assert!(poses.len() >= 3, "only {} poses", poses.len());
    let scenes = messages(&report, "/outlet/scene");
    let mut placed = 0;
    for p in &poses {
        let holes = p["holes"].as_array().expect("holes");
        let Some(entity) = scenes
            .iter()
            .flat_map(|s| s["entities"].as_array().into_iter().flatten())
            .find(|e| e["id"] == "holes" && e["stamp_ns"] == p["capture_time_ns"])
        else {
            continue;
        };
        let spheres = entity["spheres"].as_array().expect("spheres");
        for h in holes {
            let at: Vec<f64> = (0..3).map(|k| h["position_m"][k].as_f64().expect("position")).collect();
            assert!((0.15..0.75).contains(&at[2]), "hole at {at:?}");
            let shown =
                spheres.iter().any(|s| (0..3).all(|k| (s[k].as_f64().unwrap_or(f64::NAN) - at[k]).abs() < 1e-9));
            assert!(shown, "hole {at:?} not in the scene {entity}");
        }
        placed += 1;
    }
    assert!(placed >= 3, "scene entities matched to only {placed} poses");
    let tf = messages(&report, "/tf");
    assert!(tf.iter().any(|t| t[0]["parent"] == "camera_optical_frame" && t[0]["child"] == "outlet"), "{tf:?}");

    // Health: every service's heartbeat, the viewer's own included.
    let services: std::collections::BTreeSet<&str> =
        messages(&report, "/outlet/heartbeat").iter().filter_map(|b| b["service"].as_str()).collect();
    for s in ["sim-camera", "detector", "normal", "pose", "viewer"] {
        assert!(services.contains(s), "no heartbeat of {s}: {services:?}");
    }
    let clouds = messages(&report, "/outlet/cloud");
    assert!(clouds.iter().any(|c| c["points"].as_u64().is_some_and(|n| n > 100)), "{clouds:?}");

    // The demo itself ran and reported results while watched.
    let lines = String::from_utf8_lossy(&demo_out.stdout).lines().count();
    assert!(lines > 10, "the demo printed {lines} lines");
    assert_eq!(report["picture"], true, "no image with annotations of its own time to draw");
    let drawn = image::open(&picture).expect("the drawn picture").to_rgb8();
    assert!(drawn.width() > 200 && drawn.height() > 150, "{:?}", drawn.dimensions());
    let _ = std::fs::remove_dir_all(&logs);
}
