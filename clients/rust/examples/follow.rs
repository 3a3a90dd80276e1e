//! Follows the hole poses of a running sidecar: prints every result's holes and
//! age, and "no result since ..." when nothing arrives for a second.
//!
//! ```sh
//! cargo run -p outlet-client --example follow                 # default domain, until Ctrl-C
//! cargo run -p outlet-client --example follow -- mydomain --count 10
//! ```

use iceoryx2_bb_posix::signal::SignalHandler;
use outlet_client::{Client, ClientError, DEFAULT_DOMAIN};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

struct Args {
    domain: String,
    count: Option<u64>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args { domain: DEFAULT_DOMAIN.to_string(), count: None };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--count" => {
                let n = it.next().ok_or("--count needs a number")?;
                args.count = Some(n.parse().map_err(|e| format!("--count {n:?}: {e}"))?);
            }
            "-h" | "--help" => return Err(String::new()),
            _ if arg.starts_with('-') => return Err(format!("unknown option {arg:?}")),
            _ => args.domain = arg,
        }
    }
    Ok(args)
}

/// `HH:MM:SS.mmm UTC` of a time (no calendar date: enough for a log line).
fn clock(t: SystemTime) -> String {
    let ms = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis());
    let s = ms / 1000;
    format!("{:02}:{:02}:{:02}.{:03} UTC", s / 3600 % 24, s / 60 % 60, s % 60, ms % 1000)
}

fn main() -> std::process::ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            if !e.is_empty() {
                eprintln!("follow: {e}");
            }
            eprintln!("usage: follow [DOMAIN] [--count N]   (DOMAIN defaults to {DEFAULT_DOMAIN:?})");
            return std::process::ExitCode::from(2);
        }
    };
    match follow(&args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("follow: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn follow(args: &Args) -> Result<(), ClientError> {
    let mut client = Client::connect(&args.domain)?;
    println!("following hole poses in domain {:?}", client.domain());
    let mut seen = 0;
    // The first call makes iceoryx2 capture SIGINT and SIGTERM: Ctrl-C then ends
    // a wait with `ClientError::Interrupted` (or is seen here between waits), and
    // the client's shared-memory resources are released on the way out.
    while !SignalHandler::termination_requested() && args.count.is_none_or(|n| seen < n) {
        match client.wait_next(Duration::from_secs(1)) {
            Ok(Some(poses)) => {
                seen += 1;
                println!(
                    "frame {} ({}): {} holes, age {:.1} ms, sidecar latency {:.1} ms",
                    poses.frame_id,
                    poses.mode.as_str(),
                    poses.holes.len(),
                    poses.age().as_secs_f64() * 1e3,
                    poses.latency().as_secs_f64() * 1e3,
                );
                for hole in &poses.holes {
                    let [x, y, z] = hole.position_m;
                    let [sx, sy, sz] = hole.std_dev_m();
                    println!(
                        "  {:<6} ({x:+.5}, {y:+.5}, {z:+.5}) m  sigma ({:.2}, {:.2}, {:.2}) mm",
                        hole.kind.as_str(),
                        sx * 1e3,
                        sy * 1e3,
                        sz * 1e3
                    );
                }
            }
            Ok(None) => {
                if let Some(since) = client.no_result_since(Duration::from_secs(1)) {
                    let ago = SystemTime::now().duration_since(since).unwrap_or_default();
                    let what =
                        if client.last_result_at().is_some() { "no result since" } else { "no result yet, since" };
                    println!("{what} {} ({:.1} s ago)", clock(since), ago.as_secs_f64());
                }
            }
            Err(ClientError::Interrupted) => break,
            Err(e) => return Err(e),
        }
    }
    if client.rejected() > 0 {
        println!("{} messages rejected, the last: {:?}", client.rejected(), client.last_rejection());
    }
    Ok(())
}
