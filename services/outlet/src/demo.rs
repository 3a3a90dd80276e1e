//! `outlet demo`: the whole sidecar on the simulated camera. Starts `serve
//! sim-camera`, `detector`, `normal` and `pose` as child processes, follows the
//! hole poses through the client library, and prints each result beside the
//! ground truth. Ctrl-C (or `--duration`) stops the children cleanly. With
//! `--images`, photographs take the simulated camera's place
//! ([`crate::demo_photos`]).

use crate::serve::SimCameraArgs;
use anyhow::{Context, Result, bail};
use clap::Args;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use outlet::config::Config;
use outlet_client::{Client, HolePoses, PoseStatus};
use outlet_protocol::shm;
use outlet_protocol::wire::{DetectionMsg, TruthMsg, service};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// A TOML configuration file; the flags below override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The shared-memory domain (default: the file's, else `demo-<pid>`, apart from any running sidecar).
    #[arg(long)]
    pub domain: Option<String>,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long)]
    pub duration: Option<f64>,
    /// One JSON line per result on stdout (a summary goes to stderr).
    #[arg(long)]
    pub json: bool,
    /// The detector's template (default: the scenario's outlet, `2x1` or `2x2`).
    #[arg(long)]
    pub template: Option<String>,
    /// Search every frame whole (`detector.tracking = false`).
    #[arg(long)]
    pub no_tracking: bool,
    /// Serve the live view on this port (Foxglove: connect to ws://localhost:PORT);
    /// `--view` alone takes Foxglove's 8765.
    #[arg(long, num_args = 0..=1, default_missing_value = "8765")]
    pub view: Option<u16>,
    /// Where the services' logs go (default: a folder in the temp dir).
    #[arg(long)]
    pub logs: Option<PathBuf>,
    /// Soak run: write each period's memory, counters and latency percentiles
    /// to this file as JSON lines, and a summary line at the end.
    #[arg(long)]
    pub soak_report: Option<PathBuf>,
    /// Length of a soak report's period (s).
    #[arg(long, default_value_t = 60.0)]
    pub soak_period_s: f64,
    #[command(flatten)]
    pub sim: SimCameraArgs,
    /// Photographs instead of the simulated camera (`outlet serve files`): glob patterns
    /// (quoted: 'DIR/*.png'), files or folders of PNG and JPEG. Each frame's holes, pixel
    /// and 3D, are printed (there is no truth to score them against); photos are searched
    /// whole, as `outlet detect` does, and each pose uses its own photo's cloud only.
    /// `--rate` sets the frames per second (default 10); the demo ends after the last file.
    #[arg(long, num_args = 1.., conflicts_with_all = ["scenario", "seed", "width", "height", "views",
        "frames_per_scene", "no_cloud", "soak_report"])]
    pub images: Vec<String>,
    /// With --images: the camera_info YAML of every photo (default: each one's
    /// NAME.camera.yaml, else camera.yaml beside it).
    #[arg(long, requires = "images")]
    pub camera: Option<PathBuf>,
    /// With --images: stereo clouds (PLY), matched to the photos by file stem.
    #[arg(long, num_args = 1.., requires = "images")]
    pub points: Vec<String>,
    /// With --images: go through the photos again and again, until --duration or Ctrl-C.
    #[arg(long = "loop", requires = "images")]
    pub repeat: bool,
}

/// How long a result waits for its frame's truth, sent by the camera just after the frame.
const TRUTH_WAIT: Duration = Duration::from_millis(500);

/// A hole further than this from the truth makes its result a false alarm (mm).
const FALSE_ALARM_MM: f64 = 3.0;
/// ... and so does one further than this many of its own standard deviations
/// (`sqrt(e^T C^-1 e)`): an error bar that does not hold is a false alarm too.
const FALSE_ALARM_SIGMAS: f64 = 5.0;

/// One result as `--json` prints it.
#[derive(Debug, Serialize)]
struct ResultLine {
    frame_id: u64,
    mode: &'static str,
    /// `ok`, or why there is no pose (`ambiguous`, `plane_mismatch`).
    status: &'static str,
    capture_time_ns: u64,
    /// Capture to receipt by this client (ms).
    latency_ms: f64,
    /// Capture to publication by the pose service (ms).
    published_ms: f64,
    /// The detector's share of it (ms), when its detection was seen.
    detect_ms: Option<f64>,
    holes: Vec<HoleLine>,
    /// Largest hole error against the simulated truth (mm); None without truth.
    max_error_mm: Option<f64>,
    /// Largest hole error in its own standard deviations, `sqrt(e^T C^-1 e)`.
    max_error_sigmas: Option<f64>,
    /// A pose an arm would act on wrongly: the frame holds no outlet (or the
    /// result another number of holes), or a hole is more than 3 mm or 5 sigma
    /// from the truth. Results without a pose are never false alarms.
    false_alarm: bool,
    /// Why it is one: `no_outlet`, `beyond_3mm`, `beyond_5sigma`.
    false_alarm_reason: Option<&'static str>,
}

#[derive(Debug, Serialize)]
struct HoleLine {
    kind: &'static str,
    position_m: [f64; 3],
    sigma_mm: [f64; 3],
    error_mm: Option<f64>,
    /// The error along the true outlet's normal and across it, in its face plane
    /// (mm), with the standard deviations the covariance gives those directions:
    /// a controller approaches along the normal and inserts across it.
    error_normal_mm: Option<f64>,
    error_in_plane_mm: Option<f64>,
    sigma_normal_mm: Option<f64>,
    /// `sqrt(e^T C^-1 e)`: the error in the hole's own standard deviations.
    error_sigmas: Option<f64>,
    /// Its pixel was not used (the pose service found it inconsistent).
    outlier: bool,
}

/// The child processes; stopped with SIGTERM (then SIGKILL) however the demo ends.
pub(crate) struct Children(pub(crate) Vec<(&'static str, Child)>);

impl Children {
    /// Starts `outlet serve --config CONFIG NAME ARGS`, its log in `logs/NAME.log`.
    pub(crate) fn start(
        &mut self,
        name: &'static str,
        config_path: &Path,
        logs: &Path,
        args: &[std::ffi::OsString],
    ) -> Result<()> {
        let exe = std::env::current_exe().context("locating the outlet executable")?;
        let log = std::fs::File::create(logs.join(format!("{name}.log")))
            .with_context(|| format!("creating the log of {name}"))?;
        let child = Command::new(&exe)
            .arg("serve")
            .arg("--config")
            .arg(config_path)
            .arg(name)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting {name}"))?;
        self.0.push((name, child));
        Ok(())
    }

    pub(crate) fn stop(&mut self) {
        for (_, c) in &self.0 {
            if let Ok(pid) = i32::try_from(c.id()) {
                let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(3);
        for (name, c) in &mut self.0 {
            loop {
                match c.try_wait() {
                    Ok(Some(_)) | Err(_) => break,
                    Ok(None) if Instant::now() > deadline => {
                        tracing::warn!("{name} did not stop on SIGTERM: killed");
                        let _ = c.kill();
                        let _ = c.wait();
                        break;
                    }
                    Ok(None) => std::thread::sleep(Duration::from_millis(20)),
                }
            }
        }
        self.0.clear();
    }

    /// The first child that has exited, with its status.
    pub(crate) fn exited(&mut self) -> Option<String> {
        self.0.iter_mut().find_map(|(name, c)| match c.try_wait() {
            Ok(Some(status)) => Some(format!("{name} exited ({status})")),
            _ => None,
        })
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        self.stop();
    }
}

fn ns(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// The demo's configuration: the file's, in the demo's own domain unless told otherwise.
pub(crate) fn demo_config(args: &DemoArgs) -> Result<Config> {
    let mut config = Config::load(args.config.as_deref())?;
    // Apart from any running sidecar unless told otherwise.
    if let Some(d) = &args.domain {
        config.domain = d.clone();
    } else if args.config.is_none() {
        config.domain = format!("demo-{}", std::process::id());
    }
    if let Some(d) = args.duration
        && !(d > 0.0 && d.is_finite())
    {
        bail!("--duration {d}: not a positive number of seconds");
    }
    Ok(config)
}

/// Writes the configuration the services read into the demo's log folder: the folder and the file.
pub(crate) fn write_config(args: &DemoArgs, config: &Config) -> Result<(PathBuf, PathBuf)> {
    let logs = args.logs.clone().unwrap_or_else(|| std::env::temp_dir().join(format!("outlet-{}", config.domain)));
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    let config_path = logs.join("config.toml");
    std::fs::write(&config_path, config.to_toml()?).with_context(|| format!("writing {}", config_path.display()))?;
    Ok((logs, config_path))
}

pub fn demo(args: DemoArgs) -> Result<()> {
    if !args.images.is_empty() {
        return crate::demo_photos::demo(&args);
    }
    let mut config = demo_config(&args)?;
    args.sim.apply(&mut config);
    let template = args
        .template
        .clone()
        .unwrap_or_else(|| if config.sim_camera.scenario.contains("2x2") { "2x2" } else { "2x1" }.to_string());
    config.detector.template = template.clone();
    if args.no_tracking {
        config.detector.tracking = false;
    }
    config.pose.template = template;
    config.check().context("configuration")?;
    let (logs, config_path) = write_config(&args, &config)?;

    // Subscribe before the services start, so that no result is missed.
    let node = shm::node(&config.domain, "demo")?;
    let mut client = Client::connect(&config.domain).context("connecting the client")?;
    let truth = shm::messages::<TruthMsg>(&node, service::TRUTH)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("truth subscriber: {e:?}"))?;
    let detections = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("detection subscriber: {e:?}"))?;

    let mut children = Children(Vec::new());
    for name in ["normal", "pose", "detector", "sim-camera"] {
        children.start(name, &config_path, &logs, &[])?;
    }
    if let Some(port) = args.view {
        let view_args = ["--port".into(), port.to_string().into()];
        children.start("viewer", &config_path, &logs, &view_args)?;
        eprintln!("outlet demo: live view on ws://localhost:{port} (open Foxglove, Open connection)");
    }
    let sim = &config.sim_camera;
    eprintln!(
        "outlet demo: {} at {} Hz, {}x{}, template {}; domain {} (try `outlet status --domain {}`); logs in {}",
        sim.scenario,
        sim.rate_hz,
        sim.width,
        sim.height,
        config.detector.template,
        config.domain,
        config.domain,
        logs.display()
    );

    if !(args.soak_period_s >= 1.0 && args.soak_period_s.is_finite()) {
        bail!("--soak-period-s {}: at least 1 s", args.soak_period_s);
    }
    let mut soak = match &args.soak_report {
        Some(path) => {
            Some(crate::soak::SoakReport::create(path).with_context(|| format!("creating {}", path.display()))?)
        }
        None => None,
    };
    let pids: Vec<(&str, u32)> = children.0.iter().map(|(name, c)| (*name, c.id())).collect();
    let mut next_period = Duration::from_secs_f64(args.soak_period_s);

    let started = Instant::now();
    let mut truths: BTreeMap<u64, TruthMsg> = BTreeMap::new();
    let mut detect_ms: BTreeMap<u64, f64> = BTreeMap::new();
    let mut summary = Summary::default();
    let mut last_result = Instant::now();
    let outcome = loop {
        if args.duration.is_some_and(|d| started.elapsed().as_secs_f64() >= d) {
            break Ok(());
        }
        // Ctrl-C or SIGTERM: iceoryx2's handler records it, the node reports it.
        if node.wait(Duration::ZERO).is_err() {
            eprintln!("outlet demo: interrupted");
            break Ok(());
        }
        if let Some(why) = children.exited() {
            break Err(anyhow::anyhow!("{why}; see its log in {}", logs.display()));
        }
        if let Some(report) = &mut soak
            && started.elapsed() >= next_period
        {
            let beats = client.heartbeats().unwrap_or_default();
            if let Err(e) = report.period(started.elapsed().as_secs_f64(), &beats, &pids) {
                tracing::warn!("soak report: {e}");
            }
            next_period += Duration::from_secs_f64(args.soak_period_s);
        }
        let next = client.wait_next(Duration::from_millis(100));
        let mut drain_truths = |truths: &mut BTreeMap<u64, TruthMsg>| {
            while let Ok(Some(t)) = truth.receive() {
                let t = *t.payload();
                if let Some(report) = &mut soak {
                    report.frame();
                }
                if t.hole_count > 0 {
                    summary.frames_with_outlet += 1;
                }
                summary.frames += 1;
                truths.insert(t.frame_id, t);
            }
        };
        drain_truths(&mut truths);
        // The camera sends a frame's truth just after the frame: on a busy machine
        // the result can come first. Wait for it briefly rather than score the
        // result against no truth.
        if let Ok(Some(p)) = &next {
            let waited = Instant::now();
            while truths.last_key_value().is_none_or(|(&id, _)| id < p.frame_id) && waited.elapsed() < TRUTH_WAIT {
                std::thread::sleep(Duration::from_millis(2));
                drain_truths(&mut truths);
            }
        }
        while let Ok(Some(d)) = detections.receive() {
            detect_ms.insert(d.payload().frame_id, d.payload().detect_ms);
        }
        // Results come within a few frames of their truth: keep a short window.
        while truths.len() > 256 {
            truths.pop_first();
        }
        while detect_ms.len() > 256 {
            detect_ms.pop_first();
        }
        let poses = match next {
            Ok(Some(p)) => p,
            Ok(None) => {
                if last_result.elapsed() > Duration::from_secs(2) && !args.json {
                    eprintln!(
                        "no result for {:.1} s (the detector trains its template at start; frames without an outlet give none)",
                        last_result.elapsed().as_secs_f64()
                    );
                    last_result = Instant::now();
                }
                continue;
            }
            Err(e) => {
                tracing::warn!("client: {e}");
                continue;
            }
        };
        last_result = Instant::now();
        let line = result_line(&poses, truths.get(&poses.frame_id), detect_ms.get(&poses.frame_id).copied());
        summary.add(&line);
        if let Some(report) = &mut soak {
            report.result(line.latency_ms);
        }
        let written = if args.json {
            match serde_json::to_string(&line) {
                Ok(s) => writeln!(std::io::stdout().lock(), "{s}"),
                Err(e) => {
                    tracing::warn!("result line: {e}");
                    Ok(())
                }
            }
        } else {
            print_result(&mut std::io::stdout().lock(), &line)
        };
        // A reader that went away (`outlet demo | head`) ends the demo cleanly.
        match written {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                eprintln!("outlet demo: stdout closed, stopping");
                break Ok(());
            }
            Err(e) => break Err(anyhow::anyhow!("writing a result to stdout: {e}")),
        }
    };
    if let Some(report) = &mut soak {
        let crashed = outcome.as_ref().err().map(|e| format!("{e:#}"));
        match report.finish(started.elapsed().as_secs_f64(), crashed) {
            Ok(s) => eprintln!("outlet demo: soak summary {}", serde_json::to_string(&s).unwrap_or_default()),
            Err(e) => tracing::warn!("soak report: {e}"),
        }
    }
    children.stop();
    if args.domain.is_none() && args.config.is_none() {
        // The demo's own domain: nothing may stay behind in /dev/shm.
        shm::remove_node_counter(&config.domain);
    }
    summary.print(started.elapsed().as_secs_f64());
    outcome?;
    if summary.results == 0 {
        bail!(
            "no hole poses in {:.1} s; see the services' logs in {}",
            started.elapsed().as_secs_f64(),
            logs.display()
        );
    }
    Ok(())
}

fn result_line(poses: &HolePoses, truth: Option<&TruthMsg>, detect_ms: Option<f64>) -> ResultLine {
    let truth_holes = truth.filter(|t| t.hole_count as usize == poses.holes.len());
    let holes: Vec<HoleLine> = poses
        .holes
        .iter()
        .enumerate()
        .map(|(k, h)| {
            let error =
                truth_holes.map(|t| nalgebra::Vector3::from(h.position_m) - nalgebra::Vector3::from(t.positions_m[k]));
            let covariance = nalgebra::Matrix3::from_fn(|r, c| h.covariance_m2[r][c]);
            let error_sigmas =
                error.map(|e| covariance.cholesky().map_or(f64::INFINITY, |l| e.dot(&l.solve(&e)).max(0.0).sqrt()));
            // The outlet's normal: the third column of its rotation (row-major).
            let normal = truth_holes.map(|t| nalgebra::Vector3::new(t.rotation[2], t.rotation[5], t.rotation[8]));
            let along = error.zip(normal).map(|(e, n)| e.dot(&n));
            let across = error.zip(along).map(|(e, a)| (e.norm_squared() - a * a).max(0.0).sqrt());
            HoleLine {
                kind: match h.kind {
                    outlet_protocol::HoleKind::Power => "power",
                    outlet_protocol::HoleKind::Ground => "ground",
                },
                position_m: h.position_m,
                sigma_mm: h.std_dev_m().map(|s| s * 1e3),
                error_mm: error.map(|e| e.norm() * 1e3),
                error_normal_mm: along.map(|a| a * 1e3),
                error_in_plane_mm: across.map(|a| a * 1e3),
                sigma_normal_mm: normal.map(|n| n.dot(&(covariance * n)).max(0.0).sqrt() * 1e3),
                error_sigmas,
                outlier: h.outlier,
            }
        })
        .collect();
    let max_error_mm = truth_holes.map(|_| holes.iter().filter_map(|h| h.error_mm).fold(0.0, f64::max));
    let max_error_sigmas = truth_holes.map(|_| holes.iter().filter_map(|h| h.error_sigmas).fold(0.0, f64::max));
    let usable = poses.status == PoseStatus::Ok;
    let false_alarm_reason = match truth {
        _ if !usable => None,
        Some(t) if t.hole_count as usize != poses.holes.len() => Some("no_outlet"),
        _ if max_error_mm.is_some_and(|e| e > FALSE_ALARM_MM) => Some("beyond_3mm"),
        _ if max_error_sigmas.is_some_and(|e| e > FALSE_ALARM_SIGMAS) => Some("beyond_5sigma"),
        _ => None,
    };
    ResultLine {
        frame_id: poses.frame_id,
        mode: poses.mode.as_str(),
        status: poses.status.as_str(),
        capture_time_ns: ns(poses.capture_time),
        latency_ms: poses.received.duration_since(poses.capture_time).map_or(0.0, |d| d.as_secs_f64() * 1e3),
        published_ms: poses.latency().as_secs_f64() * 1e3,
        detect_ms,
        holes,
        max_error_mm,
        max_error_sigmas,
        false_alarm: false_alarm_reason.is_some(),
        false_alarm_reason,
    }
}

fn print_result(out: &mut impl Write, r: &ResultLine) -> std::io::Result<()> {
    let error = match (r.status, r.max_error_mm) {
        ("ok", Some(e)) => format!("max error {e:.3} mm ({:.1} sigma)", r.max_error_sigmas.unwrap_or(f64::NAN)),
        ("ok", None) => "no truth".into(),
        (status, _) => format!("no pose: {status}"),
    };
    let detect = r.detect_ms.map_or(String::new(), |d| format!(" (detection {d:.1} ms)"));
    let alarm = match r.false_alarm_reason {
        Some("no_outlet") => "  FALSE ALARM: no outlet in this frame",
        Some("beyond_3mm") => "  FALSE ALARM: a hole more than 3 mm off",
        Some(_) => "  FALSE ALARM: a hole more than 5 sigma off",
        None => "",
    };
    writeln!(
        out,
        "frame {:>6}  {:<5}  {} holes  {}  latency {:.1} ms{}{}",
        r.frame_id,
        r.mode,
        r.holes.len(),
        error,
        r.latency_ms,
        detect,
        alarm
    )?;
    for h in &r.holes {
        let [x, y, z] = h.position_m.map(|v| v * 1e3);
        let err = h.error_mm.map_or(String::new(), |e| format!("  error {e:.3}"));
        writeln!(out, "    {:<6} ({x:>8.2}, {y:>8.2}, {z:>8.2}) mm  ± {:.2} mm{err}", h.kind, h.sigma_mm[2])?;
    }
    Ok(())
}

/// The mean of `nees` over 3 (1 where the covariances are honest) and the share
/// beyond the chi-square 99.9% point (0.001 where they are); NaN and 0 without values.
fn nees_summary(nees: &[f64]) -> (f64, f64) {
    if nees.is_empty() {
        return (f64::NAN, 0.0);
    }
    (crate::nees::mean_over_dof(nees), crate::nees::beyond_999(nees))
}

#[derive(Debug, Default)]
struct Summary {
    frames: u64,
    frames_with_outlet: u64,
    results: u64,
    false_alarms: u64,
    ambiguous: u64,
    plane_mismatch: u64,
    errors_mm: Vec<f64>,
    /// Each hole's `e^T C^-1 e` (3 degrees of freedom): whether the error bars hold.
    nees: Vec<f64>,
    latencies_ms: Vec<f64>,
    latency_over_detection_ms: Vec<f64>,
}

impl Summary {
    fn add(&mut self, r: &ResultLine) {
        // Percentiles over the first 100 000 values: a soak of hours keeps a fixed size.
        const KEEP: usize = 100_000;
        self.results += 1;
        self.false_alarms += r.false_alarm as u64;
        self.ambiguous += (r.status == "ambiguous") as u64;
        self.plane_mismatch += (r.status == "plane_mismatch") as u64;
        if self.errors_mm.len() < KEEP {
            self.errors_mm.extend(r.holes.iter().filter_map(|h| h.error_mm));
            self.nees.extend(r.holes.iter().filter_map(|h| h.error_sigmas).map(|s| s * s));
        }
        if self.latencies_ms.len() < KEEP {
            self.latencies_ms.push(r.latency_ms);
            if let Some(d) = r.detect_ms {
                self.latency_over_detection_ms.push(r.latency_ms - d);
            }
        }
    }

    fn print(&mut self, seconds: f64) {
        let q = |v: &mut Vec<f64>, p: f64| {
            v.sort_by(f64::total_cmp);
            if v.is_empty() {
                return f64::NAN;
            }
            v[((v.len() as f64 * p).ceil() as usize).clamp(1, v.len()) - 1]
        };
        let rms = (self.errors_mm.iter().map(|e| e * e).sum::<f64>() / self.errors_mm.len().max(1) as f64).sqrt();
        let (nees_mean, nees_beyond) = nees_summary(&self.nees);
        eprintln!(
            "outlet demo: {:.1} s, {} frames ({} with an outlet), {} results, {} false alarms \
             (a hole beyond 3 mm or 5 sigma, or no outlet), {} without a pose ({} ambiguous, {} plane mismatch); \
             hole error RMS {:.3} mm, p95 {:.3} mm; error bars: mean e^T C^-1 e {:.2} x 3, {:.2}% of holes beyond \
             the chi-square 99.9% point (honest: 1 x 3, 0.1%); latency p50 {:.1} ms, p99 {:.1} ms; \
             latency beyond detection p50 {:.2} ms, p99 {:.2} ms",
            seconds,
            self.frames,
            self.frames_with_outlet,
            self.results,
            self.false_alarms,
            self.ambiguous + self.plane_mismatch,
            self.ambiguous,
            self.plane_mismatch,
            rms,
            q(&mut self.errors_mm, 0.95),
            nees_mean,
            nees_beyond * 100.0,
            q(&mut self.latencies_ms, 0.5),
            q(&mut self.latencies_ms, 0.99),
            q(&mut self.latency_over_detection_ms, 0.5),
            q(&mut self.latency_over_detection_ms, 0.99),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_error_bars_summary_is_the_mean_over_three_and_the_share_beyond_the_999_point() {
        let (mean, beyond) = nees_summary(&[3.0, 3.0, 3.0, 30.0]);
        assert!((mean - 39.0 / 4.0 / 3.0).abs() < 1e-12);
        assert!((beyond - 0.25).abs() < 1e-12);
        let (mean, beyond) = nees_summary(&[]);
        assert!(mean.is_nan() && beyond == 0.0);
    }
}
