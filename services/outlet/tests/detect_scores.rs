//! `outlet detect --json` gives every hole its verification evidence (`score`)
//! and its pixel standard deviation (`sigma_px`) and covariance (`covariance_px`)
//! beside the CONTRACT keys.

use serde_json::Value;
use std::process::Command;

fn outlet(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_outlet")).args(args).output().expect("run outlet")
}

#[test]
fn detect_json_gives_each_hole_its_score_and_sigma() {
    let dir = tempfile::tempdir().expect("tmp");
    let camera = outlet_protocol::CameraModel::default_vga();
    // A near-frontal, well-exposed scene: the keys are tested, not the detector.
    let seed = (0..200)
        .find(|&s| {
            let scene = outlet_sim::sample_scene("fw_2x1white", s, 0, &camera).expect("scene");
            let v = outlet_sim::truth::view(&scene);
            v.off_axis_deg < 15.0 && v.distance_m < 0.35 && scene.sensor.exposure > 0.7 && scene.sensor.exposure < 1.3
        })
        .expect("a frontal scene");
    let d = dir.path().to_str().expect("utf-8");
    let seed = seed.to_string();
    let out = outlet(&["render", "--scenario", "fw_2x1white", "--count", "1", "--seed", &seed, "--out", d]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let png = dir.path().join("fw_2x1white_0000.png");
    let image = if png.exists() { png } else { dir.path().join("fw_2x1white_0000.jpg") };
    let camera_yaml = dir.path().join("fw_2x1white_0000.camera.yaml");
    let out = outlet(&[
        "detect",
        "--template",
        "2x1",
        "--camera",
        camera_yaml.to_str().expect("utf-8"),
        "--json",
        image.to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let line: Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert_eq!(line["found"].as_bool(), Some(true), "{line}");
    let holes = line["holes"].as_array().expect("holes");
    assert_eq!(holes.len(), 6);
    for h in holes {
        for key in ["kind", "pixel", "position_m", "covariance_m2"] {
            assert!(h.get(key).is_some(), "CONTRACT key {key} missing: {h}");
        }
        let score = h["score"].as_f64().expect("score");
        let sigma = h["sigma_px"].as_f64().expect("sigma_px");
        assert!(score > 0.0 && score <= 1.0, "score {score}");
        assert!(sigma > 0.0 && sigma < 1.0, "sigma_px {sigma}");
        // The 2x2 pixel covariance: symmetric, positive definite, its mean
        // variance sigma_px².
        let c: Vec<Vec<f64>> = serde_json::from_value(h["covariance_px"].clone()).expect("covariance_px 2x2");
        assert_eq!((c.len(), c[0].len(), c[1].len()), (2, 2, 2), "{c:?}");
        assert!((c[0][1] - c[1][0]).abs() < 1e-12 && c[0][0] > 0.0 && c[0][0] * c[1][1] > c[0][1].powi(2), "{c:?}");
        assert!(((c[0][0] + c[1][1]) / 2.0 - sigma * sigma).abs() < 1e-9 * sigma * sigma, "{c:?} vs {sigma}");
    }
}
