//! Prints the health of every service of a sidecar, from their heartbeats, once
//! a second.
//!
//! ```sh
//! cargo run -p outlet-client --example health                 # default domain, until Ctrl-C
//! cargo run -p outlet-client --example health -- mydomain --count 3
//! ```

use iceoryx2_bb_posix::signal::SignalHandler;
use outlet_client::{Client, ClientError, DEFAULT_DOMAIN, Heartbeat};
use std::time::{Duration, Instant};

fn ms(d: Option<Duration>) -> String {
    d.map_or_else(|| "-".to_string(), |d| format!("{:.1}", d.as_secs_f64() * 1e3))
}

fn print(beat: &Heartbeat) {
    let state = if beat.is_alive(Duration::from_secs(3)) { "alive" } else { "SILENT" };
    println!(
        "  {:<12} pid {:<7} {state:<6} in {:>7} out {:>7} rejected {:>5} dropped {:>5}  {:.1}/{:.1} Hz  \
         latency p50/p99/max {}/{}/{} ms  work p50/p99 {}/{} ms",
        beat.service,
        beat.pid,
        beat.inputs,
        beat.outputs,
        beat.rejected,
        beat.dropped,
        beat.input_rate_hz,
        beat.output_rate_hz,
        ms(beat.latency_p50),
        ms(beat.latency_p99),
        ms(beat.latency_max),
        ms(beat.work_p50),
        ms(beat.work_p99),
    );
    if let Some(reason) = &beat.last_rejection {
        println!("  {:<12} last rejection: {reason}", "");
    }
}

fn main() -> Result<(), ClientError> {
    let mut args = std::env::args().skip(1);
    let mut domain = DEFAULT_DOMAIN.to_string();
    let mut count = None;
    while let Some(arg) = args.next() {
        if arg == "--count" {
            count = args.next().and_then(|n| n.parse::<u64>().ok());
        } else {
            domain = arg;
        }
    }
    let mut client = Client::connect(&domain)?;
    let mut rounds = 0;
    // The first call makes iceoryx2 capture SIGINT and SIGTERM, so that Ctrl-C
    // ends the loop and the client's resources are released.
    while !SignalHandler::termination_requested() && count.is_none_or(|n| rounds < n) {
        if rounds > 0 {
            // Sleep a second by waiting on results: a signal ends the wait at once.
            let until = Instant::now() + Duration::from_secs(1);
            let mut left = Duration::from_secs(1);
            while !left.is_zero() {
                match client.wait_next(left) {
                    Err(ClientError::Interrupted) => return Ok(()),
                    Err(e) => return Err(e),
                    Ok(_) => left = until.saturating_duration_since(Instant::now()),
                }
            }
        }
        rounds += 1;
        let beats = client.heartbeats()?;
        println!("{} services in domain {domain:?}", beats.len());
        for beat in &beats {
            print(beat);
        }
    }
    Ok(())
}
