//! `outlet trials` (issue 18): 20 approaches with fixed seeds through the CLI,
//! the sidecar's services over shared memory and the client library. Every
//! trial is classified, most go in, none goes into a wrong place, and a trial
//! repeated alone gives the same outcome.

use serde_json::Value;
use std::process::Command;

fn trials(args: &[&str]) -> Result<(Vec<Value>, String), Box<dyn std::error::Error>> {
    let out = Command::new(env!("CARGO_BIN_EXE_outlet")).arg("trials").args(args).arg("--json").output()?;
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "trials failed: {stderr}");
    let lines = String::from_utf8(out.stdout)?.lines().map(serde_json::from_str).collect::<Result<Vec<Value>, _>>()?;
    Ok((lines, stderr))
}

const CLASSES: [&str; 9] = [
    "success",
    "never_found",
    "timed_out",
    "wrong_outlet",
    "wrong_receptacle",
    "wrong_polarity",
    "off_tolerance",
    "refused_would_have_succeeded",
    "correctly_refused",
];

#[test]
fn twenty_approaches_are_classified_and_none_goes_into_a_wrong_place() -> Result<(), Box<dyn std::error::Error>> {
    let (lines, stderr) = trials(&["--count", "20", "--seed", "18"])?;
    assert_eq!(lines.len(), 20, "{stderr}");
    let mut successes = 0;
    for (k, l) in lines.iter().enumerate() {
        assert_eq!(l["trial"], k as u64);
        let class = l["class"].as_str().ok_or("no class")?;
        assert!(CLASSES.contains(&class), "{l}");
        assert_eq!(l["wrong_insertion"], false, "{l}");
        assert!(!matches!(class, "wrong_outlet" | "wrong_receptacle" | "wrong_polarity"), "{l}");
        let frames = l["frames"].as_u64().ok_or("no frames")?;
        assert!((1..=30).contains(&frames), "{l}");
        let answered: u64 = l["statuses"].as_object().ok_or("no statuses")?.values().filter_map(Value::as_u64).sum();
        assert_eq!(answered, frames, "{l}");
        if class == "success" {
            successes += 1;
            // A success is a push inside the tolerances, measured on the true face.
            let errors = l["landing"]["errors_mm"].as_array().ok_or("no landing")?;
            let worst = errors.iter().filter_map(Value::as_f64).fold(0.0, f64::max);
            assert!(worst <= 1.5, "{l}");
            assert!(l["landing"]["axis_deg"].as_f64().is_some_and(|a| a <= 3.0), "{l}");
            assert!(l["time_to_insert_s"].as_f64().is_some_and(|t| t > 0.0), "{l}");
        }
    }
    assert!(successes >= 18, "{successes} of 20 went in: {stderr}");
    assert!(stderr.contains(&format!("Success: **{successes}/20")), "{stderr}");

    // Trial 7 alone: the same scene, the same arm, the same outcome.
    let (alone, _) = trials(&["--count", "1", "--first", "7", "--seed", "18"])?;
    assert_eq!(alone.len(), 1);
    for key in ["scenario", "class", "frames", "target", "range_m"] {
        assert_eq!(alone[0][key], lines[7][key], "{key}");
    }
    Ok(())
}

#[test]
fn the_hard_mix_runs_and_never_pushes_into_a_wrong_place() -> Result<(), Box<dyn std::error::Error>> {
    let (lines, stderr) = trials(&["--count", "6", "--seed", "5", "--scenario", "hard"])?;
    assert_eq!(lines.len(), 6, "{stderr}");
    for l in &lines {
        assert_eq!(l["ground_up"], true, "{l}");
        assert_eq!(l["light"], "dim", "{l}");
        assert!(l["yaw_deg"].as_f64().is_some_and(|y| y.abs() >= 25.0), "{l}");
        assert_eq!(l["wrong_insertion"], false, "{l}");
    }
    Ok(())
}
