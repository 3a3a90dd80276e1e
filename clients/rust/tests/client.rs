//! The client against a publisher in this test: each test has its own domain, so
//! tests run in parallel without seeing each other's messages.

use outlet_client::{Client, HoleKind, PoseMode, Rejection};
use outlet_protocol::shm;
use outlet_protocol::wire::{HeartbeatMsg, HolePosesMsg, MAX_HOLES, SCHEMA_VERSION, service};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

type Ipc = iceoryx2::service::ipc::Service;

/// A domain no other test (or test run) uses: `clienttest<pid>_<n>`. Bind it
/// first in a test so that it drops last, after every node of the domain.
struct Domain(String);

fn unique_domain() -> Domain {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    Domain(format!("clienttest{}_{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)))
}

impl std::ops::Deref for Domain {
    type Target = str;
    fn deref(&self) -> &str {
        &self.0
    }
}

impl Drop for Domain {
    /// iceoryx2 removes a domain's resources with its last node, except a small
    /// node counter in /dev/shm; remove that too so test runs leave nothing behind.
    fn drop(&mut self) {
        let prefix = format!("{}_", self.0);
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for entry in entries.flatten() {
                if entry.file_name().to_string_lossy().starts_with(&prefix) {
                    let _ = std::fs::remove_file(entry.path());
                }
            }
        }
    }
}

fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// What the pose service does: publish a [`HolePosesMsg`], then notify.
struct PoseService {
    publisher: iceoryx2::port::publisher::Publisher<Ipc, HolePosesMsg, ()>,
    notifier: iceoryx2::port::notifier::Notifier<Ipc>,
    _node: iceoryx2::node::Node<Ipc>,
}

impl PoseService {
    fn open(domain: &str) -> Self {
        let node = shm::node(domain, "test-pose").expect("node");
        let publisher = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)
            .expect("hole poses service")
            .publisher_builder()
            .create()
            .expect("publisher");
        let notifier =
            shm::events(&node, service::HOLE_POSES).expect("events").notifier_builder().create().expect("notifier");
        Self { publisher, notifier, _node: node }
    }

    fn send(&self, msg: HolePosesMsg) {
        self.publisher.send_copy(msg).expect("send");
        self.notifier.notify().expect("notify");
    }
}

/// A 2x1's three holes (power, power, ground) about 30 cm in front of the camera,
/// made distinct by `frame_id`.
fn poses(frame_id: u64) -> HolePosesMsg {
    let mut m = HolePosesMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 3,
        frame_id,
        capture_time_ns: now_ns() - 40_000_000,
        published_ns: now_ns(),
        mode: 3,
        status: 1,
        outlier_mask: 0,
        reserved: 0,
        rotation: [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0],
        translation_m: [0.01, -0.02, 0.3],
        kinds: [0; MAX_HOLES],
        positions_m: [[0.0; 3]; MAX_HOLES],
        covariances_m2: [[0.0; 9]; MAX_HOLES],
    };
    let offset = frame_id as f64 * 1e-3;
    for (k, (kind, x)) in [(1, -0.00635), (1, 0.00635), (2, 0.0)].into_iter().enumerate() {
        m.kinds[k] = kind;
        m.positions_m[k] = [0.01 + x + offset, -0.02 + 0.01 * k as f64, 0.3 + offset];
        m.covariances_m2[k] = [1e-8, 0.0, 0.0, 0.0, 1e-8, 0.0, 0.0, 0.0, 4e-8];
    }
    m
}

#[test]
fn wait_next_returns_a_published_result_with_its_values() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let pose = PoseService::open(&domain);
    let sent = poses(7);
    pose.send(sent);

    let got = client.wait_next(Duration::from_secs(5)).expect("wait").expect("a result");
    assert_eq!(got.frame_id, 7);
    assert_eq!(got.mode, PoseMode::Plane);
    assert_eq!(got.holes.len(), 3);
    assert_eq!(
        got.holes.iter().map(|h| h.kind).collect::<Vec<_>>(),
        [HoleKind::Power, HoleKind::Power, HoleKind::Ground]
    );
    for (hole, position) in got.holes.iter().zip(&sent.positions_m) {
        assert_eq!(&hole.position_m, position);
    }
    assert_eq!(got.holes[2].covariance_m2[2][2], 4e-8);
    assert_eq!(got.rotation, [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]);
    assert_eq!(got.translation_m, [0.01, -0.02, 0.3]);
    assert_eq!(got.capture_time, UNIX_EPOCH + Duration::from_nanos(sent.capture_time_ns));
    assert_eq!(got.published, UNIX_EPOCH + Duration::from_nanos(sent.published_ns));
    assert!(got.received >= got.published);
    assert!(got.age() >= Duration::from_millis(40));
    assert_eq!(client.last_result_at(), Some(got.received));
    assert_eq!(client.results(), 1);
    assert_eq!(client.rejected(), 0);
}

#[test]
fn wait_next_wakes_for_a_result_published_while_it_waits() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let publisher_domain = domain.to_string();
    let publisher = std::thread::spawn(move || {
        let pose = PoseService::open(&publisher_domain);
        std::thread::sleep(Duration::from_millis(100));
        pose.send(poses(11));
        // Keep the publisher alive until the client has read the sample.
        std::thread::sleep(Duration::from_millis(500));
    });
    let got = client.wait_next(Duration::from_secs(10)).expect("wait");
    assert_eq!(got.map(|p| p.frame_id), Some(11));
    publisher.join().expect("publisher thread");
}

#[test]
fn wait_next_accepts_an_endless_timeout() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let publisher_domain = domain.to_string();
    let publisher = std::thread::spawn(move || {
        let pose = PoseService::open(&publisher_domain);
        std::thread::sleep(Duration::from_millis(100));
        pose.send(poses(12));
        std::thread::sleep(Duration::from_millis(500));
    });
    assert_eq!(client.wait_next(Duration::MAX).expect("wait").map(|p| p.frame_id), Some(12));
    publisher.join().expect("publisher thread");
}

#[test]
fn wait_next_times_out_with_none_when_nothing_is_published() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let _pose = PoseService::open(&domain);
    assert_eq!(client.wait_next(Duration::from_millis(200)).expect("wait"), None);
    assert_eq!(client.wait_next(Duration::ZERO).expect("wait"), None);
    assert_eq!(client.latest().expect("latest"), None);
    assert_eq!(client.last_result_at(), None);
    // Nothing ever arrived: "no result since" the client connected.
    let later = client.connected_at() + Duration::from_secs(2);
    assert_eq!(client.no_result_since_at(later, Duration::from_secs(1)), Some(client.connected_at()));
}

#[test]
fn a_result_is_returned_by_wait_next_only_once() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let pose = PoseService::open(&domain);
    pose.send(poses(1));
    assert_eq!(client.wait_next(Duration::from_secs(5)).expect("wait").map(|p| p.frame_id), Some(1));
    // Its notification is consumed; nothing new arrives.
    assert_eq!(client.wait_next(Duration::from_millis(100)).expect("wait"), None);
    // ... but it stays the latest.
    assert_eq!(client.latest().expect("latest").map(|p| p.frame_id), Some(1));
}

#[test]
fn latest_and_wait_next_return_the_newest_of_several() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let pose = PoseService::open(&domain);
    for frame in 1..=4 {
        pose.send(poses(frame));
    }
    let latest = client.latest().expect("latest").expect("a result");
    assert_eq!(latest.frame_id, 4);
    assert_eq!(latest.holes[0].position_m, poses(4).positions_m[0]);
    assert_eq!(client.results(), 4);
    // Drained: wait_next has nothing new; latest still answers.
    assert_eq!(client.wait_next(Duration::from_millis(50)).expect("wait"), None);
    assert_eq!(client.latest().expect("latest").map(|p| p.frame_id), Some(4));

    for frame in 5..=8 {
        pose.send(poses(frame));
    }
    assert_eq!(client.wait_next(Duration::from_secs(5)).expect("wait").map(|p| p.frame_id), Some(8));
    assert_eq!(client.latest().expect("latest").map(|p| p.frame_id), Some(8));
    let received = client.last_result_at().expect("received");
    assert_eq!(client.no_result_since_at(received + Duration::from_millis(500), Duration::from_secs(1)), None);
    assert_eq!(client.no_result_since_at(received + Duration::from_secs(2), Duration::from_secs(1)), Some(received));
}

#[test]
fn invalid_messages_are_rejected_and_counted() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let pose = PoseService::open(&domain);

    pose.send(HolePosesMsg { schema_version: SCHEMA_VERSION + 1, ..poses(1) });
    let mut nan = poses(2);
    nan.positions_m[1][0] = f64::NAN;
    pose.send(nan);
    pose.send(HolePosesMsg { hole_count: MAX_HOLES as u32 + 1, ..poses(3) });
    pose.send(HolePosesMsg { hole_count: u32::MAX, ..poses(4) });

    assert_eq!(client.wait_next(Duration::from_millis(200)).expect("wait"), None);
    assert_eq!(client.rejected(), 4);
    assert_eq!(client.results(), 0);
    assert!(matches!(client.last_rejection(), Some(Rejection::Wire(reason)) if reason.contains("frame 4")));

    // A valid message after them still comes through.
    pose.send(poses(5));
    assert_eq!(client.wait_next(Duration::from_secs(5)).expect("wait").map(|p| p.frame_id), Some(5));
    assert_eq!(client.rejected(), 4);
}

/// A service's heartbeat publisher.
struct Beats {
    publisher: iceoryx2::port::publisher::Publisher<Ipc, HeartbeatMsg, ()>,
    msg: HeartbeatMsg,
    _node: iceoryx2::node::Node<Ipc>,
}

impl Beats {
    fn open(domain: &str, name: &str, pid: u32) -> Self {
        let node = shm::node(domain, &format!("test-{name}")).expect("node");
        let publisher =
            shm::heartbeats(&node).expect("heartbeat service").publisher_builder().create().expect("publisher");
        Self { publisher, msg: HeartbeatMsg::new(name, pid, now_ns()), _node: node }
    }

    fn beat(&mut self, published_ns: u64, outputs: u64) {
        self.msg.sequence += 1;
        self.msg.published_ns = published_ns;
        self.msg.inputs = outputs + 2;
        self.msg.outputs = outputs;
        self.publisher.send_copy(self.msg).expect("send heartbeat");
    }
}

#[test]
fn heartbeats_are_collected_per_service() {
    let domain = unique_domain();
    let mut client = Client::connect(&domain).expect("connect");
    let mut detector = Beats::open(&domain, "detector", 101);
    let mut pose = Beats::open(&domain, "pose", 102);
    detector.msg.latency_p50_ms = 18.0;
    detector.msg.input_rate_hz = 30.0;
    detector.msg.set_last_rejection("frame 9: stride 10 is less than width 640 x 3 channels");
    for k in 1..=3 {
        detector.beat(now_ns(), 10 * k);
    }
    // The pose service went quiet a minute ago.
    pose.beat(now_ns() - 60_000_000_000, 4);
    let mut bad = Beats::open(&domain, "bad", 103);
    bad.msg.schema_version = SCHEMA_VERSION + 1;
    bad.beat(now_ns(), 0);

    let beats = client.heartbeats().expect("heartbeats");
    assert_eq!(beats.iter().map(|b| b.service.as_str()).collect::<Vec<_>>(), ["detector", "pose"]);
    let d = &beats[0];
    assert_eq!((d.pid, d.sequence, d.inputs, d.outputs, d.rejected, d.dropped), (101, 3, 32, 30, 0, 0));
    assert_eq!(d.input_rate_hz, 30.0);
    assert_eq!(d.latency_p50, Some(Duration::from_millis(18)));
    assert_eq!(d.latency_p99, None);
    assert_eq!(d.last_rejection.as_deref(), Some("frame 9: stride 10 is less than width 640 x 3 channels"));
    assert!(d.is_alive(Duration::from_secs(3)));
    assert_eq!(beats[1].outputs, 4);
    assert!(!beats[1].is_alive(Duration::from_secs(3)));
    assert_eq!(client.rejected_heartbeats(), 1);

    // Later calls keep every service's latest beat.
    pose.beat(now_ns(), 5);
    let beats = client.heartbeats().expect("heartbeats");
    assert_eq!(beats.len(), 2);
    assert_eq!((beats[0].sequence, beats[1].sequence, beats[1].outputs), (3, 2, 5));
    assert!(beats[1].is_alive(Duration::from_secs(3)));
}

#[test]
fn bad_domains_are_refused_with_a_clear_error() {
    let err = Client::connect("Not/A/Domain").expect_err("refused");
    assert!(err.to_string().contains("Not/A/Domain"), "{err}");
}
