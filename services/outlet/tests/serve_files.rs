//! `outlet serve files` and `outlet demo --images`: a folder of rendered
//! photographs through the whole sidecar gives, file by file, the holes `outlet
//! detect` gives on the same files; frames go out as a camera's (the image's
//! pixels, its camera, its cloud, one frame id); a bad file is reported and
//! skipped while the others go through.

mod common;

use outlet_protocol::camera_info::read_camera_info;
use outlet_protocol::ply::read_ply;
use outlet_protocol::shm;
use outlet_protocol::wire::{FileFrameMsg, PixelFormat, file_status, service};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

type TestResult = Result<(), Box<dyn std::error::Error>>;

fn outlet(args: &[&str]) -> std::io::Result<Output> {
    Command::new(env!("CARGO_BIN_EXE_outlet")).args(args).output()
}

fn render(dir: &Path, scenario: &str, count: &str, seed: &str) -> TestResult {
    let out = outlet(&["render", "--scenario", scenario, "--count", count, "--seed", seed, "--out", s(dir)?])?;
    assert!(out.status.success(), "render failed: {}", String::from_utf8_lossy(&out.stderr));
    Ok(())
}

fn s(p: &Path) -> Result<&str, String> {
    p.to_str().ok_or_else(|| format!("{} is not UTF-8", p.display()))
}

/// The rendered images of `dir` (PNG, or JPEG where the simulated sensor compresses), sorted.
fn images(dir: &Path) -> Result<Vec<PathBuf>, std::io::Error> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "jpg"))
        .collect();
    v.sort();
    Ok(v)
}

fn name(image: &Value) -> String {
    let path = image["image"].as_str().unwrap_or("");
    Path::new(path).file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

fn json_lines(out: &Output) -> Result<Vec<Value>, Box<dyn std::error::Error>> {
    Ok(String::from_utf8(out.stdout.clone())?.lines().map(serde_json::from_str).collect::<Result<_, _>>()?)
}

/// No file of the demo's own domain (named on its stderr) is left in /dev/shm.
fn nothing_left_behind(stderr: &str) -> TestResult {
    let domain = stderr.split("domain ").nth(1).and_then(|s| s.split_whitespace().next()).ok_or("no domain")?;
    let left: Vec<_> = std::fs::read_dir("/dev/shm")?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.starts_with(&format!("{domain}_")))
        .collect();
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");
    Ok(())
}

#[test]
fn the_demo_on_rendered_photos_gives_the_holes_of_outlet_detect_file_by_file() -> TestResult {
    let dir = tempfile::tempdir()?;
    render(dir.path(), "orange2x1", "4", "3")?;
    render(dir.path(), "white2x2", "2", "4")?;
    let images = images(dir.path())?;
    assert_eq!(images.len(), 6);

    // `outlet detect` on each file with its own camera and cloud.
    let manifest = dir.path().join("manifest.jsonl");
    let mut lines = String::new();
    for image in &images {
        let stem = image.file_stem().ok_or("no stem")?.to_string_lossy().into_owned();
        let line = serde_json::json!({
            "image": image,
            "camera": dir.path().join(format!("{stem}.camera.yaml")),
            "points": dir.path().join(format!("{stem}.ply")),
            "template": "2x1",
        });
        lines += &format!("{line}\n");
    }
    std::fs::write(&manifest, lines)?;
    let detect = outlet(&["detect", "--batch", s(&manifest)?, "--json"])?;
    assert!(detect.status.success(), "detect failed: {}", String::from_utf8_lossy(&detect.stderr));
    let expected: BTreeMap<String, Value> = json_lines(&detect)?.into_iter().map(|v| (name(&v), v)).collect();
    let found = expected.values().filter(|v| v["found"] == true).count();
    assert!(found >= 3, "detect finds the outlet in only {found} of the rendered 2x1 photos: {expected:?}");

    // The same files through the sidecar: globs, their cameras beside them, clouds by stem.
    let png = format!("{}/*.png", s(dir.path())?);
    let jpg = format!("{}/*.jpg", s(dir.path())?);
    let ply = format!("{}/*.ply", s(dir.path())?);
    let demo =
        outlet(&["demo", "--images", &png, &jpg, "--points", &ply, "--rate", "2", "--json", "--duration", "180"])?;
    let stderr = String::from_utf8_lossy(&demo.stderr);
    assert!(demo.status.success(), "demo failed: {stderr}");
    let got = json_lines(&demo)?;
    let names: Vec<String> = got.iter().map(name).collect();
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(names, sorted, "records in the list's order");
    assert_eq!(names.len(), images.len(), "one record per file, the demo ends after the last: {stderr}");
    let mut posed = 0;
    for line in &got {
        let want = &expected[&name(line)];
        assert!(line.get("error").is_none(), "{line}");
        assert_eq!(line["found"], want["found"], "{line}\n{want}");
        let (holes, want_holes) = (line["holes"].as_array().ok_or("holes")?, want["holes"].as_array().ok_or("holes")?);
        assert_eq!(holes.len(), want_holes.len(), "{line}\n{want}");
        for (h, w) in holes.iter().zip(want_holes) {
            assert_eq!(h["kind"], w["kind"], "{line}\n{want}");
            for k in 0..2 {
                let (a, b) = (h["pixel"][k].as_f64().ok_or("pixel")?, w["pixel"][k].as_f64().ok_or("pixel")?);
                assert!((a - b).abs() < 0.01, "pixel {a} against {b}: {line}\n{want}");
            }
        }
        // Where both have a pose from the photo's own plane, the holes are where detect puts them.
        if line["pose"]["mode"] == "plane" && want["pose"]["mode"] == "plane" {
            posed += 1;
            for (h, w) in holes.iter().zip(want_holes) {
                for k in 0..3 {
                    let (a, b) = (
                        h["position_m"][k].as_f64().ok_or("position")?,
                        w["position_m"][k].as_f64().ok_or("position")?,
                    );
                    assert!((a - b).abs() < 1e-6, "position {a} m against {b} m: {line}\n{want}");
                }
            }
        }
    }
    assert!(posed >= 3, "only {posed} photos have a plane pose in both: {stderr}");
    assert!(stderr.contains("0 skipped"), "{stderr}");
    nothing_left_behind(&stderr)
}

#[test]
fn a_corrupt_or_oversized_file_is_reported_and_skipped_and_the_others_come_through() -> TestResult {
    let dir = tempfile::tempdir()?;
    render(dir.path(), "orange2x1", "2", "5")?;
    let good = images(dir.path())?;
    assert_eq!(good.len(), 2);
    let camera = dir.path().join("orange2x1_0000.camera.yaml");
    // A PNG cut short, one that is no image at all, and one larger than a frame may be.
    let mut png = Vec::new();
    image::open(&good[0])?.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    std::fs::write(dir.path().join("a_cut.png"), &png[..png.len() / 3])?;
    std::fs::write(dir.path().join("b_garbage.jpg"), b"this is not a JPEG")?;
    image::GrayImage::new(5000, 5000).save(dir.path().join("c_huge.png"))?;
    for bad in ["a_cut", "b_garbage", "c_huge"] {
        std::fs::copy(&camera, dir.path().join(format!("{bad}.camera.yaml")))?;
    }
    let logs = dir.path().join("logs");
    let demo = outlet(&[
        "demo",
        "--images",
        s(dir.path())?,
        "--rate",
        "4",
        "--json",
        "--duration",
        "120",
        "--logs",
        s(&logs)?,
    ])?;
    let stderr = String::from_utf8_lossy(&demo.stderr);
    assert!(demo.status.success(), "demo failed: {stderr}");
    let got = json_lines(&demo)?;
    let by_name: BTreeMap<String, &Value> = got.iter().map(|v| (name(v), v)).collect();
    assert_eq!(by_name.len(), 5, "{got:?}");
    for (bad, why) in [
        ("a_cut.png", "not a readable PNG or JPEG"),
        ("b_garbage.jpg", "not a readable PNG or JPEG"),
        ("c_huge.png", "more than a frame may have"),
    ] {
        let line = by_name[bad];
        let error = line["error"].as_str().ok_or("no error")?;
        assert!(error.contains("skipped") && error.contains(why), "{line}");
        assert_eq!(line["found"], false);
        assert!(line.get("frame_id").is_none(), "{line}");
    }
    let mut found = 0;
    for image in &good {
        let line = by_name[&image.file_name().ok_or("name")?.to_string_lossy().into_owned()];
        assert!(line.get("error").is_none(), "{line}");
        assert!(line["frame_id"].as_u64().is_some(), "{line}");
        if line["found"] == true {
            found += 1;
            assert_eq!(line["holes"].as_array().map(Vec::len), Some(6), "{line}");
        }
    }
    assert!(found >= 1, "the good photos gave no outlet: {got:?}");
    assert!(stderr.contains("3 skipped"), "{stderr}");
    // The file source says which file and why in its log.
    let log = std::fs::read_to_string(logs.join("files.log"))?;
    for bad in ["a_cut.png", "b_garbage.jpg", "c_huge.png"] {
        assert!(log.lines().any(|l| l.contains(bad) && l.contains("skipped")), "{bad} not reported:\n{log}");
    }
    nothing_left_behind(&stderr)
}

#[test]
fn files_go_out_as_a_camera_frames_with_their_camera_and_cloud_again_with_loop() -> TestResult {
    let dir = tempfile::tempdir()?;
    render(dir.path(), "white2x2", "2", "8")?;
    let images = images(dir.path())?;
    let domain = common::domain("servefiles");
    let node = shm::node(&domain, "test")?;
    // Readers first: the file source waits for a frame reader before its first frame.
    let frames = shm::frames(&node)?.subscriber_builder().create()?;
    let clouds = shm::clouds(&node)?.subscriber_builder().create()?;
    let files = shm::messages::<FileFrameMsg>(&node, service::FILES)?.subscriber_builder().create()?;
    let pattern = format!("{}/*", s(dir.path())?);
    let ply = format!("{}/*.ply", s(dir.path())?);
    let mut services = common::Services::start(
        &domain,
        &[&["files", "--images", &pattern, "--points", &ply, "--rate", "20", "--loop"]],
    )?;

    let mut seen: BTreeMap<u64, (FileFrameMsg, bool, bool)> = BTreeMap::new();
    let start = Instant::now();
    while seen.values().filter(|(_, frame, cloud)| *frame && *cloud).count() < 4 {
        assert!(start.elapsed() < Duration::from_secs(30), "frames seen: {:?}", seen.keys());
        assert!(services.all_running(), "serve files died");
        while let Some(m) = files.receive()? {
            let m = *m.payload();
            assert_eq!(m.status, file_status::SENT, "{}: {}", m.image(), m.reason());
            seen.entry(m.frame_id).or_insert((m, false, false)).0 = m;
        }
        // The frame: the image's pixels and its camera, exactly.
        while let Some(f) = frames.receive()? {
            let header = *f.user_header();
            let (format, camera) = header.validate(f.payload().len())?;
            let Some(entry) = seen.get_mut(&header.frame_id) else { continue };
            let image = Path::new(entry.0.image()).to_path_buf();
            let stem = image.file_stem().ok_or("stem")?.to_string_lossy().into_owned();
            assert_eq!(format, PixelFormat::Rgb8);
            assert_eq!(camera, read_camera_info(&dir.path().join(format!("{stem}.camera.yaml")))?);
            assert!(f.payload() == image::open(&image)?.to_rgb8().as_raw().as_slice(), "pixels of {}", image.display());
            assert_eq!(entry.0.capture_time_ns, header.capture_time_ns);
            entry.1 = true;
        }
        // Its cloud: the file of its stem, with the frame's id and stamp.
        while let Some(c) = clouds.receive()? {
            let header = *c.user_header();
            header.validate(c.payload().len())?;
            let Some(entry) = seen.get_mut(&header.frame_id) else { continue };
            let stem = Path::new(entry.0.image()).file_stem().ok_or("stem")?.to_string_lossy().into_owned();
            let cloud = read_ply(&dir.path().join(format!("{stem}.ply")))?;
            assert_eq!(header.points as usize, cloud.len());
            assert!(c.payload().iter().zip(cloud.as_flattened()).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert_eq!(entry.0.capture_time_ns, header.capture_time_ns);
            entry.2 = true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    // In the list's order, pass after pass: frame k is file (k - 1) mod 2 of pass (k - 1) / 2.
    for (frame_id, (m, _, _)) in &seen {
        let k = (frame_id - 1) as usize;
        assert_eq!((m.index as usize, m.pass as usize, m.files), (k % 2, k / 2, 2), "frame {frame_id}");
        assert_eq!(Path::new(m.image()), images[k % 2]);
    }
    assert!(seen.keys().any(|&f| f > 2), "--loop sent the files again");
    Ok(())
}

#[test]
fn an_image_without_a_camera_stops_the_service_at_start_naming_it() -> TestResult {
    let dir = tempfile::tempdir()?;
    image::RgbImage::new(8, 6).save(dir.path().join("lonely.png"))?;
    let pattern = format!("{}/*.png", s(dir.path())?);
    let domain = common::domain("filesnocam");
    let out = outlet(&["serve", "--domain", &domain, "files", "--images", &pattern])?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("no camera for") && stderr.contains("lonely.png") && stderr.contains("--camera"),
        "{stderr}"
    );
    outlet_protocol::shm::remove_node_counter(&domain);
    Ok(())
}
