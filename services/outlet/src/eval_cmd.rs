//! `outlet eval`: the paper's Table I on rendered scenarios, plus where the time
//! goes and how detection varies with the viewing angle and distance.

use crate::render_cmd::CameraArgs;
use anyhow::{Context, Result};
use clap::Args;
use outlet_detector::detect::{Detector, DetectorParams, StageTimes};
use outlet_sim::{SCENARIOS, paper_count, render_frame, sample_scene};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Mutex;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Scenario name or `all`.
    #[arg(long, default_value = "all")]
    pub scenario: String,
    /// Images per scenario (default: the paper's counts, 300 negatives).
    #[arg(long)]
    pub count: Option<usize>,
    /// Seed of the rendered scenes (use another than the tests' to evaluate fairly).
    #[arg(long, default_value_t = 1000)]
    pub seed: u64,
    /// Folder for table.md, results.jsonl, the plots (rates, errors, timing; PNG and
    /// SVG) and report.html, which shows them all in a browser.
    #[arg(long, default_value = "eval")]
    pub out: PathBuf,
    /// Worker threads (1 gives the cleanest timings).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// A hole counts as found within this many pixels (the paper: 5).
    #[arg(long, default_value_t = 5.0)]
    pub tolerance_px: f64,
    #[command(flatten)]
    pub camera: CameraArgs,
    /// Instead of Table I: whether the pose covariances hold, the NEES of every
    /// hole per pose mode over the positive scenarios (`nees.md`, `nees.jsonl`;
    /// `--count` frames per scenario, default 150).
    #[arg(long)]
    pub nees: bool,
    /// Instead of Table I: approaches from 60 to 10 cm seen by a 640x480, a
    /// 1280x960 and a 1920x1080 camera (`approach.md`, `approach.jsonl`,
    /// `approach.png`; `--count` approaches per scenario, default 5).
    #[arg(long)]
    pub approach: bool,
    /// Plane mode: what the stereo plane cannot know, "FACE_MM,TILT_DEG,DISTANCE_MM"
    /// (as `outlet detect --model-error`); "0,0,0" for exact faces and an unbiased cloud.
    #[arg(long, default_value = "1.15,0.48,1.32", value_parser = outlet::ModelError::parse)]
    pub model_error: outlet::ModelError,
    /// Evaluate on the labelled photographs of this folder (`*.labels.json`, as
    /// `outlet train` takes them; `camera.yaml` optional) and on turned and zoomed
    /// views of each, instead of rendered scenarios. Repeat it to keep labels in
    /// one folder and the photographs in another.
    #[arg(long)]
    pub photos: Vec<PathBuf>,
    /// With --photos: turned views per photograph.
    #[arg(long, default_value_t = 30)]
    pub views: usize,
    /// With --photos: the template (built-in name or file); default each label file's own.
    #[arg(long)]
    pub template: Option<String>,
    /// With --photos: the largest turn of a view's optical axis (degrees).
    #[arg(long, default_value_t = 25.0)]
    pub max_turn_deg: f64,
    /// With --photos: write the first this many views of each photograph (PNG,
    /// with its camera_info YAML) under `OUT/views`, to rerun `outlet detect` on them.
    #[arg(long, default_value_t = 3)]
    pub save_views: usize,
    /// Redraw the plots and report.html of OUT from its results.jsonl and table.md
    /// (an earlier run's), without evaluating again.
    #[arg(long, conflicts_with_all = ["nees", "approach", "photos"])]
    pub replot: bool,
}

/// The outcome of one image (a line of results.jsonl).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct Outcome {
    pub(crate) scenario: String,
    pub(crate) index: usize,
    pub(crate) positive: bool,
    pub(crate) found: bool,
    pub(crate) correct: bool,
    /// Per-hole pixel errors of a found outlet.
    pub(crate) errors_px: Vec<f64>,
    pub(crate) ms: f64,
    /// Candidates, classify, hash, refine (ms).
    pub(crate) stages: [f64; 4],
    pub(crate) off_axis_deg: f64,
    pub(crate) distance_m: f64,
    /// Hole position errors (mm) per pose mode, for correct detections.
    pub(crate) pose_mm: PoseErrors,
    /// Of the true holes: how many have a candidate on them, and how many of
    /// those the descriptor classed right (where a miss was lost).
    pub(crate) holes_with_candidate: usize,
    pub(crate) holes_classified: usize,
}

/// Hole position errors (mm) of each pose mode, and the Cramér-Rao bounds (RMS
/// over holes, mm) for the same pose, pixel noise and wall measurement.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct PoseErrors {
    pub(crate) mono: Vec<f64>,
    pub(crate) normal: Vec<f64>,
    pub(crate) normal_cloud: Vec<f64>,
    pub(crate) plane: Vec<f64>,
    pub(crate) bound_normal: Option<f64>,
    pub(crate) bound_plane: Option<f64>,
    /// RMS pixel error of this detection's holes: the measured pixel noise.
    pub(crate) pixel_rms: Option<f64>,
    /// What OpenCV needs to solve the same holes (tests/opencv_pnp.py).
    #[serde(skip)]
    pub(crate) opencv_input: Option<serde_json::Value>,
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

pub fn eval(args: EvalArgs) -> Result<()> {
    if args.replot {
        return replot(&args.out);
    }
    if args.nees {
        return crate::nees::eval_nees(&args);
    }
    if args.approach {
        return crate::approach_cmd::eval_approach(&args);
    }
    if !args.photos.is_empty() {
        return crate::photos_cmd::eval_photos(&crate::photos_cmd::PhotoEvalArgs {
            dirs: &args.photos,
            out: &args.out,
            views: args.views,
            seed: args.seed,
            template: args.template.as_deref(),
            max_turn_deg: args.max_turn_deg,
            slot_px: [8.0, 30.0],
            save_views: args.save_views,
        });
    }
    let camera = args.camera.camera()?;
    let scenarios: Vec<&str> = match args.scenario.as_str() {
        "all" => SCENARIOS.to_vec(),
        "realistic" => outlet_sim::REALISTIC_SCENARIOS.to_vec(),
        name => vec![outlet_sim::scenario_named(name).with_context(|| {
            format!(
                "unknown scenario {name:?}; known: all, realistic, {}, each also as rs_NAME (realistic stereo)",
                SCENARIOS.join(", ")
            )
        })?],
    };
    let t0 = std::time::Instant::now();
    let mut detectors = HashMap::new();
    for name in ["2x1", "2x2"] {
        detectors.insert(name, Detector::new(outlet::templates::builtin(name)?, DetectorParams::default()));
    }
    tracing::info!("templates ready in {:.0} ms", t0.elapsed().as_secs_f64() * 1e3);
    let jobs: Vec<(&str, usize)> = scenarios
        .iter()
        .flat_map(|s| (0..args.count.unwrap_or_else(|| paper_count(s))).map(move |i| (*s, i)))
        .collect();
    let bar = crate::progress::bar(jobs.len(), "evaluating");
    let outcomes = Mutex::new(Vec::with_capacity(jobs.len()));
    let next = std::sync::atomic::AtomicUsize::new(0);
    std::thread::scope(|s| {
        for _ in 0..args.threads.max(1) {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&(scenario, index)) = jobs.get(k) else { break };
                    match evaluate_one(scenario, index, &args, &camera, &detectors) {
                        Ok(o) => {
                            if let Ok(mut v) = outcomes.lock() {
                                v.push(o)
                            }
                        }
                        Err(e) => tracing::error!("{scenario} #{index}: {e:#}"),
                    }
                    bar.inc(1);
                }
            });
        }
    });
    bar.finish_and_clear();
    let mut outcomes = outcomes.into_inner().unwrap_or_default();
    outcomes.sort_by(|a, b| (a.scenario.as_str(), a.index).cmp(&(b.scenario.as_str(), b.index)));
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let table = table(&scenarios, &outcomes, &args, &camera);
    std::fs::write(args.out.join("table.md"), &table)?;
    let mut jsonl = String::new();
    for o in &outcomes {
        let _ = writeln!(jsonl, "{}", serde_json::to_string(o)?);
    }
    std::fs::write(args.out.join("results.jsonl"), jsonl)?;
    let mut pose_inputs = String::new();
    for o in &outcomes {
        if let Some(v) = &o.pose_mm.opencv_input {
            let _ = writeln!(pose_inputs, "{v}");
        }
    }
    std::fs::write(args.out.join("pose_inputs.jsonl"), pose_inputs)?;
    let report = write_plots_and_report(&args.out, &table, &outcomes)?;
    println!("{table}");
    tracing::info!("wrote {}/table.md, results.jsonl, plots and {}", args.out.display(), report.display());
    Ok(())
}

/// The plots of the outcomes and `OUT/report.html` with the table; returns the report's path.
fn write_plots_and_report(out: &std::path::Path, table: &str, outcomes: &[Outcome]) -> Result<PathBuf> {
    let figures = crate::eval_plots::figures(outcomes);
    for (stem, _, figure) in &figures {
        crate::plot::write(figure, out, stem)?;
    }
    let plots: Vec<crate::report_html::Plot> =
        figures.iter().map(|(stem, caption, _)| crate::report_html::Plot { stem, caption }).collect();
    crate::report_html::write(out, "outlet eval: Table I on rendered scenarios", table, &plots)
}

/// `--replot`: the plots and report of OUT again from its results.jsonl and table.md.
fn replot(out: &std::path::Path) -> Result<()> {
    let path = out.join("results.jsonl");
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let outcomes: Vec<Outcome> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(k, l)| serde_json::from_str(l).with_context(|| format!("{} line {}", path.display(), k + 1)))
        .collect::<Result<_>>()?;
    let table_path = out.join("table.md");
    let table = std::fs::read_to_string(&table_path).with_context(|| format!("reading {}", table_path.display()))?;
    let report = write_plots_and_report(out, &table, &outcomes)?;
    tracing::info!("redrew {} outcomes' plots and {}", outcomes.len(), report.display());
    Ok(())
}

fn evaluate_one(
    scenario: &str,
    index: usize,
    args: &EvalArgs,
    camera: &outlet_protocol::CameraModel,
    detectors: &HashMap<&str, Detector>,
) -> Result<Outcome> {
    let scene = sample_scene(scenario, args.seed, index as u64, camera)?;
    let frame = render_frame(&scene, "eval");
    let detector = detectors.get(scene.search_template.as_str()).context("no detector for the sought template")?;
    let t = std::time::Instant::now();
    let report = detector.detect(&frame.frame.image, Some(camera));
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let StageTimes { candidates, classify, hash, refine } = report.times;
    let truth = &frame.truth;
    let positive = truth.template.is_some();
    let errors_px: Vec<f64> = match &report.detection {
        Some(d) if positive => d
            .holes
            .iter()
            .zip(&truth.holes)
            .map(|(h, t)| ((h.pixel.x - t.pixel[0]).powi(2) + (h.pixel.y - t.pixel[1]).powi(2)).sqrt())
            .collect(),
        _ => Vec::new(),
    };
    let found = report.detection.is_some();
    let correct = positive && found && errors_px.iter().all(|e| *e <= args.tolerance_px);
    let (mut holes_with_candidate, mut holes_classified) = (0, 0);
    for hole in &truth.holes {
        let p = nalgebra::Point2::new(hole.pixel[0], hole.pixel[1]);
        let nearest = report
            .candidates
            .iter()
            .map(|(c, class)| ((c.centre - p).norm(), *class))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((d, class)) = nearest
            && d < 3.0
        {
            holes_with_candidate += 1;
            if class == outlet_detector::Class::from(hole.kind) {
                holes_classified += 1;
            }
        }
    }
    let pose_mm = match (&report.detection, correct) {
        (Some(d), true) => {
            let view = RenderedView { frame: &frame, scene: &scene, index };
            pose_errors(d, detector, camera, &view, &errors_px, &args.model_error)
        }
        _ => PoseErrors::default(),
    };
    let view = truth.view.unwrap_or(outlet_protocol::truth::ViewJson {
        distance_m: f64::NAN,
        off_axis_deg: f64::NAN,
        roll_deg: 0.0,
        ground_up: false,
    });
    Ok(Outcome {
        scenario: scenario.to_string(),
        index,
        positive,
        found,
        correct,
        errors_px,
        ms,
        stages: [candidates, classify, hash, refine],
        off_axis_deg: view.off_axis_deg,
        distance_m: view.distance_m,
        pose_mm,
        holes_with_candidate,
        holes_classified,
    })
}

/// Wall normal noise of the `normal` mode's evaluation (radians): 1 degree.
const NORMAL_NOISE_RAD: f64 = 0.017;

/// One rendered view: its frame, its scene and its index in the scenario.
struct RenderedView<'a> {
    frame: &'a outlet_sim::RenderedFrame,
    scene: &'a outlet_sim::Scene,
    index: usize,
}

fn pose_errors(
    detection: &outlet_detector::detect::Detection,
    detector: &Detector,
    camera: &outlet_protocol::CameraModel,
    view: &RenderedView,
    errors_px: &[f64],
    model_error: &outlet::ModelError,
) -> PoseErrors {
    use nalgebra::{Point2, Point3, Vector3};
    use outlet_pose::{Observations, cramer_rao, solve_mono, solve_normal};
    let RenderedView { frame, scene, index } = *view;
    let geometry = &detector.template().geometry;
    let model: Vec<Point2<f64>> = geometry.holes.iter().map(|h| h.position()).collect();
    let pixels: Vec<Point2<f64>> = detection.holes.iter().map(|h| h.pixel).collect();
    let truth: Vec<Point3<f64>> = frame.truth.holes.iter().filter_map(|h| h.position_m.map(Point3::from)).collect();
    let pixel_rms = (errors_px.iter().map(|e| e * e).sum::<f64>() / errors_px.len().max(1) as f64).sqrt();
    let obs = Observations::uniform(&model, &pixels, camera, 0.25);
    let errors = |holes: &[Point3<f64>]| -> Vec<f64> {
        holes.iter().zip(&truth).map(|(h, t)| (h - t).norm() * 1000.0).collect()
    };
    let mut out = PoseErrors { pixel_rms: Some(pixel_rms), ..PoseErrors::default() };
    if let Ok(p) = solve_mono(&obs) {
        out.mono = errors(&p.holes_cam_m);
    }
    // The true wall normal tilted by 1 degree in a direction drawn per image.
    let n_true = Vector3::from(frame.truth.wall_plane.normal);
    let [e1, e2] = outlet_pose::tangent_basis(&n_true);
    let a = (index as f64 * 2.399963) % std::f64::consts::TAU; // golden angle: spread directions
    let n_noisy = (n_true + (e1 * a.cos() + e2 * a.sin()) * NORMAL_NOISE_RAD.tan()).normalize();
    if let Ok(p) = solve_normal(&obs, &n_noisy, NORMAL_NOISE_RAD) {
        out.normal = errors(&p.holes_cam_m);
    }
    if let Ok(plane) = outlet_normal::fit_wall_plane(&frame.cloud, &outlet_normal::PlaneParams::default()) {
        let mut face = None;
        if let Ok((p, f)) = outlet::solve_plane_with_cloud(&obs, &plane, &frame.cloud, geometry, model_error) {
            out.plane = errors(&p.holes_cam_m);
            face = f;
        }
        let sigma = plane.covariance[(0, 0)].max(plane.covariance[(1, 1)]).sqrt();
        if let Ok(p) = solve_normal(&obs, &plane.normal, sigma) {
            out.normal_cloud = errors(&p.holes_cam_m);
        }
        // Bounds at the truth, with the measured pixel noise.
        let bound_obs = Observations { pixel_sigma: pixel_rms.max(0.01) / std::f64::consts::SQRT_2, ..obs };
        let rms = |c: Vec<nalgebra::Matrix3<f64>>| {
            (c.iter().map(|m| m.trace()).sum::<f64>() / c.len().max(1) as f64).sqrt() * 1000.0
        };
        let measurement = outlet::plane_measurement_with_face(&plane, geometry, model_error, face.as_ref());
        out.bound_plane = cramer_rao(&bound_obs, &scene.pose, Some(&measurement), None).ok().map(rms);
        out.bound_normal = cramer_rao(&bound_obs, &scene.pose, None, Some(NORMAL_NOISE_RAD)).ok().map(rms);
    }
    out.opencv_input = Some(serde_json::json!({
        "model_mm": model.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>(),
        "pixels": pixels.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>(),
        "camera_matrix": [camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0],
        "distortion": camera.distortion,
        "truth_m": truth.iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>(),
    }));
    out
}

fn table(scenarios: &[&str], outcomes: &[Outcome], args: &EvalArgs, camera: &outlet_protocol::CameraModel) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Rendered {}x{}, f = {:.0} px, seed {}; a detection is correct when every hole is within {} px.\n",
        camera.width, camera.height, camera.fx, args.seed, args.tolerance_px
    );
    let _ = writeln!(
        s,
        "| dataset | images | correct | false alarms | median ms | p95 ms | median hole error (px) | p95 hole error (px) |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut all_stages = [0.0; 4];
    for scenario in scenarios {
        let o: Vec<&Outcome> = outcomes.iter().filter(|o| o.scenario == *scenario).collect();
        let correct = o.iter().filter(|o| o.correct).count();
        let false_alarms = o.iter().filter(|o| o.found && !o.correct).count();
        let mut ms: Vec<f64> = o.iter().map(|o| o.ms).collect();
        ms.sort_by(f64::total_cmp);
        let mut errors: Vec<f64> = o.iter().filter(|o| o.correct).flat_map(|o| o.errors_px.iter().copied()).collect();
        errors.sort_by(f64::total_cmp);
        for x in &o {
            for (a, b) in all_stages.iter_mut().zip(x.stages) {
                *a += b;
            }
        }
        let fmt = |v: f64| if v.is_nan() { "-".to_string() } else { format!("{v:.3}") };
        let _ = writeln!(
            s,
            "| {scenario} | {} | {correct} | {false_alarms} | {:.2} | {:.2} | {} | {} |",
            o.len(),
            percentile(&ms, 0.5),
            percentile(&ms, 0.95),
            fmt(percentile(&errors, 0.5)),
            fmt(percentile(&errors, 0.95)),
        );
    }
    // Where the misses were lost: the first stage that fell below the paper's
    // score S (4 of 6, 8 of 12).
    let misses: Vec<&Outcome> = outcomes.iter().filter(|o| o.positive && !o.correct).collect();
    let needed = |o: &Outcome| if o.scenario.contains("2x2") { 8 } else { 4 };
    let no_candidates = misses.iter().filter(|o| o.holes_with_candidate < needed(o)).count();
    let misclassified =
        misses.iter().filter(|o| o.holes_with_candidate >= needed(o) && o.holes_classified < needed(o)).count();
    let _ = writeln!(
        s,
        "\nMisses ({}): {no_candidates} with too few holes among the candidates, {misclassified} with too few classed right, {} lost in hashing or verification.",
        misses.len(),
        misses.len() - no_candidates - misclassified
    );
    let _ = writeln!(s, "\n{}", pose_table(outcomes));
    let n = outcomes.len().max(1) as f64;
    let _ = writeln!(
        s,
        "\nMean time per stage (ms): candidates {:.2}, classify {:.2}, hash {:.2}, refine {:.2}.",
        all_stages[0] / n,
        all_stages[1] / n,
        all_stages[2] / n,
        all_stages[3] / n
    );
    s
}

/// Hole position error per pose mode over the correct detections, beside the
/// Cramér-Rao bounds at the measured pixel noise.
fn pose_table(outcomes: &[Outcome]) -> String {
    let mut s = String::new();
    let stats = |mut v: Vec<f64>| -> (f64, f64, usize) {
        v.retain(|x| x.is_finite());
        v.sort_by(f64::total_cmp);
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        (rms, percentile(&v, 0.95), v.len())
    };
    let images = outcomes.iter().filter(|o| o.pose_mm.pixel_rms.is_some()).count();
    let mut pixel: Vec<f64> = outcomes.iter().filter_map(|o| o.pose_mm.pixel_rms).collect();
    pixel.sort_by(f64::total_cmp);
    let _ = writeln!(
        s,
        "Hole position error over {images} correct detections (measured pixel noise: median RMS {:.3} px):\n",
        percentile(&pixel, 0.5)
    );
    let _ = writeln!(s, "| mode | what it uses | holes | RMS (mm) | p95 (mm) | Cramér-Rao bound, RMS (mm) |");
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|");
    let bound = |f: fn(&PoseErrors) -> Option<f64>| {
        let v: Vec<f64> = outcomes.iter().filter_map(|o| f(&o.pose_mm)).collect();
        if v.is_empty() {
            "-".to_string()
        } else {
            format!("{:.3}", (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
        }
    };
    let rows: [(&str, &str, Vec<f64>, String); 4] = [
        (
            "plane",
            "pixels + stereo cloud (normal and distance)",
            outcomes.iter().flat_map(|o| o.pose_mm.plane.clone()).collect(),
            bound(|p| p.bound_plane),
        ),
        (
            "normal",
            "pixels + wall normal with 1 deg noise (paper)",
            outcomes.iter().flat_map(|o| o.pose_mm.normal.clone()).collect(),
            bound(|p| p.bound_normal),
        ),
        (
            "normal",
            "pixels + the cloud's normal (paper)",
            outcomes.iter().flat_map(|o| o.pose_mm.normal_cloud.clone()).collect(),
            "-".to_string(),
        ),
        (
            "mono",
            "pixels only (planar PnP)",
            outcomes.iter().flat_map(|o| o.pose_mm.mono.clone()).collect(),
            "-".to_string(),
        ),
    ];
    for (mode, uses, errors, b) in rows {
        let (rms, p95, n) = stats(errors);
        let _ = writeln!(s, "| {mode} | {uses} | {n} | {rms:.3} | {p95:.3} | {b} |");
    }
    s
}
