//! A 2x2 in a specular highlight, approached from 60 cm (issue 21): at 60 cm a VGA
//! camera sees its slots 9 px long, too short to tell neutral from hot, and its
//! ground holes only 0.16 darker than the places a half-turned reading would put
//! them (the face clipped near 240). The ground holes must still decide the half
//! turn (`DetectorParams::ground_decides`), and nothing found may be wrong.

use serde_json::Value;
use std::process::Command;

#[test]
fn a_glared_2x2_at_60_cm_is_found_by_its_ground_holes_and_nothing_is_wrong() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = Command::new(env!("CARGO_BIN_EXE_outlet"))
        .args(["eval", "--approach", "--scenario", "specular2x2", "--count", "3", "--threads", "2", "--out"])
        .arg(dir.path())
        .output()
        .expect("run outlet");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(dir.path().join("approach.jsonl")).expect("approach.jsonl");
    let views: Vec<Value> = text.lines().map(|l| serde_json::from_str(l).expect("json")).collect();
    assert_eq!(views.len(), 81, "3 approaches, 9 distances, 3 cameras");
    let wrong: Vec<&Value> =
        views.iter().filter(|v| v["found"].as_bool() == Some(true) && v["correct"].as_bool() != Some(true)).collect();
    assert!(wrong.is_empty(), "wrong outlets: {wrong:?}");
    let glared = views
        .iter()
        .find(|v| v["approach"] == 2 && v["camera"] == "640x480" && v["distance_m"].as_f64() == Some(0.6))
        .expect("approach 2 at 60 cm, VGA");
    assert_eq!(glared["correct"].as_bool(), Some(true), "{glared}");
}
