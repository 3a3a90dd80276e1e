//! `outlet demo`, the README's first command: the whole sidecar as child
//! processes, results within a millimetre of the truth, and nothing left behind.

use std::process::Command;

#[test]
fn the_demo_prints_json_results_under_a_millimetre_and_cleans_up() -> Result<(), Box<dyn std::error::Error>> {
    let out = Command::new(env!("CARGO_BIN_EXE_outlet"))
        .args(["demo", "--duration", "8", "--json", "--views", "4", "--rate", "10"])
        .output()?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed: {stderr}");
    let lines: Vec<serde_json::Value> =
        String::from_utf8(out.stdout)?.lines().map(serde_json::from_str).collect::<Result<_, _>>()?;
    assert!(lines.len() >= 5, "only {} results in 8 s: {stderr}", lines.len());
    let mut plane = 0;
    for l in &lines {
        if l["status"] != "ok" {
            // Ambiguous or plane mismatch: no pose, so no holes and no false alarm.
            assert_eq!(l["holes"].as_array().map(Vec::len), Some(0), "{l}");
            assert_eq!(l["false_alarm"], false);
            continue;
        }
        assert_eq!(l["holes"].as_array().map(Vec::len), Some(6), "{l}");
        assert_eq!(l["false_alarm"], false);
        if l["mode"] == "plane" {
            plane += 1;
            let e = l["max_error_mm"].as_f64().ok_or("no error against the truth")?;
            assert!(e < 1.0, "hole error {e} mm: {l}");
        }
        assert!(l["latency_ms"].as_f64().is_some_and(|v| v > 0.0 && v < 1000.0), "{l}");
    }
    assert!(plane * 2 >= lines.len(), "{plane} of {} results in plane mode", lines.len());
    assert!(stderr.contains("0 false alarms"), "{stderr}");

    // The demo's domain is its own: every file of it is gone.
    let domain = stderr.split("domain ").nth(1).and_then(|s| s.split_whitespace().next()).ok_or("no domain")?;
    let left: Vec<_> = std::fs::read_dir("/dev/shm")?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.starts_with(&format!("{domain}_")))
        .collect();
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");
    Ok(())
}

/// `outlet demo | head -1`: the reader goes away, the demo stops its services
/// and ends without an error (it used to panic on the closed pipe).
#[test]
fn the_demo_ends_cleanly_when_its_reader_goes_away() -> Result<(), Box<dyn std::error::Error>> {
    use std::io::BufRead;
    let mut child = Command::new(env!("CARGO_BIN_EXE_outlet"))
        .args(["demo", "--duration", "60", "--json", "--views", "4", "--rate", "10"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    let stdout = child.stdout.take().ok_or("no stdout")?;
    let mut first = String::new();
    std::io::BufReader::new(stdout).read_line(&mut first)?;
    // The reader drops here, as `head -1` would after its line.
    let out = child.wait_with_output()?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(serde_json::from_str::<serde_json::Value>(&first).is_ok(), "first line {first:?}");
    assert!(out.status.success(), "demo failed: {stderr}");
    assert!(stderr.contains("stdout closed"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    Ok(())
}
