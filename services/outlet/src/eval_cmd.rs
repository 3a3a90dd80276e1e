//! `outlet eval`: the paper's Table I on rendered scenarios, plus where the time
//! goes and how detection varies with the viewing angle and distance.

use crate::render_cmd::CameraArgs;
use anyhow::{Context, Result};
use clap::Args;
use image::{Rgb, RgbImage};
use indicatif::{ProgressBar, ProgressStyle};
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
    /// Folder for table.md, rates.png and results.jsonl.
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
}

/// The outcome of one image.
#[derive(Debug, Clone, serde::Serialize)]
struct Outcome {
    scenario: String,
    index: usize,
    positive: bool,
    found: bool,
    correct: bool,
    /// Per-hole pixel errors of a found outlet.
    errors_px: Vec<f64>,
    ms: f64,
    stages: [f64; 4],
    off_axis_deg: f64,
    distance_m: f64,
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

pub fn eval(args: EvalArgs) -> Result<()> {
    let camera = args.camera.camera()?;
    let scenarios: Vec<&str> =
        if args.scenario == "all" {
            SCENARIOS.to_vec()
        } else {
            vec![SCENARIOS.iter().copied().find(|s| *s == args.scenario).with_context(|| {
                format!("unknown scenario {:?}; known: all, {}", args.scenario, SCENARIOS.join(", "))
            })?]
        };
    let t0 = std::time::Instant::now();
    let mut detectors = HashMap::new();
    for name in ["2x1", "2x2"] {
        detectors.insert(name, Detector::new(crate::templates::builtin(name)?, DetectorParams::default()));
    }
    tracing::info!("templates ready in {:.0} ms", t0.elapsed().as_secs_f64() * 1e3);
    let jobs: Vec<(&str, usize)> = scenarios
        .iter()
        .flat_map(|s| (0..args.count.unwrap_or_else(|| paper_count(s))).map(move |i| (*s, i)))
        .collect();
    let bar = ProgressBar::new(jobs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("evaluating [{bar:40}] {pos}/{len} ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
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
    plot(&outcomes).save_with_format(args.out.join("rates.png"), image::ImageFormat::Png)?;
    println!("{table}");
    tracing::info!("wrote {}/table.md, rates.png, results.jsonl", args.out.display());
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
    })
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

/// Two bar charts of the detection rate of the positive images: against the
/// off-axis angle (0-40 degrees) and the distance (20-50 cm).
fn plot(outcomes: &[Outcome]) -> RgbImage {
    let (w, h) = (900u32, 360u32);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let positives: Vec<&Outcome> = outcomes.iter().filter(|o| o.positive).collect();
    let panels: [(&str, Vec<(String, f64, usize)>); 2] = [
        ("detection rate vs off-axis angle (deg)", bins(&positives, |o| o.off_axis_deg, 0.0, 40.0, 8)),
        ("detection rate vs distance (cm)", bins(&positives, |o| o.distance_m * 100.0, 20.0, 50.0, 6)),
    ];
    for (p, (title, bars)) in panels.iter().enumerate() {
        let x0 = 40 + p as u32 * 440;
        let (plot_w, plot_h, y0) = (400u32, 240u32, 60u32);
        crate::font::draw_text(&mut img, title, x0, 16, 2, Rgb([0, 0, 0]));
        for k in 0..=4 {
            let y = y0 + plot_h - plot_h * k / 4;
            for x in x0..x0 + plot_w {
                img.put_pixel(x, y, Rgb([210, 210, 210]));
            }
            crate::font::draw_text(
                &mut img,
                &format!("{}%", k * 25),
                x0.saturating_sub(34),
                y.saturating_sub(3),
                1,
                Rgb([80, 80, 80]),
            );
        }
        let bw = plot_w / bars.len().max(1) as u32;
        for (i, (label, rate, n)) in bars.iter().enumerate() {
            let bx = x0 + i as u32 * bw;
            let top = y0 + plot_h - (plot_h as f64 * rate.clamp(0.0, 1.0)) as u32;
            let colour = if *n == 0 { Rgb([230, 230, 230]) } else { Rgb([60, 110, 200]) };
            for x in bx + 4..bx + bw - 4 {
                for y in top..y0 + plot_h {
                    img.put_pixel(x, y, colour);
                }
            }
            crate::font::draw_text(&mut img, label, bx + 4, y0 + plot_h + 8, 1, Rgb([0, 0, 0]));
            crate::font::draw_text(&mut img, &format!("n={n}"), bx + 4, y0 + plot_h + 20, 1, Rgb([100, 100, 100]));
        }
    }
    img
}

fn bins(o: &[&Outcome], key: impl Fn(&Outcome) -> f64, lo: f64, hi: f64, n: usize) -> Vec<(String, f64, usize)> {
    let step = (hi - lo) / n as f64;
    (0..n)
        .map(|k| {
            let (a, b) = (lo + k as f64 * step, lo + (k + 1) as f64 * step);
            let inside: Vec<&&Outcome> = o.iter().filter(|x| (a..b + 1e-9).contains(&key(x))).collect();
            let rate = inside.iter().filter(|x| x.correct).count() as f64 / inside.len().max(1) as f64;
            (format!("{a:.0}-{b:.0}"), rate, inside.len())
        })
        .collect()
}
