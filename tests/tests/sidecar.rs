//! The sidecar as it runs on a robot: `outlet serve sim-camera | detector |
//! normal | pose` as separate processes on iceoryx2 shared memory, the client
//! library reading the hole poses. Each test has a domain of its own.

use iceoryx2::prelude::*;
use outlet_client::{Client, PoseMode};
use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, FrameHeader, PixelFormat, SCHEMA_VERSION, TruthMsg, WallPlaneMsg, service,
};
use outlet_tests::{Sidecar, domain, shm_files, wait_for};
use std::collections::HashMap;
use std::time::{Duration, Instant, SystemTime};

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// The four services of a 2x1 pipeline on a simulated camera replaying a few views.
fn start_pipeline(sidecar: &mut Sidecar) -> Result<(), String> {
    sidecar.start("normal", &[])?;
    sidecar.start("pose", &["--template", "2x1"])?;
    sidecar.start("detector", &["--template", "2x1"])?;
    sidecar.start("sim-camera", &["--scenario", "fw_2x1white", "--rate", "10", "--views", "4"])
}

/// The hole errors (mm) of every plane-mode result against the truth of its frame.
fn plane_errors_mm(
    client: &mut Client,
    truth: &iceoryx2::port::subscriber::Subscriber<ipc::Service, TruthMsg, ()>,
    truths: &mut HashMap<u64, TruthMsg>,
    timeout: Duration,
) -> Result<Option<Vec<f64>>, Box<dyn std::error::Error>> {
    let Some(poses) = client.wait_next(timeout)? else { return Ok(None) };
    while let Some(t) = truth.receive()? {
        truths.insert(t.payload().frame_id, *t.payload());
    }
    let t = truths.get(&poses.frame_id).ok_or(format!("no truth for frame {}", poses.frame_id))?;
    assert_eq!(t.hole_count as usize, poses.holes.len(), "frame {}: hole count", poses.frame_id);
    if poses.mode != PoseMode::Plane {
        return Ok(Some(Vec::new()));
    }
    Ok(Some(
        poses
            .holes
            .iter()
            .zip(&t.positions_m)
            .map(|(h, p)| (0..3).map(|j| (h.position_m[j] - p[j]).powi(2)).sum::<f64>().sqrt() * 1e3)
            .collect(),
    ))
}

#[test]
fn frames_from_the_sim_camera_give_hole_poses_under_a_millimetre_in_owner_only_memory() -> TestResult {
    let domain = domain("e2e");
    let mut sidecar = Sidecar::new(&domain)?;
    let mut client = Client::connect(&domain)?;
    let node = shm::node(&domain, "test")?;
    let truth = shm::messages::<TruthMsg>(&node, service::TRUTH)?.subscriber_builder().create()?;
    start_pipeline(&mut sidecar)?;

    let mut truths = HashMap::new();
    let mut errors = Vec::new();
    let start = Instant::now();
    while errors.len() < 5 * 6 {
        assert!(start.elapsed() < Duration::from_secs(60), "only {} hole errors in 60 s", errors.len());
        assert_eq!(sidecar.dead(), None, "a service died; logs in {}", sidecar.logs.display());
        if let Some(e) = plane_errors_mm(&mut client, &truth, &mut truths, Duration::from_secs(1))? {
            errors.extend(e);
        }
    }
    let worst = errors.iter().copied().fold(0.0, f64::max);

    // `outlet status` sees the four services alive and the frames flowing.
    let status = std::process::Command::new(outlet_tests::outlet_exe()?)
        .args(["status", "--domain", &domain, "--once", "--json", "--interval-ms", "1500"])
        .output()?;
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let report: serde_json::Value = serde_json::from_slice(&status.stdout)?;
    let alive: Vec<&str> = report["services"]
        .as_array()
        .ok_or("no services")?
        .iter()
        .filter(|s| s["alive"] == true)
        .filter_map(|s| s["service"].as_str())
        .collect();
    assert_eq!(alive, ["detector", "normal", "pose", "sim-camera"], "{report}");
    let frames = &report["channels"][0];
    assert_eq!(frames["name"], service::FRAMES);
    assert!(frames["rate_hz"].as_f64().is_some_and(|r| r > 3.0), "{report}");
    assert!(worst < 1.0, "worst hole error {worst:.3} mm over {} holes", errors.len());

    // Every segment of the domain, iceoryx2's node counter included, is the owner's alone.
    let files = shm_files(&domain);
    assert!(files.len() > 5, "the domain's shared memory was not found: {files:?}");
    let open: Vec<_> = files.iter().filter(|(_, mode)| mode & 0o077 != 0).collect();
    assert!(open.is_empty(), "shared memory readable or writable by others: {open:?}");
    Ok(())
}

#[test]
fn a_service_killed_with_sigkill_is_restarted_and_results_flow_within_a_second() -> TestResult {
    let domain = domain("kill9");
    let mut sidecar = Sidecar::new(&domain)?;
    let mut client = Client::connect(&domain)?;
    let node = shm::node(&domain, "test")?;
    let truth = shm::messages::<TruthMsg>(&node, service::TRUTH)?.subscriber_builder().create()?;
    let mut truths = HashMap::new();
    start_pipeline(&mut sidecar)?;
    // Up and running: a plane-mode result.
    wait_for(Duration::from_secs(60), || {
        plane_errors_mm(&mut client, &truth, &mut truths, Duration::from_millis(200))
            .ok()
            .flatten()
            .filter(|e| !e.is_empty())
    })
    .ok_or("no plane-mode result from the pipeline")?;
    let steady_files = shm_files(&domain).len();

    for victim in ["detector", "normal", "pose"] {
        let args = sidecar.kill9(victim)?;
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        std::thread::sleep(Duration::from_millis(300));
        let _ = client.latest()?; // what came before the restart does not count
        let restarted_at = SystemTime::now();
        let restarted = Instant::now();
        sidecar.start(victim, &args)?;
        // A plane-mode result of a frame captured after the restart, under a millimetre.
        let back = wait_for(Duration::from_secs(5), || {
            let poses = client.wait_next(Duration::from_millis(50)).ok().flatten()?;
            (poses.capture_time > restarted_at && poses.mode == PoseMode::Plane).then_some(poses)
        })
        .ok_or(format!("no result after restarting {victim}; logs in {}", sidecar.logs.display()))?;
        let after = restarted.elapsed();
        eprintln!("{victim}: results back {after:?} after its restart");
        assert!(after < Duration::from_secs(1), "results came back {after:?} after restarting {victim}");
        assert_eq!(back.holes.len(), 6);
        assert_eq!(sidecar.dead(), None, "a service died after restarting {victim}");

        // The killed process left nothing behind: iceoryx2 sees no dead node in the
        // domain, and the domain holds no more files than before.
        let mut dead = 0;
        Node::<ipc::Service>::list(&shm::config(&domain)?, |state| {
            if let NodeState::Dead(_) = state {
                dead += 1;
            }
            CallbackProgression::Continue
        })?;
        assert_eq!(dead, 0, "a dead node of {victim} is left in the domain");
        let files = shm_files(&domain).len();
        assert!(files <= steady_files, "{files} shared-memory files after restarting {victim}, {steady_files} before");
    }
    Ok(())
}

/// The newest heartbeat of `service` once `ready` holds for it.
fn heartbeat_when(
    client: &mut Client,
    service: &str,
    ready: impl Fn(&outlet_client::Heartbeat) -> bool,
) -> Option<outlet_client::Heartbeat> {
    wait_for(Duration::from_secs(10), || {
        client.heartbeats().ok()?.into_iter().find(|h| h.service == service && ready(h))
    })
}

#[test]
fn bad_frames_and_clouds_are_counted_as_rejected_logged_and_the_services_go_on() -> TestResult {
    let domain = domain("reject");
    let mut sidecar = Sidecar::new(&domain)?;
    let mut client = Client::connect(&domain)?;
    let node = shm::node(&domain, "test")?;
    let frame_pub = shm::frames(&node)?.publisher_builder().initial_max_slice_len(640 * 480 * 3).create()?;
    let cloud_pub = shm::clouds(&node)?.publisher_builder().initial_max_slice_len(3 * 4096).create()?;
    let frame_note = shm::events(&node, service::FRAMES)?.notifier_builder().create()?;
    let cloud_note = shm::events(&node, service::CLOUDS)?.notifier_builder().create()?;
    let detections = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?.subscriber_builder().create()?;
    let planes = shm::messages::<WallPlaneMsg>(&node, service::PLANES)?.subscriber_builder().create()?;
    sidecar.start("detector", &["--template", "2x1"])?;
    sidecar.start("normal", &[])?;
    // Both serving: their first heartbeats.
    for s in ["detector", "normal"] {
        heartbeat_when(&mut client, s, |_| true).ok_or(format!("no heartbeat from {s}"))?;
    }

    let camera = CameraModel::default_vga();
    let grey = vec![128u8; 640 * 480 * 3];
    let send_frame = |header: FrameHeader, len: usize| -> TestResult {
        let mut f = frame_pub.loan_slice_uninit(len)?;
        *f.user_header_mut() = header;
        f.write_from_slice(&grey[..len]).send()?;
        frame_note.notify()?;
        Ok(())
    };
    let good = FrameHeader::new(1, 1, PixelFormat::Rgb8, &camera);
    let bad_frames = [
        (FrameHeader { frame_id: 2, ..good }, 1000), // shorter than its size
        (FrameHeader { frame_id: 3, width: 0, ..good }, grey.len()), // zero width
        (FrameHeader { frame_id: 4, pixel_format: 77, ..good }, grey.len()), // unknown format
    ];
    for (k, (header, len)) in bad_frames.into_iter().enumerate() {
        send_frame(header, len)?;
        // One at a time: the detector drops frames that queue up behind a newer one.
        heartbeat_when(&mut client, "detector", |h| h.rejected == k as u64 + 1)
            .ok_or(format!("bad frame {} not counted as rejected", header.frame_id))?;
    }
    // A cloud of NaN: stereo that failed everywhere.
    let nan = vec![f32::NAN; 3 * 4096];
    let mut c = cloud_pub.loan_slice_uninit(nan.len())?;
    *c.user_header_mut() =
        CloudHeader { schema_version: SCHEMA_VERSION, reserved: 0, frame_id: 5, capture_time_ns: 5, points: 4096 };
    c.write_from_slice(&nan).send()?;
    cloud_note.notify()?;
    heartbeat_when(&mut client, "normal", |h| h.rejected == 1).ok_or("the NaN cloud was not counted as rejected")?;

    // Both still serve: a good frame gives a detection, a good cloud a plane.
    send_frame(good, grey.len())?;
    let wall: Vec<f32> = (0..4096)
        .flat_map(|k| {
            let (x, y) = ((k % 64) as f32 * 0.005 - 0.16, (k / 64) as f32 * 0.005 - 0.16);
            [x, y, 0.4 + 0.1 * x]
        })
        .collect();
    let mut c = cloud_pub.loan_slice_uninit(wall.len())?;
    *c.user_header_mut() =
        CloudHeader { schema_version: SCHEMA_VERSION, reserved: 0, frame_id: 6, capture_time_ns: 6, points: 4096 };
    c.write_from_slice(&wall).send()?;
    cloud_note.notify()?;
    let detection = wait_for(Duration::from_secs(10), || detections.receive().ok().flatten().map(|d| *d.payload()))
        .ok_or("no detection for the good frame")?;
    assert_eq!(detection.frame_id, 1);
    let plane = wait_for(Duration::from_secs(10), || planes.receive().ok().flatten().map(|p| *p.payload()))
        .ok_or("no plane for the good cloud")?;
    assert_eq!(plane.frame_id, 6);
    assert_eq!(sidecar.dead(), None);

    let detector = heartbeat_when(&mut client, "detector", |h| h.outputs >= 1).ok_or("no detector heartbeat")?;
    assert_eq!((detector.rejected, detector.inputs, detector.outputs), (3, 4, 1));
    let last = detector.last_rejection.unwrap_or_default();
    assert!(last.contains("unknown pixel format"), "{last}");
    let normal = heartbeat_when(&mut client, "normal", |h| h.outputs >= 1).ok_or("no normal heartbeat")?;
    assert_eq!((normal.rejected, normal.outputs), (1, 1));

    // And each refusal is in the service's log, with its reason.
    let log = std::fs::read_to_string(sidecar.log_path("detector"))?;
    assert_eq!(log.matches("frame rejected").count(), 3, "detector log:\n{log}");
    assert!(log.contains("1000 bytes of pixels") && log.contains("is empty") && log.contains("unknown pixel format"));
    let log = std::fs::read_to_string(sidecar.log_path("normal"))?;
    assert!(log.contains("cloud rejected"), "normal log:\n{log}");
    Ok(())
}

#[test]
fn services_stopped_one_by_one_leave_nothing_in_shared_memory() -> TestResult {
    let domain = domain("stop1by1");
    let mut sidecar = Sidecar::new(&domain)?;
    let mut client = Client::connect(&domain)?;
    start_pipeline(&mut sidecar)?;
    wait_for(Duration::from_secs(60), || client.wait_next(Duration::from_millis(200)).ok().flatten())
        .ok_or(format!("no result from the pipeline; logs in {}", sidecar.logs.display()))?;
    drop(client);
    let counter = |files: &[(String, u32)]| files.iter().any(|(name, _)| name.ends_with(".global_mgmt"));
    for (k, service) in ["sim-camera", "detector", "normal", "pose"].into_iter().enumerate() {
        sidecar.terminate(service)?;
        let files = shm_files(&domain);
        if k < 3 {
            // Others still run: the domain's node counter stays theirs.
            assert!(counter(&files), "iceoryx2's node counter went while services still ran: {files:?}");
        } else {
            assert!(files.is_empty(), "the last service stopped and left {files:?}");
        }
    }
    Ok(())
}

/// Ctrl-Z then `fg` sends SIGCONT; SIGURG and SIGWINCH come to any terminal
/// program. Each interrupts a service's wait, and none may end it: only SIGINT
/// and SIGTERM do (it used to stop on any of them).
#[test]
fn signals_that_only_interrupt_do_not_stop_a_service() -> TestResult {
    use nix::sys::signal::{Signal, kill};
    let domain = domain("signals");
    let mut sidecar = Sidecar::new(&domain)?;
    start_pipeline(&mut sidecar)?;
    // Every service's first heartbeat: each is in its WaitSet.
    let node = shm::node(&domain, "signals-test")?;
    let beats = shm::heartbeats(&node)?.subscriber_builder().create().map_err(|e| format!("{e:?}"))?;
    let mut seen = std::collections::BTreeSet::new();
    wait_for(Duration::from_secs(30), || {
        while let Ok(Some(b)) = beats.receive() {
            seen.insert(b.payload().service_name().to_string());
        }
        (seen.len() >= 4).then_some(())
    })
    .ok_or_else(|| format!("heartbeats only from {seen:?}"))?;
    for service in ["normal", "pose", "detector", "sim-camera"] {
        let pid = sidecar.pid(service).ok_or(format!("no {service}"))?;
        let pid = nix::unistd::Pid::from_raw(i32::try_from(pid)?);
        for signal in [Signal::SIGCONT, Signal::SIGURG, Signal::SIGWINCH] {
            kill(pid, signal)?;
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(sidecar.dead(), None, "a service ended on SIGCONT, SIGURG or SIGWINCH");
    // SIGTERM still stops each one.
    for service in ["sim-camera", "detector", "pose", "normal"] {
        sidecar.terminate(service)?;
    }
    Ok(())
}
