//! Faults the robot will meet: services started in any order, a pipeline that
//! stops. The client must get results whatever the order, and must say "no
//! result since T" rather than hand out stale data as fresh.

use outlet_client::{Client, PoseMode};
use outlet_tests::{Sidecar, domain, wait_for};
use std::time::{Duration, Instant, SystemTime};

type TestResult = Result<(), Box<dyn std::error::Error>>;

const SERVICES: [(&str, &[&str]); 4] = [
    ("normal", &[]),
    ("pose", &["--template", "2x1"]),
    ("detector", &["--template", "2x1"]),
    ("sim-camera", &["--scenario", "fw_2x1white", "--rate", "15", "--views", "2"]),
];

/// Every permutation of `0..n`, in lexicographic order.
fn permutations(n: usize) -> Vec<Vec<usize>> {
    if n == 0 {
        return vec![Vec::new()];
    }
    let mut out = Vec::new();
    for first in 0..n {
        for rest in permutations(n - 1) {
            let mut p = vec![first];
            p.extend(rest.into_iter().map(|k| if k >= first { k + 1 } else { k }));
            out.push(p);
        }
    }
    out
}

#[test]
fn the_services_started_in_every_order_give_plane_mode_results() -> TestResult {
    let orders = permutations(SERVICES.len());
    assert_eq!(orders.len(), 24);
    for (k, order) in orders.iter().enumerate() {
        let domain = domain(&format!("order{k}"));
        let mut client = Client::connect(&domain)?;
        let mut sidecar = Sidecar::new(&domain)?;
        let names: Vec<&str> = order.iter().map(|&i| SERVICES[i].0).collect();
        for &i in order {
            sidecar.start(SERVICES[i].0, SERVICES[i].1)?;
            // Far enough apart that each really comes up after the one before.
            std::thread::sleep(Duration::from_millis(150));
        }
        let result = wait_for(Duration::from_secs(30), || {
            client.wait_next(Duration::from_millis(100)).ok().flatten().filter(|p| p.mode == PoseMode::Plane)
        });
        assert!(result.is_some(), "no plane-mode result with the services started in the order {names:?}");
        assert_eq!(sidecar.dead(), None, "a service died in the order {names:?}");
    }
    Ok(())
}

#[test]
fn a_stopped_pipeline_is_reported_as_no_result_since_not_as_fresh_data() -> TestResult {
    let domain = domain("stale");
    let mut client = Client::connect(&domain)?;
    let mut sidecar = Sidecar::new(&domain)?;
    for (name, args) in SERVICES {
        sidecar.start(name, args)?;
    }
    let last = wait_for(Duration::from_secs(30), || client.wait_next(Duration::from_millis(100)).ok().flatten())
        .ok_or("no result from the pipeline")?;
    assert_eq!(client.no_result_since(Duration::from_millis(500)), None, "results are flowing");

    // The camera dies: nothing new comes, whatever else still runs.
    sidecar.kill9("sim-camera")?;
    let stopped = Instant::now();
    std::thread::sleep(Duration::from_millis(300)); // what was in flight arrives
    while client.wait_next(Duration::ZERO)?.is_some() {}
    let received_last = client.last_result_at().ok_or("no last result")?;
    assert_eq!(client.wait_next(Duration::from_millis(1200))?, None, "a result after the camera died");
    assert!(stopped.elapsed() >= Duration::from_millis(1500));

    // The client says since when there is nothing, and the newest result says its age.
    let since = client.no_result_since(Duration::from_secs(1)).ok_or("the client does not report the silence")?;
    assert_eq!(since, received_last);
    let latest = client.latest()?.ok_or("the newest result is gone")?;
    assert!(latest.frame_id >= last.frame_id);
    assert!(latest.age() > Duration::from_secs(1), "stale result aged {:?}", latest.age());
    assert!(SystemTime::now().duration_since(latest.received)? > Duration::from_secs(1));
    // The services themselves are alive, and their heartbeats show nothing coming out.
    let detector = wait_for(Duration::from_secs(5), || {
        client.heartbeats().ok()?.into_iter().find(|h| h.service == "detector" && h.output_rate_hz == 0.0)
    })
    .ok_or("the detector's heartbeat does not show the silence")?;
    assert!(detector.is_alive(Duration::from_secs(1)));
    Ok(())
}

#[test]
fn permutations_are_all_distinct() {
    let mut p = permutations(4);
    p.sort();
    p.dedup();
    assert_eq!(p.len(), 24);
    assert!(p.iter().all(|o| { (0..4).all(|k| o.contains(&k)) }));
}
