//! `outlet demo --images`: the whole sidecar on photographs. Starts `serve
//! normal`, `pose` and `detector`, waits until each has beaten its heartbeat
//! (ready), then `serve files` in the simulated camera's place. There is no
//! truth to score a photograph against, so the demo prints what the sidecar
//! found in each file, in the list's order: its frame's holes from the
//! detector (pixels, [`service::DETECTIONS`]) with their hole poses from the
//! pose service (camera frame, [`service::HOLE_POSES`]), in the shape of
//! `outlet detect --json`; a file `serve files` skipped, with why; a frame the
//! detector skipped because a newer one was waiting. Without `--loop` the demo
//! ends once every file is accounted for.

use crate::demo::{Children, DemoArgs, demo_config, write_config};
use anyhow::{Context, Result, bail};
use outlet_client::{HolePoses, PoseStatus};
use outlet_protocol::shm;
use outlet_protocol::wire::{DetectionMsg, FileFrameMsg, HolePosesMsg, file_status, service};
use serde_json::{Value, json};
use std::collections::{BTreeMap, HashMap};
use std::ffi::OsString;
use std::io::Write;
use std::time::{Duration, Instant, SystemTime};

/// Frames per second when `--rate` is not given.
const DEFAULT_RATE_HZ: f64 = 10.0;
/// How often the demo looks for new messages.
const POLL: Duration = Duration::from_millis(10);
/// A frame with no detection this long after it went out has none.
const DETECTION_TIMEOUT: Duration = Duration::from_secs(10);
/// A detection with holes and no hole poses this long after it came has none
/// (the pose service logs why), beyond the pose service's own wait for a plane.
const POSE_TIMEOUT: Duration = Duration::from_secs(3);

/// One file of the list on its way through the sidecar.
struct Record {
    image: String,
    pass: u32,
    /// The frame it went out as; None when `serve files` skipped it.
    frame_id: Option<u64>,
    /// Why `serve files` skipped it.
    skipped: Option<String>,
    /// When the demo heard of it.
    seen: Instant,
}

/// What came back for the frames, by frame id, until their records are printed.
#[derive(Default)]
struct Results {
    detections: HashMap<u64, (DetectionMsg, Instant)>,
    poses: HashMap<u64, HolePoses>,
    /// The newest frame each has answered: an older frame without an answer by
    /// then gets none (both services take frames in order).
    last_detected: u64,
    last_posed: u64,
}

/// Counts for the summary.
#[derive(Default)]
struct Tally {
    files: u64,
    frames: u64,
    found: u64,
    posed: BTreeMap<&'static str, u64>,
    refused: BTreeMap<&'static str, u64>,
    skipped: u64,
    undetected: u64,
    latencies_ms: Vec<f64>,
}

pub fn demo(args: &DemoArgs) -> Result<()> {
    let mut config = demo_config(args)?;
    let template = args.template.clone().unwrap_or_else(|| "2x1".into());
    config.detector.template = template.clone();
    config.pose.template = template;
    let rate = args.sim.rate.unwrap_or(DEFAULT_RATE_HZ);
    if !(rate > 0.0 && rate.is_finite()) {
        bail!("--rate {rate}: not a positive number of frames per second");
    }
    let period_ms = 1e3 / rate;
    // Photographs are separate scenes: each is searched whole, as `outlet
    // detect` searches it (tracking would look where the last photo's outlet
    // was), and a pose takes the plane of its own photo's cloud (the same
    // capture stamp), waiting for it up to most of a period, never the plane
    // of the photo before.
    config.detector.tracking = false;
    config.pose.max_plane_age_ms = config.pose.max_plane_age_ms.min(0.5 * period_ms);
    if !args.points.is_empty() {
        config.pose.plane_wait_ms = config.pose.plane_wait_ms.max(0.8 * period_ms).min(10_000.0);
    }
    config.check().context("configuration")?;
    let (logs, config_path) = write_config(args, &config)?;

    // Subscribe before the services start, so that nothing is missed.
    let node = shm::node(&config.domain, "demo")?;
    let err = |what: &str, e: &dyn std::fmt::Debug| anyhow::anyhow!("{what} subscriber: {e:?}");
    let files = shm::messages::<FileFrameMsg>(&node, service::FILES)?
        .subscriber_builder()
        .create()
        .map_err(|e| err("file", &e))?;
    let detections = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?
        .subscriber_builder()
        .create()
        .map_err(|e| err("detection", &e))?;
    let poses = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?
        .subscriber_builder()
        .create()
        .map_err(|e| err("hole pose", &e))?;
    let beats = shm::heartbeats(&node)?.subscriber_builder().create().map_err(|e| err("heartbeat", &e))?;

    let mut children = Children(Vec::new());
    for name in ["normal", "pose", "detector"] {
        children.start(name, &config_path, &logs, &[])?;
    }
    eprintln!(
        "outlet demo: photographs {:?} at {rate} Hz, template {}; domain {} (try `outlet status --domain {}`); \
         logs in {}",
        args.images,
        config.detector.template,
        config.domain,
        config.domain,
        logs.display()
    );

    let started = Instant::now();
    // The files go out once the pipeline is ready: a service's first heartbeat
    // comes after it has set up its inputs (the detector its template).
    let mut waiting: Vec<&str> = vec!["normal", "pose", "detector"];
    let mut records: BTreeMap<(u32, u32), Record> = BTreeMap::new();
    let mut results = Results::default();
    let mut tally = Tally::default();
    let mut end = false;
    let mut stdout_failed = None;
    let outcome = loop {
        if args.duration.is_some_and(|d| started.elapsed().as_secs_f64() >= d) {
            if !waiting.is_empty() {
                break Err(anyhow::anyhow!(
                    "{waiting:?} not ready within --duration; see the logs in {}",
                    logs.display()
                ));
            }
            break Ok(());
        }
        // Ctrl-C or SIGTERM: iceoryx2's handler records it, the node reports it.
        if node.wait(POLL).is_err() {
            eprintln!("outlet demo: interrupted");
            break Ok(());
        }
        if !waiting.is_empty() {
            if let Some(why) = children.exited() {
                break Err(anyhow::anyhow!("{why}; see its log in {}", logs.display()));
            }
            while let Ok(Some(b)) = beats.receive() {
                let name = b.payload().service_name().to_string();
                waiting.retain(|w| *w != name);
            }
            if waiting.is_empty()
                && let Err(e) = children.start("files", &config_path, &logs, &files_args(args, rate))
            {
                break Err(e);
            }
            continue;
        }
        while let Ok(Some(m)) = files.receive() {
            let m = m.payload();
            match m.status {
                file_status::END => end = true,
                status => {
                    let record = Record {
                        image: m.image().to_string(),
                        pass: m.pass,
                        frame_id: (status == file_status::SENT).then_some(m.frame_id),
                        skipped: (status != file_status::SENT).then(|| m.reason().to_string()),
                        seen: Instant::now(),
                    };
                    records.insert((m.pass, m.index), record);
                }
            }
        }
        while let Ok(Some(d)) = detections.receive() {
            let d = *d.payload();
            results.last_detected = results.last_detected.max(d.frame_id);
            results.detections.insert(d.frame_id, (d, Instant::now()));
        }
        while let Ok(Some(p)) = poses.receive() {
            match HolePoses::from_msg(p.payload(), SystemTime::now()) {
                Ok(p) => {
                    results.last_posed = results.last_posed.max(p.frame_id);
                    results.poses.insert(p.frame_id, p);
                }
                Err(e) => tracing::warn!("hole poses refused: {e}"),
            }
        }
        // Print every record that is complete, in the list's order.
        while let Some(entry) = records.first_entry() {
            let Some(line) = finished(entry.get(), &mut results, &config.detector.template, &mut tally) else {
                break;
            };
            if let Some(frame_id) = entry.get().frame_id {
                // Frames go out in the list's order: what is left of this one and
                // older ones (a late pose) is never asked for again.
                results.detections.retain(|f, _| *f > frame_id);
                results.poses.retain(|f, _| *f > frame_id);
            }
            entry.remove();
            let text = if args.json { line.to_string() } else { human(&line) };
            if let Err(e) = writeln!(std::io::stdout().lock(), "{text}") {
                stdout_failed = Some(e);
                break;
            }
        }
        if let Some(e) = stdout_failed.take() {
            break Err(anyhow::anyhow!("writing the results: {e}"));
        }
        if end && records.is_empty() {
            break Ok(());
        }
        // After the records are out: a `files` that failed has said why in its log.
        if let Some(why) = children.exited() {
            break Err(anyhow::anyhow!("{why}; see its log in {}", logs.display()));
        }
    };
    children.stop();
    if args.domain.is_none() && args.config.is_none() {
        // The demo's own domain: nothing may stay behind in /dev/shm.
        shm::remove_node_counter(&config.domain);
    }
    tally.print(started.elapsed().as_secs_f64());
    outcome?;
    if tally.frames == 0 {
        bail!(
            "no photograph went through in {:.1} s; see the logs in {}",
            started.elapsed().as_secs_f64(),
            logs.display()
        );
    }
    Ok(())
}

/// `outlet serve files` arguments for the demo's.
fn files_args(args: &DemoArgs, rate: f64) -> Vec<OsString> {
    let mut out: Vec<OsString> = vec!["--images".into()];
    out.extend(args.images.iter().map(OsString::from));
    if let Some(camera) = &args.camera {
        out.extend(["--camera".into(), camera.as_os_str().to_owned()]);
    }
    if !args.points.is_empty() {
        out.push("--points".into());
        out.extend(args.points.iter().map(OsString::from));
    }
    out.extend(["--rate".into(), rate.to_string().into()]);
    if args.repeat {
        out.push("--loop".into());
    }
    out
}

fn kind_name(code: u32) -> &'static str {
    match code {
        1 => "power",
        2 => "ground",
        _ => "unknown",
    }
}

/// The record's line once everything that will come for it has come; None
/// while something may still come.
fn finished(record: &Record, results: &mut Results, template: &str, tally: &mut Tally) -> Option<Value> {
    let base = json!({"image": record.image, "pass": record.pass});
    let with = |mut v: Value, extra: Value| {
        if let (Some(v), Value::Object(extra)) = (v.as_object_mut(), extra) {
            v.extend(extra);
        }
        v
    };
    let Some(frame_id) = record.frame_id else {
        tally.files += 1;
        tally.skipped += 1;
        let reason = record.skipped.clone().unwrap_or_default();
        return Some(with(base, json!({"found": false, "error": format!("skipped by serve files: {reason}")})));
    };
    let base = with(base, json!({"frame_id": frame_id}));
    let Some((detection, detected)) = results.detections.get(&frame_id).copied() else {
        let why = if results.last_detected > frame_id {
            "the detector skipped this frame for a newer one (frames came faster than it detects them: lower --rate)"
        } else if record.seen.elapsed() > DETECTION_TIMEOUT {
            "no detection within 10 s (see the detector's log)"
        } else {
            return None;
        };
        tally.files += 1;
        tally.frames += 1;
        tally.undetected += 1;
        return Some(with(base, json!({"found": false, "error": why})));
    };
    let found = detection.hole_count > 0;
    let poses = results.poses.get(&frame_id);
    if found && poses.is_none() && results.last_posed <= frame_id && detected.elapsed() < POSE_TIMEOUT {
        return None;
    }
    let poses = results.poses.remove(&frame_id);
    results.detections.remove(&frame_id);
    tally.files += 1;
    tally.frames += 1;
    tally.found += u64::from(found);
    let usable =
        poses.as_ref().filter(|p| p.status == PoseStatus::Ok && p.holes.len() == detection.hole_count as usize);
    let holes: Vec<Value> = detection.holes[..(detection.hole_count as usize).min(detection.holes.len())]
        .iter()
        .enumerate()
        .map(|(k, h)| {
            let pose_hole = usable.map(|p| p.holes[k]);
            json!({
                "kind": kind_name(h.kind),
                "pixel": h.pixel,
                "position_m": pose_hole.map(|p| p.position_m),
                "covariance_m2": pose_hole.map(|p| p.covariance_m2),
                "outlier": pose_hole.map(|p| p.outlier),
                "score": h.score,
                "sigma_px": h.sigma_px,
                "refined": h.refined == 1,
            })
        })
        .collect();
    let pose =
        usable.map(|p| json!({"rotation": p.rotation, "translation_m": p.translation_m, "mode": p.mode.as_str()}));
    let latency_ms =
        poses.as_ref().and_then(|p| p.received.duration_since(p.capture_time).ok()).map(|d| d.as_secs_f64() * 1e3);
    match &poses {
        Some(p) if p.status == PoseStatus::Ok => *tally.posed.entry(p.mode.as_str()).or_default() += 1,
        Some(p) => *tally.refused.entry(p.status.as_str()).or_default() += 1,
        None if found => *tally.refused.entry("none").or_default() += 1,
        None => {}
    }
    tally.latencies_ms.extend(latency_ms);
    let mut line = with(
        base,
        json!({
            "found": found,
            "template": template,
            "holes": holes,
            "pose": pose,
            "pose_status": poses.as_ref().map(|p| p.status.as_str()),
            "timing_ms": {"detect": detection.detect_ms, "latency": latency_ms},
        }),
    );
    if found && poses.is_none() {
        line["pose_error"] = json!("the pose service gave no pose for this frame (see its log)");
    }
    Some(line)
}

/// A record as lines for a person: the file, what was found, each hole.
fn human(r: &Value) -> String {
    let image = r["image"].as_str().unwrap_or("?");
    let frame = r["frame_id"].as_u64().map_or(String::new(), |f| format!(" (frame {f})"));
    if let Some(e) = r["error"].as_str() {
        return format!("{image}{frame}: {e}");
    }
    let detect_ms = r["timing_ms"]["detect"].as_f64().unwrap_or(f64::NAN);
    let holes = r["holes"].as_array().map_or(&[][..], Vec::as_slice);
    if holes.is_empty() {
        return format!("{image}{frame}: no outlet (detection {detect_ms:.1} ms)");
    }
    let pose = match (r["pose"]["mode"].as_str(), r["pose_status"].as_str()) {
        (Some(mode), _) => format!("pose {mode}"),
        (None, Some(status)) => format!("no pose: {status}"),
        (None, None) => "no pose".into(),
    };
    let latency = r["timing_ms"]["latency"].as_f64().map_or(String::new(), |l| format!(", latency {l:.1} ms"));
    let mut out = format!(
        "{image}{frame}: outlet {}, {} holes, {pose} (detection {detect_ms:.1} ms{latency})",
        r["template"].as_str().unwrap_or("?"),
        holes.len()
    );
    for h in holes {
        let px = |k: usize| h["pixel"][k].as_f64().unwrap_or(f64::NAN);
        let position = match h["position_m"].as_array() {
            Some(p) => {
                let mm = |k: usize| p.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN) * 1e3;
                let sigma_z = h["covariance_m2"][2][2].as_f64().map_or(f64::NAN, |v| v.max(0.0).sqrt() * 1e3);
                format!("  ({:>8.2}, {:>8.2}, {:>8.2}) mm  ± {sigma_z:.2} mm", mm(0), mm(1), mm(2))
            }
            None => String::new(),
        };
        out +=
            &format!("\n    {:<6} pixel ({:>8.2}, {:>8.2}){position}", h["kind"].as_str().unwrap_or("?"), px(0), px(1));
    }
    out
}

impl Tally {
    fn print(&mut self, seconds: f64) {
        let list = |m: &BTreeMap<&str, u64>| {
            if m.is_empty() {
                "none".to_string()
            } else {
                m.iter().map(|(k, v)| format!("{v} {k}")).collect::<Vec<_>>().join(", ")
            }
        };
        self.latencies_ms.sort_by(f64::total_cmp);
        let q = |p: f64| match self.latencies_ms.len() {
            0 => f64::NAN,
            n => self.latencies_ms[((n as f64 * p).ceil() as usize).clamp(1, n) - 1],
        };
        eprintln!(
            "outlet demo: {seconds:.1} s, {} files: {} frames, {} with an outlet; poses: {}; without a pose: {}; \
             {} skipped (bad files), {} not detected (frames faster than the detector); latency p50 {:.1} ms, \
             p99 {:.1} ms",
            self.files,
            self.frames,
            self.found,
            list(&self.posed),
            list(&self.refused),
            self.skipped,
            self.undetected,
            q(0.5),
            q(0.99)
        );
    }
}
