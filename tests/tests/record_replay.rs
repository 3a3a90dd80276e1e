//! `outlet record` keeps what the camera put in shared memory; `outlet replay`
//! plays it into another domain, where the services find the same holes.

use outlet_client::{Client, PoseMode};
use outlet_protocol::shm;
use outlet_protocol::wire::{TruthMsg, service};
use outlet_tests::{Sidecar, domain, outlet_exe, wait_for};
use std::collections::HashMap;
use std::process::Command;
use std::time::Duration;

#[test]
fn a_recording_replayed_into_another_domain_gives_the_same_holes() -> Result<(), Box<dyn std::error::Error>> {
    let live = domain("live");
    let node = shm::node(&live, "test")?;
    let truth = shm::messages::<TruthMsg>(&node, service::TRUTH)?.subscriber_builder().create()?;
    let file = std::env::temp_dir().join(format!("outlet-{live}.rec"));
    let mut camera = Sidecar::new(&live)?;
    let recorder = Command::new(outlet_exe()?)
        .args(["record", "--domain", &live, "--frames", "8"])
        .arg(&file)
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    std::thread::sleep(Duration::from_millis(300)); // the recorder subscribes first
    // Ctrl-Z and `fg` (SIGCONT), a resized terminal (SIGWINCH): the recording goes on.
    let pid = nix::unistd::Pid::from_raw(i32::try_from(recorder.id())?);
    for signal in [nix::sys::signal::Signal::SIGCONT, nix::sys::signal::Signal::SIGWINCH] {
        nix::sys::signal::kill(pid, signal)?;
    }
    camera.start("sim-camera", &["--scenario", "fw_2x1white", "--rate", "10", "--views", "3"])?;
    let output = recorder.wait_with_output()?;
    let said = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "outlet record failed: {}: {said}", output.status);
    assert!(said.contains("outlet record: 8 frames"), "the recording ended early: {said}");
    let mut truths = HashMap::new();
    while let Some(t) = truth.receive()? {
        truths.insert(t.payload().frame_id, *t.payload());
    }
    drop(camera);

    let replayed = domain("replayed");
    let mut client = Client::connect(&replayed)?;
    let mut services = Sidecar::new(&replayed)?;
    services.start("normal", &[])?;
    services.start("pose", &["--template", "2x1"])?;
    services.start("detector", &["--template", "2x1"])?;
    // Until the services are up, what is replayed finds nobody: play it a few times.
    let replay =
        Command::new(outlet_exe()?).args(["replay", "--domain", &replayed, "--repeat", "6"]).arg(&file).output()?;
    assert!(replay.status.success(), "outlet replay failed: {}", String::from_utf8_lossy(&replay.stderr));
    let poses =
        wait_for(Duration::from_secs(10), || client.latest().ok().flatten().filter(|p| p.mode == PoseMode::Plane))
            .ok_or("no plane-mode result from the replayed frames")?;
    // Replayed frame ids are the recorded ones plus a billion per pass.
    let t = truths.get(&(poses.frame_id % 1_000_000_000)).ok_or(format!("no truth for {}", poses.frame_id))?;
    for (h, p) in poses.holes.iter().zip(&t.positions_m) {
        let e = (0..3).map(|j| (h.position_m[j] - p[j]).powi(2)).sum::<f64>().sqrt() * 1e3;
        assert!(e < 1.0, "frame {}: hole error {e:.3} mm", poses.frame_id);
    }
    let _ = std::fs::remove_file(&file);
    Ok(())
}
