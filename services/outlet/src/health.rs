//! What a service counts between heartbeats, and the heartbeat it makes of it.

use outlet_protocol::wire::HeartbeatMsg;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

/// Nanoseconds since the Unix epoch: the clock of capture and publish stamps.
pub fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos().min(u64::MAX as u128) as u64)
}

/// Counters and the latencies of the current period.
#[derive(Debug)]
pub struct Health {
    beat: HeartbeatMsg,
    period_start: Instant,
    period_inputs: u64,
    period_outputs: u64,
    latencies_ms: Vec<f64>,
    work_ms: Vec<f64>,
}

/// The value below which a fraction `q` of the sorted samples lie (NaN if none).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let k = ((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len());
    sorted[k - 1]
}

impl Health {
    pub fn new(service: &str) -> Self {
        Self {
            beat: HeartbeatMsg::new(service, std::process::id(), now_ns()),
            period_start: Instant::now(),
            period_inputs: 0,
            period_outputs: 0,
            latencies_ms: Vec::with_capacity(256),
            work_ms: Vec::with_capacity(256),
        }
    }

    pub fn input(&mut self) {
        self.beat.inputs += 1;
        self.period_inputs += 1;
    }

    /// An input refused: counted, and its reason kept for the heartbeat.
    pub fn rejected(&mut self, reason: &str) {
        self.beat.rejected += 1;
        self.beat.set_last_rejection(reason);
    }

    /// Inputs skipped because a newer one was waiting.
    pub fn dropped(&mut self, count: u64) {
        self.beat.dropped += count;
    }

    /// An output published for an input captured at `capture_ns`, after `work_ms` of work.
    pub fn output(&mut self, capture_ns: u64, work_ms: f64) {
        let now = now_ns();
        self.beat.outputs += 1;
        self.beat.last_output_ns = now;
        self.period_outputs += 1;
        // A capture stamp from another clock (or none) says nothing about latency.
        if capture_ns > 0 && capture_ns <= now && self.latencies_ms.len() < 100_000 {
            self.latencies_ms.push((now - capture_ns) as f64 / 1e6);
        }
        if work_ms.is_finite() && self.work_ms.len() < 100_000 {
            self.work_ms.push(work_ms);
        }
    }

    pub fn totals(&self) -> &HeartbeatMsg {
        &self.beat
    }

    /// The heartbeat of the period now ending; the next period starts.
    pub fn beat(&mut self) -> HeartbeatMsg {
        let seconds = self.period_start.elapsed().as_secs_f64().max(1e-3);
        self.latencies_ms.sort_by(f64::total_cmp);
        self.work_ms.sort_by(f64::total_cmp);
        let b = &mut self.beat;
        b.sequence += 1;
        b.published_ns = now_ns();
        b.input_rate_hz = self.period_inputs as f64 / seconds;
        b.output_rate_hz = self.period_outputs as f64 / seconds;
        b.latency_p50_ms = quantile(&self.latencies_ms, 0.5);
        b.latency_p99_ms = quantile(&self.latencies_ms, 0.99);
        b.latency_max_ms = self.latencies_ms.last().copied().unwrap_or(f64::NAN);
        b.work_p50_ms = quantile(&self.work_ms, 0.5);
        b.work_p99_ms = quantile(&self.work_ms, 0.99);
        let beat = *b;
        self.period_start = Instant::now();
        self.period_inputs = 0;
        self.period_outputs = 0;
        self.latencies_ms.clear();
        self.work_ms.clear();
        beat
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_beat_summarises_its_period_and_starts_the_next() {
        let mut h = Health::new("detector");
        let now = now_ns();
        for k in 1..=100 {
            h.input();
            h.output(now - k * 1_000_000, k as f64 / 10.0);
        }
        h.input();
        h.rejected("frame 7: size 0x480 is empty");
        h.dropped(3);
        let b = h.beat();
        assert_eq!((b.inputs, b.outputs, b.rejected, b.dropped, b.sequence), (101, 100, 1, 3, 1));
        assert_eq!(b.service_name(), "detector");
        assert_eq!(b.last_rejection(), "frame 7: size 0x480 is empty");
        // Latencies are 1..100 ms plus the moments the test took.
        assert!((50.0..60.0).contains(&b.latency_p50_ms), "{}", b.latency_p50_ms);
        assert!((99.0..110.0).contains(&b.latency_p99_ms), "{}", b.latency_p99_ms);
        assert_eq!(b.work_p50_ms, 5.0);
        assert_eq!(b.work_p99_ms, 9.9);
        let next = h.beat();
        assert_eq!((next.inputs, next.outputs, next.sequence), (101, 100, 2));
        assert!(next.latency_p50_ms.is_nan() && next.output_rate_hz == 0.0);
    }

    #[test]
    fn foreign_capture_stamps_do_not_make_latencies() {
        let mut h = Health::new("pose");
        h.output(0, 1.0);
        h.output(u64::MAX, 1.0);
        let b = h.beat();
        assert_eq!(b.outputs, 2);
        assert!(b.latency_p50_ms.is_nan());
    }
}
