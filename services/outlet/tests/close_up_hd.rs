//! Every distance, every camera (issue 21): an HD camera (1920x1080, f = 1181 px)
//! 20 cm from a 2x1 sees slots 75 px apart, beyond what the descriptor and the
//! hashing know at full resolution; the detector's half-resolution look finds it,
//! every hole within the paper's 5 px.

use serde_json::Value;
use std::process::Command;

fn outlet(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_outlet")).args(args).output().expect("run outlet")
}

#[test]
fn an_hd_close_up_beyond_the_full_resolution_scales_is_found() {
    let dir = tempfile::tempdir().expect("tmp");
    let out_dir = dir.path().to_str().expect("utf-8");
    let out = outlet(&[
        "render",
        "--scenario",
        "fw_2x1white",
        "--count",
        "5",
        "--seed",
        "1000",
        "--width",
        "1920",
        "--height",
        "1080",
        "--focal",
        "1181",
        "--out",
        out_dir,
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // View 4 is 20 cm away, nearly head-on.
    let stem = "fw_2x1white_0004";
    let truth: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join(format!("{stem}.json"))).expect("truth")).expect("json");
    let pixel = |v: &Value, k: usize| [v["holes"][k]["pixel"][0].as_f64(), v["holes"][k]["pixel"][1].as_f64()];
    let ([Some(nu), Some(nv)], [Some(hu), Some(hv)]) = (pixel(&truth, 0), pixel(&truth, 1)) else {
        panic!("truth without hole pixels: {truth}")
    };
    let pitch = (nu - hu).hypot(nv - hv);
    assert!(pitch > 60.0, "slot pitch {pitch:.0} px: not the close-up this test is about");
    let image = truth["image"].as_str().expect("image name");
    let out = outlet(&[
        "detect",
        "--template",
        "2x1",
        "--camera",
        dir.path().join(format!("{stem}.camera.yaml")).to_str().expect("utf-8"),
        "--json",
        dir.path().join(image).to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let found: Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    assert_eq!(found["found"].as_bool(), Some(true), "{found}");
    for k in 0..6 {
        let ([Some(u), Some(v)], [Some(tu), Some(tv)]) = (pixel(&found, k), pixel(&truth, k)) else {
            panic!("hole {k} without a pixel: {found}")
        };
        let e = (u - tu).hypot(v - tv);
        assert!(e < 5.0, "hole {k}: {e:.1} px from the truth");
    }
}
