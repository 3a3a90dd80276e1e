//! `outlet render` writes, per image, the picture, the ground truth, the camera and
//! the cloud exactly as CONTRACT.md says, the same bytes for the same seed.

use outlet_protocol::camera_info::read_camera_info;
use outlet_protocol::ply::read_ply;
use outlet_protocol::truth::GroundTruth;
use std::path::Path;
use std::process::Command;

fn outlet(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_outlet")).args(args).output().expect("run outlet")
}

fn render(dir: &Path, scenario: &str, count: &str, seed: &str) {
    let out = outlet(&[
        "render",
        "--scenario",
        scenario,
        "--count",
        count,
        "--seed",
        seed,
        "--out",
        dir.to_str().expect("utf-8 path"),
    ]);
    assert!(out.status.success(), "render failed: {}", String::from_utf8_lossy(&out.stderr));
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| {
            let p = e.expect("entry").path();
            (p.file_name().expect("name").to_string_lossy().into_owned(), std::fs::read(&p).expect("read"))
        })
        .collect();
    v.sort();
    v
}

#[test]
fn the_same_seed_writes_the_same_bytes() {
    let (a, b) = (tempfile::tempdir().expect("tmp"), tempfile::tempdir().expect("tmp"));
    render(a.path(), "specular2x2", "4", "77");
    render(b.path(), "specular2x2", "4", "77");
    let (fa, fb) = (files(a.path()), files(b.path()));
    assert_eq!(fa.len(), 16, "four files per image");
    assert_eq!(fa, fb);
}

#[test]
fn every_image_has_its_truth_camera_and_cloud_and_they_agree() {
    let dir = tempfile::tempdir().expect("tmp");
    render(dir.path(), "orange2x1", "3", "5");
    for i in 0..3 {
        let stem = dir.path().join(format!("orange2x1_{i:04}"));
        let truth: GroundTruth =
            serde_json::from_slice(&std::fs::read(stem.with_extension("json")).expect("json")).expect("truth parses");
        assert_eq!(truth.template.as_deref(), Some("2x1"));
        assert_eq!(truth.holes.len(), 6);
        let image_path = dir.path().join(&truth.image);
        let image = image::open(&image_path).expect("image opens");
        let camera = read_camera_info(&stem.with_extension("camera.yaml")).expect("camera_info parses");
        assert_eq!((image.width(), image.height()), (camera.width, camera.height));
        for hole in &truth.holes {
            let p = hole.position_m.expect("position");
            let px = camera.project(&nalgebra::Point3::from(p)).expect("in front");
            assert!((px.x - hole.pixel[0]).abs() < 1e-6 && (px.y - hole.pixel[1]).abs() < 1e-6);
        }
        let cloud = read_ply(&stem.with_extension("ply")).expect("ply parses");
        let finite = cloud.iter().filter(|p| p.iter().all(|v| v.is_finite())).count();
        assert_eq!(cloud.len(), 320 * 240);
        assert!(finite > cloud.len() / 2 && finite < cloud.len());
        // Wall points lie on the recorded plane, give or take the stereo noise.
        let n = nalgebra::Vector3::from(truth.wall_plane.normal);
        let near = cloud
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .filter(|p| {
                (n.dot(&nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)) - truth.wall_plane.distance_m)
                    .abs()
                    < 0.003
            })
            .count();
        assert!(near > finite / 2, "{near} of {finite} points near the wall");
    }
}

#[test]
fn negatives_name_the_sought_template_and_hold_no_outlet() {
    let dir = tempfile::tempdir().expect("tmp");
    render(dir.path(), "negative", "3", "1");
    for i in 0..3 {
        let text = std::fs::read_to_string(dir.path().join(format!("negative_{i:04}.json"))).expect("json");
        let v: serde_json::Value = serde_json::from_str(&text).expect("json");
        assert!(v["template"].is_null() && v["pose"].is_null());
        assert_eq!(v["holes"].as_array().map(Vec::len), Some(0));
        assert!(matches!(v["search_template"].as_str(), Some("2x1" | "2x2")));
    }
}

#[test]
fn an_unknown_scenario_or_bad_camera_is_a_clear_error() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = dir.path().to_str().expect("utf-8");
    let out = outlet(&["render", "--scenario", "kitchen", "--count", "1", "--out", d]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("kitchen") && err.contains("orange2x1"), "{err}");
    let out = outlet(&["render", "--scenario", "orange2x1", "--count", "1", "--out", d, "--width", "0"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("empty"));
    let out =
        outlet(&["render", "--scenario", "orange2x1", "--count", "1", "--out", d, "--camera", "/nonexistent.yaml"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent.yaml"));
}

#[test]
fn sizes_and_intrinsics_are_honoured() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = dir.path().to_str().expect("utf-8");
    let out = outlet(&[
        "render",
        "--scenario",
        "white2x2",
        "--count",
        "1",
        "--out",
        d,
        "--width",
        "1280",
        "--height",
        "960",
        "--focal",
        "1000",
        "--distortion",
        "-0.2,0.05,0,0,0",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let camera = read_camera_info(&dir.path().join("white2x2_0000.camera.yaml")).expect("camera");
    assert_eq!((camera.width, camera.height, camera.fx), (1280, 960, 1000.0));
    assert_eq!(camera.distortion[0], -0.2);
}

#[test]
fn a_terminal_sees_a_progress_bar_and_a_pipe_does_not() {
    // A pipe (what `output()` gives): the log line, never a bar.
    let dir = tempfile::tempdir().expect("tmp");
    let d = dir.path().to_str().expect("utf-8");
    let args = ["render", "--scenario", "orange2x1", "--count", "6", "--threads", "1", "--out", d];
    let piped = outlet(&args);
    assert!(piped.status.success(), "{}", String::from_utf8_lossy(&piped.stderr));
    let text = String::from_utf8_lossy(&piped.stderr);
    assert!(text.contains("rendered 6 of 6 images"), "{text}");
    assert!(!text.contains("rendering [") && !text.contains('\r'), "a bar in a pipe: {text:?}");
    // A terminal: `script` (util-linux) runs the same command on a pseudo-terminal.
    let command: Vec<String> =
        std::iter::once(env!("CARGO_BIN_EXE_outlet")).chain(args).map(|a| format!("'{a}'")).collect();
    let command = command.join(" ");
    let tty = Command::new("script")
        .args(["-q", "-e", "-c", &command, "/dev/null"])
        .stdin(std::process::Stdio::null())
        .output()
        .expect("script (util-linux) runs the command on a terminal");
    assert!(tty.status.success(), "{}", String::from_utf8_lossy(&tty.stderr));
    let screen = String::from_utf8_lossy(&tty.stdout);
    assert!(screen.contains("rendering ["), "no bar on a terminal: {screen:?}");
}
