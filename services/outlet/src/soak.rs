//! The soak report of `outlet demo --soak-report FILE`: one JSON line per
//! period with each process's resident memory, the services' counters and the
//! results' latency percentiles; a summary line at the end that says whether
//! memory grew after warm-up, whether latency drifted, and what was dropped.

use outlet_client::Heartbeat;
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// Resident memory of a process (kB), from `/proc/<pid>/status`.
pub fn rss_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[derive(Debug, Clone, Serialize)]
pub struct ServiceSample {
    pub pid: u32,
    pub rss_kb: Option<u64>,
    pub inputs: u64,
    pub outputs: u64,
    pub rejected: u64,
    pub dropped: u64,
}

/// One period of the soak.
#[derive(Debug, Serialize)]
pub struct Period {
    pub t_s: f64,
    pub frames: u64,
    pub results: u64,
    pub latency_p50_ms: Option<f64>,
    pub latency_p99_ms: Option<f64>,
    pub latency_max_ms: Option<f64>,
    pub demo_rss_kb: Option<u64>,
    pub services: BTreeMap<String, ServiceSample>,
}

#[derive(Debug, Serialize)]
pub struct Summary {
    pub summary: bool,
    pub seconds: f64,
    pub periods: usize,
    pub frames: u64,
    pub results: u64,
    /// Frames the services skipped for a newer one (heartbeats' `dropped`).
    pub dropped: u64,
    pub rejected: u64,
    /// Frames published without a result (no outlet found, or dropped).
    pub frames_without_result: u64,
    /// Per process: resident memory after warm-up (the second period) and its
    /// largest growth above that since (kB).
    pub rss_after_warmup_kb: BTreeMap<String, u64>,
    pub rss_growth_kb: BTreeMap<String, i64>,
    /// Median latency of the last periods over the first ones after warm-up.
    pub latency_p50_drift: Option<f64>,
    pub crashed: Option<String>,
}

pub struct SoakReport {
    file: std::fs::File,
    periods: Vec<Period>,
    window: Vec<f64>,
    frames_in_period: u64,
    results_in_period: u64,
}

fn quantile(sorted: &[f64], q: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    Some(sorted[((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len()) - 1])
}

impl SoakReport {
    pub fn create(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            file: std::fs::File::create(path)?,
            periods: Vec::new(),
            window: Vec::new(),
            frames_in_period: 0,
            results_in_period: 0,
        })
    }

    pub fn frame(&mut self) {
        self.frames_in_period += 1;
    }

    pub fn result(&mut self, latency_ms: f64) {
        self.results_in_period += 1;
        self.window.push(latency_ms);
    }

    /// Closes a period: samples memory and counters, writes its line.
    pub fn period(&mut self, t_s: f64, heartbeats: &[Heartbeat], pids: &[(&str, u32)]) -> std::io::Result<()> {
        self.window.sort_by(f64::total_cmp);
        let services = pids
            .iter()
            .map(|&(name, pid)| {
                let beat = heartbeats.iter().find(|h| h.service == name && h.pid == pid);
                let sample = ServiceSample {
                    pid,
                    rss_kb: rss_kb(pid),
                    inputs: beat.map_or(0, |h| h.inputs),
                    outputs: beat.map_or(0, |h| h.outputs),
                    rejected: beat.map_or(0, |h| h.rejected),
                    dropped: beat.map_or(0, |h| h.dropped),
                };
                (name.to_string(), sample)
            })
            .collect();
        let period = Period {
            t_s,
            frames: self.frames_in_period,
            results: self.results_in_period,
            latency_p50_ms: quantile(&self.window, 0.5),
            latency_p99_ms: quantile(&self.window, 0.99),
            latency_max_ms: self.window.last().copied(),
            demo_rss_kb: rss_kb(std::process::id()),
            services,
        };
        writeln!(self.file, "{}", serde_json::to_string(&period).map_err(std::io::Error::other)?)?;
        self.file.flush()?;
        self.periods.push(period);
        self.window.clear();
        self.frames_in_period = 0;
        self.results_in_period = 0;
        Ok(())
    }

    /// The summary over every period, also written as the file's last line.
    pub fn finish(&mut self, seconds: f64, crashed: Option<String>) -> std::io::Result<Summary> {
        let summary = summarise(&self.periods, seconds, crashed);
        writeln!(self.file, "{}", serde_json::to_string(&summary).map_err(std::io::Error::other)?)?;
        self.file.flush()?;
        Ok(summary)
    }
}

fn summarise(periods: &[Period], seconds: f64, crashed: Option<String>) -> Summary {
    // The first period is warm-up (templates, page faults of the shared memory).
    let settled = periods.get(1..).unwrap_or_default();
    let mut rss_after_warmup_kb = BTreeMap::new();
    let mut rss_growth_kb = BTreeMap::new();
    let mut names: Vec<String> = periods.iter().flat_map(|p| p.services.keys().cloned()).collect();
    names.sort();
    names.dedup();
    for name in names.iter().map(String::as_str).chain(["demo"]) {
        let series: Vec<u64> = settled
            .iter()
            .filter_map(|p| if name == "demo" { p.demo_rss_kb } else { p.services.get(name)?.rss_kb })
            .collect();
        if let (Some(&first), Some(&max)) = (series.first(), series.iter().max()) {
            rss_after_warmup_kb.insert(name.to_string(), first);
            rss_growth_kb.insert(name.to_string(), max as i64 - first as i64);
        }
    }
    let p50s: Vec<f64> = settled.iter().filter_map(|p| p.latency_p50_ms).collect();
    let third = (p50s.len() / 3).max(1);
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        quantile(&v, 0.5)
    };
    let latency_p50_drift = if p50s.len() >= 3 {
        median(&p50s[p50s.len() - third..]).zip(median(&p50s[..third])).map(|(late, early)| late / early)
    } else {
        None
    };
    let last = periods.last();
    let total = |f: fn(&ServiceSample) -> u64| last.map_or(0, |p| p.services.values().map(f).sum::<u64>());
    let frames: u64 = periods.iter().map(|p| p.frames).sum();
    let results: u64 = periods.iter().map(|p| p.results).sum();
    Summary {
        summary: true,
        seconds,
        periods: periods.len(),
        frames,
        results,
        dropped: total(|s| s.dropped),
        rejected: total(|s| s.rejected),
        frames_without_result: frames.saturating_sub(results),
        rss_after_warmup_kb,
        rss_growth_kb,
        latency_p50_drift,
        crashed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn period(t: f64, rss: u64, p50: f64) -> Period {
        let mut services = BTreeMap::new();
        services.insert(
            "detector".to_string(),
            ServiceSample { pid: 1, rss_kb: Some(rss), inputs: 10, outputs: 9, rejected: 0, dropped: 1 },
        );
        Period {
            t_s: t,
            frames: 10,
            results: 9,
            latency_p50_ms: Some(p50),
            latency_p99_ms: Some(p50 * 2.0),
            latency_max_ms: Some(p50 * 3.0),
            demo_rss_kb: Some(1000),
            services,
        }
    }

    #[test]
    fn growth_is_measured_after_warm_up_and_drift_late_over_early() {
        let periods: Vec<Period> =
            (0..7).map(|k| period(k as f64 * 60.0, if k == 0 { 500 } else { 900 + 10 * k }, 5.0 + k as f64)).collect();
        let s = summarise(&periods, 420.0, None);
        assert_eq!(s.rss_after_warmup_kb["detector"], 910);
        assert_eq!(s.rss_growth_kb["detector"], 50);
        assert_eq!(s.rss_growth_kb["demo"], 0);
        // p50s after warm-up: 6..=11; last two over first two: median 10 (of 10, 11) / median 6 (of 6, 7).
        assert_eq!(s.latency_p50_drift, Some(10.0 / 6.0));
        assert_eq!((s.frames, s.results, s.frames_without_result, s.dropped), (70, 63, 7, 1));
    }

    #[test]
    fn resident_memory_of_this_process_is_read() {
        assert!(rss_kb(std::process::id()).is_some_and(|kb| kb > 0));
        assert_eq!(rss_kb(u32::MAX), None);
    }
}
