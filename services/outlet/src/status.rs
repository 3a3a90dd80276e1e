//! `outlet status`: a live view of a running sidecar, like `ros2 topic hz` for
//! its channels: each channel's rate and age (capture to now), and each
//! service's heartbeat (counters, rates, latencies, the last rejection).

use anyhow::Result;
use clap::Args;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use outlet::config::Config;
use outlet::health::now_ns;
use outlet_protocol::shm;
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, FrameHeader, HeartbeatMsg, HolePosesMsg, WallPlaneMsg, service,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Args, Debug)]
pub struct StatusArgs {
    /// The configuration file of the sidecar (for its domain).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The shared-memory domain.
    #[arg(long)]
    pub domain: Option<String>,
    /// Refresh period (ms).
    #[arg(long, default_value_t = 1000)]
    pub interval_ms: u64,
    /// Print one report after one period and exit.
    #[arg(long)]
    pub once: bool,
    /// One JSON object per report instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Also print each service's configuration as TOML.
    #[arg(long)]
    pub show_config: bool,
}

/// A channel's traffic over one period.
#[derive(Debug, Default, Serialize)]
struct ChannelStats {
    name: &'static str,
    messages: u64,
    rate_hz: f64,
    /// Capture to receipt of the newest message (ms), when it carries a capture stamp.
    age_ms: Option<f64>,
}

#[derive(Debug, Serialize)]
struct ServiceStatus {
    service: String,
    pid: u32,
    alive: bool,
    silent_ms: f64,
    inputs: u64,
    outputs: u64,
    rejected: u64,
    dropped: u64,
    input_rate_hz: f64,
    output_rate_hz: f64,
    latency_p50_ms: Option<f64>,
    latency_p99_ms: Option<f64>,
    work_p50_ms: Option<f64>,
    work_p99_ms: Option<f64>,
    last_rejection: String,
}

#[derive(Debug, Serialize)]
struct Report {
    domain: String,
    channels: Vec<ChannelStats>,
    services: Vec<ServiceStatus>,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// Counts what arrives on one channel, and the capture stamp of the newest.
trait Tap {
    fn drain(&self) -> (u64, Option<u64>);
}

impl<P, H> Tap for Subscriber<ipc::Service, [P], H>
where
    P: std::fmt::Debug + ZeroCopySend + 'static,
    H: Stamped + std::fmt::Debug + ZeroCopySend + 'static,
{
    fn drain(&self) -> (u64, Option<u64>) {
        let (mut n, mut stamp) = (0, None);
        while let Ok(Some(s)) = self.receive() {
            n += 1;
            stamp = Some(s.user_header().capture_time_ns());
        }
        (n, stamp)
    }
}

/// Messages and headers with a capture stamp.
trait Stamped {
    fn capture_time_ns(&self) -> u64;
}

macro_rules! stamped {
    ($($t:ty),*) => {$(
        impl Stamped for $t {
            fn capture_time_ns(&self) -> u64 {
                self.capture_time_ns
            }
        }
    )*};
}
stamped!(FrameHeader, CloudHeader, WallPlaneMsg, DetectionMsg, HolePosesMsg);

impl<T: Stamped + std::fmt::Debug + ZeroCopySend + 'static> Tap for Subscriber<ipc::Service, T, ()> {
    fn drain(&self) -> (u64, Option<u64>) {
        let (mut n, mut stamp) = (0, None);
        while let Ok(Some(s)) = self.receive() {
            n += 1;
            stamp = Some(s.payload().capture_time_ns());
        }
        (n, stamp)
    }
}

pub fn status(args: StatusArgs) -> Result<()> {
    let mut config = Config::load(args.config.as_deref())?;
    if let Some(d) = args.domain {
        config.domain = d;
    }
    config.check()?;
    let node = shm::node(&config.domain, "status")?;
    let sub_err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("subscriber: {e:?}");
    let taps: Vec<(&'static str, Box<dyn Tap>)> = vec![
        (service::FRAMES, Box::new(shm::frames(&node)?.subscriber_builder().create().map_err(|e| sub_err(&e))?)),
        (service::CLOUDS, Box::new(shm::clouds(&node)?.subscriber_builder().create().map_err(|e| sub_err(&e))?)),
        (
            service::PLANES,
            Box::new(
                shm::messages::<WallPlaneMsg>(&node, service::PLANES)?
                    .subscriber_builder()
                    .create()
                    .map_err(|e| sub_err(&e))?,
            ),
        ),
        (
            service::DETECTIONS,
            Box::new(
                shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?
                    .subscriber_builder()
                    .create()
                    .map_err(|e| sub_err(&e))?,
            ),
        ),
        (
            service::HOLE_POSES,
            Box::new(
                shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?
                    .subscriber_builder()
                    .create()
                    .map_err(|e| sub_err(&e))?,
            ),
        ),
    ];
    // Frames and clouds keep two samples per reader: drain on every notification.
    let listeners = taps
        .iter()
        .map(|(name, _)| {
            shm::events(&node, name)?.listener_builder().create().map_err(|e| anyhow::anyhow!("listener: {e:?}"))
        })
        .collect::<Result<Vec<_>>>()?;
    let heartbeats = shm::heartbeats(&node)?.subscriber_builder().create().map_err(|e| sub_err(&e))?;
    let snapshots = shm::snapshots(&node)?.subscriber_builder().create().map_err(|e| sub_err(&e))?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    let guards = listeners
        .iter()
        .map(|l| waitset.attach_notification(l).map_err(|e| anyhow::anyhow!("attach: {e:?}")))
        .collect::<Result<Vec<_>>>()?;
    let interval = Duration::from_millis(args.interval_ms.max(100));
    let report_tick = waitset.attach_interval(interval).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;

    let mut counts = vec![(0u64, None::<u64>); taps.len()];
    let mut beats: BTreeMap<String, HeartbeatMsg> = BTreeMap::new();
    let mut configs: BTreeMap<String, Config> = BTreeMap::new();
    let mut period_start = Instant::now();
    let mut done = false;
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        for (k, guard) in guards.iter().enumerate() {
            if id.has_event_from(guard) {
                let _ = listeners[k].try_wait(|_| {});
                let (n, stamp) = taps[k].1.drain();
                counts[k].0 += n;
                if stamp.is_some() {
                    counts[k].1 = stamp;
                }
            }
        }
        if !id.has_event_from(&report_tick) {
            return CallbackProgression::Continue;
        }
        for (k, (_, tap)) in taps.iter().enumerate() {
            let (n, stamp) = tap.drain();
            counts[k].0 += n;
            if stamp.is_some() {
                counts[k].1 = stamp;
            }
        }
        while let Ok(Some(b)) = heartbeats.receive() {
            beats.insert(b.payload().service_name().to_string(), *b.payload());
        }
        while let Ok(Some(s)) = snapshots.receive() {
            match postcard::from_bytes::<(String, Config)>(s.payload()) {
                Ok((name, c)) => {
                    configs.insert(name, c);
                }
                Err(e) => tracing::warn!("a configuration snapshot does not decode: {e}"),
            }
        }
        let seconds = period_start.elapsed().as_secs_f64();
        let now = now_ns();
        let channels = taps
            .iter()
            .zip(&counts)
            .map(|((name, _), &(n, stamp))| ChannelStats {
                name,
                messages: n,
                rate_hz: n as f64 / seconds,
                age_ms: stamp.filter(|&s| s > 0 && s <= now).map(|s| (now - s) as f64 / 1e6),
            })
            .collect();
        let services = beats
            .values()
            .map(|b| {
                let silent_ms = now.saturating_sub(b.published_ns) as f64 / 1e6;
                ServiceStatus {
                    service: b.service_name().to_string(),
                    pid: b.pid,
                    // Three missed beats and the service counts as gone.
                    alive: silent_ms < 3.0 * config.heartbeat_ms as f64 + 500.0,
                    silent_ms,
                    inputs: b.inputs,
                    outputs: b.outputs,
                    rejected: b.rejected,
                    dropped: b.dropped,
                    input_rate_hz: b.input_rate_hz,
                    output_rate_hz: b.output_rate_hz,
                    latency_p50_ms: finite(b.latency_p50_ms),
                    latency_p99_ms: finite(b.latency_p99_ms),
                    work_p50_ms: finite(b.work_p50_ms),
                    work_p99_ms: finite(b.work_p99_ms),
                    last_rejection: b.last_rejection().to_string(),
                }
            })
            .collect();
        let report = Report { domain: config.domain.clone(), channels, services };
        let text = if args.json {
            match serde_json::to_string(&report) {
                Ok(line) => line + "\n",
                Err(e) => {
                    tracing::warn!("report: {e}");
                    String::new()
                }
            }
        } else {
            let mut text = tables(&report);
            if args.show_config {
                for (name, c) in &configs {
                    text += &format!("# {name}\n{}\n", c.to_toml().unwrap_or_else(|e| format!("({e})")));
                }
            }
            text
        };
        // A reader that went away (`outlet status | head`) ends the command, not a panic.
        if let Err(e) = std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes()) {
            if e.kind() != std::io::ErrorKind::BrokenPipe {
                tracing::warn!("writing the report: {e}");
            }
            return CallbackProgression::Stop;
        }
        counts.iter_mut().for_each(|c| c.0 = 0);
        period_start = Instant::now();
        if args.once {
            done = true;
            CallbackProgression::Stop
        } else {
            CallbackProgression::Continue
        }
    };
    crate::serve::run_until_stopped(&waitset, on_event)?;
    let _ = done;
    Ok(())
}

fn ms(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.1}"))
}

fn tables(r: &Report) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(out, "domain {}", r.domain);
    let _ = writeln!(out, "{:<28} {:>8} {:>10}", "channel", "rate Hz", "age ms");
    for c in &r.channels {
        let _ = writeln!(out, "{:<28} {:>8.1} {:>10}", c.name, c.rate_hz, ms(c.age_ms));
    }
    let _ = writeln!(
        out,
        "{:<11} {:>7} {:>5} {:>8} {:>8} {:>6} {:>6} {:>7} {:>7} {:>8} {:>8} {:>8}  last rejection",
        "service", "pid", "alive", "in", "out", "rej", "drop", "in Hz", "out Hz", "lat p50", "lat p99", "work p50"
    );
    if r.services.is_empty() {
        let _ = writeln!(out, "(no heartbeat: no service running in this domain)");
    }
    for s in &r.services {
        let _ = writeln!(
            out,
            "{:<11} {:>7} {:>5} {:>8} {:>8} {:>6} {:>6} {:>7.1} {:>7.1} {:>8} {:>8} {:>8}  {}",
            s.service,
            s.pid,
            if s.alive { "yes" } else { "NO" },
            s.inputs,
            s.outputs,
            s.rejected,
            s.dropped,
            s.input_rate_hz,
            s.output_rate_hz,
            ms(s.latency_p50_ms),
            ms(s.latency_p99_ms),
            ms(s.work_p50_ms),
            s.last_rejection
        );
    }
    let _ = writeln!(out);
    out
}
