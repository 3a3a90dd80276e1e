//! What the C tests share: a unique domain and a stand-in for the pose service.

use outlet_protocol::shm;
use outlet_protocol::wire::{HolePosesMsg, MAX_HOLES, SCHEMA_VERSION, service};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

type Ipc = iceoryx2::service::ipc::Service;

/// A domain no other test (or test run) uses. Bind it first in a test so that it
/// drops last, after every node of the domain.
pub struct Domain(pub String);

pub fn unique_domain() -> Domain {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    Domain(format!("clientc{}_{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)))
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

pub fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// What the pose service does: publish a [`HolePosesMsg`], then notify.
pub struct PoseService {
    publisher: iceoryx2::port::publisher::Publisher<Ipc, HolePosesMsg, ()>,
    notifier: iceoryx2::port::notifier::Notifier<Ipc>,
    _node: iceoryx2::node::Node<Ipc>,
}

impl PoseService {
    pub fn open(domain: &Domain) -> Self {
        let node = shm::node(&domain.0, "test-pose").expect("node");
        let publisher = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)
            .expect("hole poses service")
            .publisher_builder()
            .create()
            .expect("publisher");
        let notifier =
            shm::events(&node, service::HOLE_POSES).expect("events").notifier_builder().create().expect("notifier");
        Self { publisher, notifier, _node: node }
    }

    pub fn send(&self, msg: HolePosesMsg) {
        self.publisher.send_copy(msg).expect("send");
        self.notifier.notify().expect("notify");
    }
}

/// The positions [`poses`] gives a 2x1's holes: power, power, ground.
pub const POSITIONS_M: [[f64; 3]; 3] = [[0.0127, -0.02, 0.3125], [-0.0127, -0.02, 0.3131], [0.0, 0.0213, 0.3102]];

/// A result for a 2x1 at [`POSITIONS_M`], plane mode.
pub fn poses(frame_id: u64) -> HolePosesMsg {
    let mut m = HolePosesMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 3,
        frame_id,
        capture_time_ns: now_ns() - 30_000_000,
        published_ns: now_ns(),
        mode: 3,
        status: 1,
        outlier_mask: 0,
        reserved: 0,
        rotation: [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0],
        translation_m: [0.0, 0.0, 0.31],
        kinds: [0; MAX_HOLES],
        positions_m: [[0.0; 3]; MAX_HOLES],
        covariances_m2: [[0.0; 9]; MAX_HOLES],
    };
    for (k, (kind, position)) in [1, 1, 2].into_iter().zip(POSITIONS_M).enumerate() {
        m.kinds[k] = kind;
        m.positions_m[k] = position;
        m.covariances_m2[k] = [1e-8, 2e-9, 0.0, 2e-9, 1e-8, 0.0, 0.0, 0.0, 4e-8];
    }
    m
}
