//! Rendered scenes whose holes the detector finds: the inputs of the ROS 2
//! interop tests (Cyclone DDS, Fast DDS), which need views the pipeline
//! answers, at one or several image sizes.

use crate::outlet_exe;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A scene is kept only when `outlet detect` finds its holes this close to the truth (m).
pub const DETECT_TOLERANCE_M: f64 = 0.5e-3;

/// Which views to render and how many to keep.
#[derive(Debug, Clone)]
pub struct SceneRequest<'a> {
    pub scenario: &'a str,
    pub width: u32,
    pub height: u32,
    /// The stereo cloud: one point every this many pixels (`outlet render --cloud-step`).
    pub cloud_step: u32,
    /// Views rendered (seed 1), of which the first `keep` detected ones are kept.
    pub candidates: usize,
    pub keep: usize,
    /// Put before each kept scene's stem (and its files' names), so that scenes
    /// of several sizes can share a folder.
    pub prefix: &'a str,
}

/// Renders `request.candidates` views into `work/<prefix>all` and copies into
/// `into` the first `request.keep` whose holes `outlet detect` finds (plane
/// mode, each hole within [`DETECT_TOLERANCE_M`] of the truth): the bridge
/// answers only detected views. Each kept scene is `STEM.json` (its `image`
/// renamed too), `STEM.camera.yaml`, `STEM.ply` and the image, STEM prefixed.
/// Returns the kept stems, in order.
pub fn detectable_scenes(work: &Path, into: &Path, request: &SceneRequest) -> Result<Vec<String>, String> {
    let exe = outlet_exe()?;
    let all = work.join(format!("{}all", request.prefix));
    std::fs::create_dir_all(into).map_err(|e| format!("{}: {e}", into.display()))?;
    let out = Command::new(&exe)
        .args(["render", "--scenario", request.scenario, "--seed", "1", "--threads", "2"])
        .args(["--count", &request.candidates.to_string()])
        .args(["--width", &request.width.to_string(), "--height", &request.height.to_string()])
        .args(["--cloud-step", &request.cloud_step.to_string()])
        .arg("--out")
        .arg(&all)
        .output()
        .map_err(|e| format!("outlet render: {e}"))?;
    if !out.status.success() {
        return Err(format!("outlet render: {}", String::from_utf8_lossy(&out.stderr)));
    }

    let read_json = |path: PathBuf| -> Result<serde_json::Value, String> {
        let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))
    };
    let mut stems: Vec<String> = std::fs::read_dir(&all)
        .map_err(|e| format!("{}: {e}", all.display()))?
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.strip_suffix(".camera.yaml").map(String::from))
        .collect();
    stems.sort();
    let mut manifest = String::new();
    let mut truths = Vec::new();
    for stem in &stems {
        let truth = read_json(all.join(format!("{stem}.json")))?;
        let image = truth["image"].as_str().ok_or("truth without an image")?.to_string();
        let line = serde_json::json!({
            "image": image, "camera": format!("{stem}.camera.yaml"), "points": format!("{stem}.ply"), "template": "2x1"
        });
        manifest.push_str(&format!("{line}\n"));
        truths.push(truth);
    }
    std::fs::write(all.join("manifest.jsonl"), manifest).map_err(|e| e.to_string())?;
    let out = Command::new(&exe)
        .arg("detect")
        .arg("--batch")
        .arg(all.join("manifest.jsonl"))
        .arg("--json")
        .output()
        .map_err(|e| format!("outlet detect: {e}"))?;
    if !out.status.success() {
        return Err(format!("outlet detect: {}", String::from_utf8_lossy(&out.stderr)));
    }

    let mut kept = Vec::new();
    for ((stem, truth), line) in stems.iter().zip(&truths).zip(String::from_utf8_lossy(&out.stdout).lines()) {
        if kept.len() == request.keep {
            break;
        }
        let found: serde_json::Value = serde_json::from_str(line).map_err(|e| format!("outlet detect --json: {e}"))?;
        if !found_within_tolerance(&found, truth) {
            continue;
        }
        let image = truth["image"].as_str().ok_or("truth without an image")?;
        let new_stem = format!("{}{stem}", request.prefix);
        let new_image = format!("{}{image}", request.prefix);
        let mut renamed = truth.clone();
        renamed["image"] = serde_json::Value::String(new_image.clone());
        let copies = [
            (image.to_string(), new_image),
            (format!("{stem}.camera.yaml"), format!("{new_stem}.camera.yaml")),
            (format!("{stem}.ply"), format!("{new_stem}.ply")),
        ];
        for (from, to) in copies {
            std::fs::copy(all.join(&from), into.join(&to)).map_err(|e| format!("copying {from}: {e}"))?;
        }
        let json = serde_json::to_string_pretty(&renamed).map_err(|e| e.to_string())?;
        std::fs::write(into.join(format!("{new_stem}.json")), json).map_err(|e| e.to_string())?;
        kept.push(new_stem);
    }
    if kept.len() < request.keep {
        return Err(format!(
            "only {kept:?} of {} {}x{} views of {} were detected within {DETECT_TOLERANCE_M} m ({} wanted)",
            stems.len(),
            request.width,
            request.height,
            request.scenario,
            request.keep
        ));
    }
    Ok(kept)
}

/// `outlet detect --json`'s answer found every hole of the truth, in plane
/// mode, within [`DETECT_TOLERANCE_M`].
fn found_within_tolerance(found: &serde_json::Value, truth: &serde_json::Value) -> bool {
    let holes = found["holes"].as_array().cloned().unwrap_or_default();
    let expected = truth["holes"].as_array().cloned().unwrap_or_default();
    found["found"] == true
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
        })
}
