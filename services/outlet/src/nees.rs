//! `outlet eval --nees`: whether the covariances the pose reports hold. For every
//! correctly detected outlet of the rendered scenarios, each mode (`plane` from
//! the stereo cloud, `normal` with a wall normal 1 degree off, `mono`) is solved
//! as the sidecar solves it, and every hole's normalised estimation error squared
//! `e^T C^-1 e` (3 degrees of freedom) is compared with the chi-square
//! distribution: mean near 3, about 0.1% beyond its 99.9% point (16.27).

use anyhow::{Context, Result};
use nalgebra::{Matrix3, Point2, Point3, Vector3};
use outlet_detector::detect::Detector;
use outlet_pose::{Observations, OutletPose, PoseError, solve_mono, solve_normal};
use outlet_sim::{render_frame, sample_scene};
use std::collections::HashMap;
use std::fmt::Write as _;

/// The chi-square 99.9% point with 3 degrees of freedom.
pub const CHI2_3_999: f64 = 16.266;
/// No hole's NEES may exceed this (issue 14).
pub const NEES_HARD_LIMIT: f64 = 25.0;
/// Wall normal noise of the `normal` mode (radians): 1 degree, as `outlet eval`.
pub const NORMAL_NOISE_RAD: f64 = 0.017;

/// The mean of NEES values over their 3 degrees of freedom (1 if honest; 0
/// without values).
pub fn mean_over_dof(nees: &[f64]) -> f64 {
    nees.iter().sum::<f64>() / nees.len().max(1) as f64 / 3.0
}

/// The share of NEES values beyond [`CHI2_3_999`] (0.001 if honest; 0 without values).
pub fn beyond_999(nees: &[f64]) -> f64 {
    nees.iter().filter(|v| **v > CHI2_3_999).count() as f64 / nees.len().max(1) as f64
}

/// The pose modes evaluated, in table order.
pub const MODES: [&str; 3] = ["plane", "normal", "mono"];

/// `e^T C^-1 e` of one hole; None when the covariance cannot be inverted.
pub fn nees(estimate: &Point3<f64>, truth: &Point3<f64>, covariance: &Matrix3<f64>) -> Option<f64> {
    let e = estimate - truth;
    let info = covariance.cholesky()?.inverse();
    let v = (e.transpose() * info * e)[0];
    v.is_finite().then_some(v)
}

/// The NEES of every hole of one mode, and the outcomes that gave no pose.
#[derive(Debug, Clone, Default)]
pub struct ModeStats {
    pub nees: Vec<f64>,
    /// Hole errors (mm), for the RMS beside the statistic.
    pub errors_mm: Vec<f64>,
    /// Frames refused as ambiguous (mono) or inconsistent.
    pub ambiguous: usize,
    /// Frames the mode could not solve at all.
    pub failed: usize,
    /// Frames solved.
    pub frames: usize,
}

impl ModeStats {
    pub fn add(&mut self, pose: &OutletPose, truth: &[Point3<f64>]) {
        self.frames += 1;
        for ((h, c), t) in pose.holes_cam_m.iter().zip(&pose.covariances).zip(truth) {
            self.nees.push(nees(h, t, c).unwrap_or(f64::INFINITY));
            self.errors_mm.push((h - t).norm() * 1e3);
        }
    }

    pub fn add_outcome(&mut self, outcome: Result<OutletPose, PoseError>, truth: &[Point3<f64>]) {
        match outcome {
            Ok(p) => self.add(&p, truth),
            Err(PoseError::Ambiguous { .. }) => self.ambiguous += 1,
            Err(_) => self.failed += 1,
        }
    }

    pub fn mean_over_dof(&self) -> f64 {
        mean_over_dof(&self.nees)
    }

    pub fn beyond_999(&self) -> f64 {
        beyond_999(&self.nees)
    }

    pub fn max(&self) -> f64 {
        self.nees.iter().copied().fold(0.0, f64::max)
    }

    pub fn rms_mm(&self) -> f64 {
        (self.errors_mm.iter().map(|e| e * e).sum::<f64>() / self.errors_mm.len().max(1) as f64).sqrt()
    }

    /// Issue 14's test: mean within [0.7, 1.4] x 3, at most 1% beyond the 99.9%
    /// point, none beyond 25.
    pub fn holds(&self) -> bool {
        let m = self.mean_over_dof();
        !self.nees.is_empty() && (0.7..=1.4).contains(&m) && self.beyond_999() <= 0.01 && self.max() <= NEES_HARD_LIMIT
    }
}

/// What one frame adds to the table, per mode and per group of frames.
#[derive(Debug, Clone, Default)]
pub struct NeesTable {
    /// (group, mode) -> statistics; group `all`, `oblique` (over 30 degrees
    /// off-axis), `blurred` (defocus over 0.6 px), `far` (over 40 cm).
    pub cells: HashMap<(&'static str, &'static str), ModeStats>,
    pub frames: usize,
    pub detected: usize,
    /// Median hole pixel error of the detections (px).
    pub pixel_errors: Vec<f64>,
    /// One JSON line per detected frame: its holes' NEES per mode.
    pub lines: Vec<String>,
}

pub const GROUPS: [&str; 4] = ["all", "oblique", "blurred", "far"];

impl NeesTable {
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let mut px = self.pixel_errors.clone();
        px.sort_by(f64::total_cmp);
        let median = px.get(px.len() / 2).copied().unwrap_or(f64::NAN);
        let _ = writeln!(
            s,
            "{} frames rendered, {} outlets correctly detected (median hole pixel error {median:.3} px)\n",
            self.frames, self.detected
        );
        let _ = writeln!(
            s,
            "| frames | mode | solved | holes | NEES mean / 3 | beyond 16.27 | max | error RMS (mm) | ambiguous | failed | holds |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
        for group in GROUPS {
            for mode in MODES {
                let Some(c) = self.cells.get(&(group, mode)) else { continue };
                let _ = writeln!(
                    s,
                    "| {group} | {mode} | {} | {} | {:.2} | {:.2}% | {:.1} | {:.3} | {} | {} | {} |",
                    c.frames,
                    c.nees.len(),
                    c.mean_over_dof(),
                    c.beyond_999() * 100.0,
                    c.max(),
                    c.rms_mm(),
                    c.ambiguous,
                    c.failed,
                    if c.holds() { "yes" } else { "no" }
                );
            }
        }
        s
    }
}

/// The pose inputs of one detection, as the sidecar would have them.
pub struct Inputs {
    pub model_mm: Vec<Point2<f64>>,
    pub pixels: Vec<Point2<f64>>,
    pub pixel_sigmas: Vec<f64>,
    pub pixel_shapes: Vec<nalgebra::Matrix2<f64>>,
    pub truth: Vec<Point3<f64>>,
}

/// Renders and detects view `index` of `scenario` and adds what each mode gives.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_frame(
    table: &mut NeesTable,
    scenario: &str,
    seed: u64,
    index: u64,
    camera: &outlet_protocol::CameraModel,
    detectors: &HashMap<&str, Detector>,
    tolerance_px: f64,
    pixel_sigma: f64,
    model_error: &outlet::ModelError,
) -> Result<()> {
    let scene = sample_scene(scenario, seed, index, camera)?;
    let frame = render_frame(&scene, "nees");
    table.frames += 1;
    let Some(geometry) = scene.geometry() else { return Ok(()) };
    let detector = detectors.get(scene.search_template.as_str()).context("no detector for the sought template")?;
    let report = detector.detect(&frame.frame.image, Some(camera));
    let Some(detection) = report.detection else { return Ok(()) };
    let truth: Vec<Point3<f64>> = frame.truth.holes.iter().filter_map(|h| h.position_m.map(Point3::from)).collect();
    if truth.len() != detection.holes.len() || truth.len() != geometry.holes.len() {
        return Ok(());
    }
    let errors_px: Vec<f64> = detection
        .holes
        .iter()
        .zip(&frame.truth.holes)
        .map(|(h, t)| ((h.pixel.x - t.pixel[0]).powi(2) + (h.pixel.y - t.pixel[1]).powi(2)).sqrt())
        .collect();
    if !errors_px.iter().all(|e| *e <= tolerance_px) {
        return Ok(());
    }
    table.detected += 1;
    table.pixel_errors.extend(&errors_px);
    let inputs = Inputs {
        model_mm: geometry.holes.iter().map(|h| h.position()).collect(),
        pixels: detection.holes.iter().map(|h| h.pixel).collect(),
        pixel_sigmas: detection.holes.iter().map(|h| h.sigma_px).collect(),
        pixel_shapes: detection.holes.iter().map(|h| h.shape).collect(),
        truth,
    };
    let obs = Observations {
        model_mm: &inputs.model_mm,
        pixels: &inputs.pixels,
        camera,
        pixel_sigma,
        pixel_sigmas: (!inputs.pixel_sigmas.is_empty()).then_some(inputs.pixel_sigmas.as_slice()),
        pixel_shapes: (!inputs.pixel_shapes.is_empty()).then_some(inputs.pixel_shapes.as_slice()),
    };
    let view = frame.truth.view;
    let mut groups = vec!["all"];
    if view.is_some_and(|v| v.off_axis_deg > 30.0) {
        groups.push("oblique");
    }
    if scene.sensor.blur_sigma > 0.6 {
        groups.push("blurred");
    }
    if view.is_some_and(|v| v.distance_m > 0.4) {
        groups.push("far");
    }
    let mean_error_px = {
        let n = detection.holes.len().max(1) as f64;
        let (sx, sy) = detection
            .holes
            .iter()
            .zip(&frame.truth.holes)
            .fold((0.0, 0.0), |(x, y), (h, t)| (x + h.pixel.x - t.pixel[0], y + h.pixel.y - t.pixel[1]));
        [sx / n, sy / n]
    };
    let mut record = serde_json::json!({
        "scenario": scenario, "index": index, "errors_px": errors_px,
        "blur": scene.sensor.blur_sigma, "off_axis_deg": view.map(|v| v.off_axis_deg),
        "distance_m": view.map(|v| v.distance_m),
        "mean_error_px": mean_error_px,
        "sigma_px": inputs.pixel_sigmas,
        "pixels": inputs.pixels.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>(),
        "shapes": inputs.pixel_shapes.iter().map(|s| [s[(0, 0)], s[(0, 1)], s[(1, 1)]]).collect::<Vec<_>>(),
        "errors_xy_px": detection.holes.iter().zip(&frame.truth.holes)
            .map(|(h, t)| [h.pixel.x - t.pixel[0], h.pixel.y - t.pixel[1]]).collect::<Vec<_>>(),
        "wall_normal": frame.truth.wall_plane.normal,
    });
    let mut add = |mode: &'static str, outcome: Result<OutletPose, PoseError>| {
        record[mode] = match &outcome {
            Ok(p) => serde_json::json!({
                "nees": p.holes_cam_m.iter().zip(&p.covariances).zip(&inputs.truth)
                    .map(|((h, c), t)| nees(h, t, c).unwrap_or(f64::INFINITY)).collect::<Vec<_>>(),
                "outliers": p.outliers, "variance_factor": p.variance_factor, "rms_px": p.rms_px,
                "err_mm": p.holes_cam_m.iter().zip(&inputs.truth).map(|(h, t)| ((h - t) * 1e3).as_slice().to_vec()).collect::<Vec<_>>(),
                "sigma_mm": p.covariances.iter().map(|c| [c[(0,0)].sqrt()*1e3, c[(1,1)].sqrt()*1e3, c[(2,2)].sqrt()*1e3]).collect::<Vec<_>>(),
                "cov_mm2": p.covariances.iter().map(|c| (c * 1e6).as_slice().to_vec()).collect::<Vec<_>>(),
            }),
            Err(e) => serde_json::json!({ "error": e.to_string() }),
        };
        for g in &groups {
            table.cells.entry((g, mode)).or_default().add_outcome(outcome.clone(), &inputs.truth);
        }
    };
    add("mono", solve_mono(&obs));
    // The true wall normal tilted by 1 degree in a direction drawn per image.
    let n_true = Vector3::from(frame.truth.wall_plane.normal);
    let [e1, e2] = outlet_pose::tangent_basis(&n_true);
    let a = (index as f64 * 2.399963) % std::f64::consts::TAU;
    let n_noisy = (n_true + (e1 * a.cos() + e2 * a.sin()) * NORMAL_NOISE_RAD.tan()).normalize();
    // A tilt of fixed size in a uniform direction is 1/sqrt(2) of it on each
    // tangent axis: the per-axis sigma the pose is told.
    add("normal", solve_normal(&obs, &n_noisy, NORMAL_NOISE_RAD * std::f64::consts::FRAC_1_SQRT_2));
    let plane = outlet_normal::fit_wall_plane(&frame.cloud, &outlet_normal::PlaneParams::default());
    match plane {
        Ok(plane) => {
            let solved = outlet::solve_plane_with_cloud(&obs, &plane, &frame.cloud, &geometry, model_error);
            add("plane", solved.map(|(pose, _)| pose));
        }
        Err(_) => add("plane", Err(PoseError::BadPlane)),
    }
    table.lines.push(record.to_string());
    Ok(())
}

/// Pixel noise the sidecar assumes where a hole has none of its own (px), as
/// the pose service's default `pixel_sigma`.
pub const DEFAULT_PIXEL_SIGMA: f64 = 0.25;

/// `outlet eval --nees`: the table over the positive scenarios (or the one
/// named), `count` frames each (default 150), into `OUT/nees.md`.
pub fn eval_nees(args: &crate::eval_cmd::EvalArgs) -> Result<()> {
    let camera = args.camera.camera()?;
    // `all`: the rendered scenarios; `realistic`: the same with realistic stereo
    // (rs_*: a biased, noisier cloud and the face 3-7 mm ahead of the wall).
    let scenarios: Vec<&str> = outlet_sim::SCENARIOS
        .iter()
        .chain(&outlet_sim::REALISTIC_SCENARIOS)
        .copied()
        .filter(|s| !s.ends_with("negative"))
        .filter(|s| match args.scenario.as_str() {
            "all" => !s.starts_with(outlet_sim::REALISTIC_STEREO_PREFIX),
            "realistic" => s.starts_with(outlet_sim::REALISTIC_STEREO_PREFIX),
            name => *s == name,
        })
        .collect();
    anyhow::ensure!(!scenarios.is_empty(), "no positive scenario named {:?}", args.scenario);
    let mut detectors = HashMap::new();
    for name in ["2x1", "2x2"] {
        detectors.insert(
            name,
            Detector::new(outlet::templates::builtin(name)?, outlet_detector::detect::DetectorParams::default()),
        );
    }
    let count = args.count.unwrap_or(150) as u64;
    let jobs: Vec<(&str, u64)> = scenarios.iter().flat_map(|s| (0..count).map(move |i| (*s, i))).collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let tables = std::sync::Mutex::new(Vec::new());
    let bar = crate::progress::bar(jobs.len(), "checking covariances");
    std::thread::scope(|scope| {
        for _ in 0..args.threads.max(1) {
            scope.spawn(|| {
                let mut table = NeesTable::default();
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&(scenario, index)) = jobs.get(k) else { break };
                    if let Err(e) = evaluate_frame(
                        &mut table,
                        scenario,
                        args.seed,
                        index,
                        &camera,
                        &detectors,
                        args.tolerance_px,
                        DEFAULT_PIXEL_SIGMA,
                        &args.model_error,
                    ) {
                        tracing::warn!("{scenario} #{index}: {e:#}");
                    }
                    bar.inc(1);
                }
                if let Ok(mut t) = tables.lock() {
                    t.push(table);
                }
            });
        }
    });
    bar.finish_and_clear();
    let mut table = NeesTable::default();
    for t in tables.into_inner().unwrap_or_default() {
        table.merge(t);
    }
    let text = table.markdown();
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    std::fs::write(args.out.join("nees.md"), &text)?;
    table.lines.sort();
    std::fs::write(args.out.join("nees.jsonl"), table.lines.join("\n") + "\n")?;
    println!("{text}");
    Ok(())
}

impl NeesTable {
    /// Adds another table's frames (from another worker thread).
    pub fn merge(&mut self, other: NeesTable) {
        self.frames += other.frames;
        self.detected += other.detected;
        self.pixel_errors.extend(other.pixel_errors);
        self.lines.extend(other.lines);
        for (key, c) in other.cells {
            let mine = self.cells.entry(key).or_default();
            mine.nees.extend(c.nees);
            mine.errors_mm.extend(c.errors_mm);
            mine.ambiguous += c.ambiguous;
            mine.failed += c.failed;
            mine.frames += c.frames;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two rendered frames (seed 1000) whose mono error bars once lied: a blurred
    /// white 2x1 at 47 cm (frame 101: a hole 56.7 of its NEES with one sigma for
    /// both axes of a slot) and a 2x1 at 48 cm, 12 degrees off-axis (frame 2: its
    /// pose tilted the wrong way, 26.8 with the linearised covariance alone), and a
    /// sharp 2x1 at 44 cm, 19 degrees off-axis (frame 85: mono's depth 10 mm off,
    /// 27.1 with mono's own noise share at 0.8). Each hole within issue 14's hard
    /// limit of 25 in every mode.
    #[test]
    fn the_mono_frames_that_lied_stay_within_their_error_bars() {
        let camera = outlet_protocol::CameraModel::default_vga();
        let mut detectors = HashMap::new();
        detectors.insert(
            "2x1",
            Detector::new(
                outlet::templates::builtin("2x1").expect("template"),
                outlet_detector::detect::DetectorParams::default(),
            ),
        );
        for (scenario, index) in [("fw_2x1white", 101), ("whitehall2x1", 2), ("fw_2x1white", 85)] {
            let mut table = NeesTable::default();
            evaluate_frame(
                &mut table,
                scenario,
                1000,
                index,
                &camera,
                &detectors,
                5.0,
                DEFAULT_PIXEL_SIGMA,
                &outlet::ModelError::NONE,
            )
            .expect("frame");
            assert_eq!(table.detected, 1, "{scenario} #{index} not detected");
            for mode in ["plane", "normal", "mono"] {
                let stats = table.cells.get(&("all", mode)).expect("mode");
                assert!(stats.max() <= 25.0, "{scenario} #{index} {mode}: NEES {:.1}", stats.max());
            }
        }
    }
}
