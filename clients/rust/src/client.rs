//! [`Client`]: the subscriber to hole poses and heartbeats, and its builder.

use crate::error::{ClientError, Rejection};
use crate::types::{Heartbeat, HolePoses};
use iceoryx2::node::Node;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::service::ipc;
use outlet_protocol::shm;
use outlet_protocol::wire::{HeartbeatMsg, HolePosesMsg, service};
use std::collections::BTreeMap;
use std::time::{Duration, Instant, SystemTime};

/// The iceoryx2 node name a client uses unless told otherwise (it shows in
/// `iox2 node list`).
pub const DEFAULT_NODE_NAME: &str = "outlet-client";

/// The longest single wait on the listener: longer timeouts wait in steps of
/// this, as the socket timeout underneath cannot hold any `Duration`.
const MAX_WAIT_STEP: Duration = Duration::from_secs(3600);

/// Configures a [`Client`] before connecting: the domain and the node name.
///
/// ```no_run
/// # fn main() -> Result<(), outlet_client::ClientError> {
/// let client = outlet_client::Client::builder().domain("outlet").node_name("arm-controller").connect()?;
/// # Ok(())
/// # }
/// ```
#[derive(Debug, Clone)]
pub struct ClientBuilder {
    domain: String,
    node_name: String,
}

impl Default for ClientBuilder {
    fn default() -> Self {
        Self { domain: shm::DEFAULT_DOMAIN.to_string(), node_name: DEFAULT_NODE_NAME.to_string() }
    }
}

impl ClientBuilder {
    /// The sidecar to join ([`DEFAULT_DOMAIN`](crate::DEFAULT_DOMAIN) unless set):
    /// 1 to 32 characters of a-z, 0-9, `_` and `-`.
    pub fn domain(mut self, domain: &str) -> Self {
        self.domain = domain.to_string();
        self
    }

    /// The name of the client's iceoryx2 node ([`DEFAULT_NODE_NAME`] unless set).
    pub fn node_name(mut self, node_name: &str) -> Self {
        self.node_name = node_name.to_string();
        self
    }

    /// Creates the node, a subscriber to the hole poses and a listener for their
    /// notifications, and a subscriber to the heartbeats. The services are
    /// created if no sidecar runs yet, so a client may start before the sidecar.
    pub fn connect(self) -> Result<Client, ClientError> {
        let node = shm::node(&self.domain, &self.node_name)?;
        let poses = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?
            .subscriber_builder()
            .create()
            .map_err(|source| ClientError::Subscribe { service: service::HOLE_POSES, source })?;
        let poses_listener = shm::events(&node, service::HOLE_POSES)?
            .listener_builder()
            .create()
            .map_err(|source| ClientError::Listen { service: service::HOLE_POSES, source })?;
        let heartbeats = shm::heartbeats(&node)?
            .subscriber_builder()
            .create()
            .map_err(|source| ClientError::Subscribe { service: service::HEARTBEAT, source })?;
        Ok(Client {
            poses,
            poses_listener,
            heartbeats,
            _node: node,
            domain: self.domain,
            connected_at: SystemTime::now(),
            latest: None,
            results: 0,
            rejected: 0,
            last_rejection: None,
            beats: BTreeMap::new(),
            rejected_heartbeats: 0,
        })
    }
}

/// A reader of one sidecar's hole poses and heartbeats.
///
/// Not [`Send`]: iceoryx2's ports of this kind stay on the thread that made them.
pub struct Client {
    poses: Subscriber<ipc::Service, HolePosesMsg, ()>,
    poses_listener: Listener<ipc::Service>,
    heartbeats: Subscriber<ipc::Service, HeartbeatMsg, ()>,
    // Kept for the ports' lifetime; declared last so the ports drop first.
    _node: Node<ipc::Service>,
    domain: String,
    connected_at: SystemTime,
    latest: Option<HolePoses>,
    results: u64,
    rejected: u64,
    last_rejection: Option<Rejection>,
    beats: BTreeMap<String, Heartbeat>,
    rejected_heartbeats: u64,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client")
            .field("domain", &self.domain)
            .field("connected_at", &self.connected_at)
            .field("latest_frame", &self.latest.as_ref().map(|p| p.frame_id))
            .field("results", &self.results)
            .field("rejected", &self.rejected)
            .field("services", &self.beats.keys().collect::<Vec<_>>())
            .finish_non_exhaustive()
    }
}

impl Client {
    /// A builder, to set the node name as well as the domain.
    pub fn builder() -> ClientBuilder {
        ClientBuilder::default()
    }

    /// Joins the sidecar of `domain` (see [`ClientBuilder::connect`]).
    pub fn connect(domain: &str) -> Result<Self, ClientError> {
        Self::builder().domain(domain).connect()
    }

    /// Joins the sidecar of the default domain, [`DEFAULT_DOMAIN`](crate::DEFAULT_DOMAIN).
    pub fn connect_default() -> Result<Self, ClientError> {
        Self::builder().connect()
    }

    /// The domain this client joined.
    pub fn domain(&self) -> &str {
        &self.domain
    }

    /// When this client connected.
    pub fn connected_at(&self) -> SystemTime {
        self.connected_at
    }

    /// Blocks until a result arrives that this client has not returned yet, or
    /// until `timeout` passes (`Ok(None)`).
    ///
    /// Sleeps on the pose service's notifications (no polling). If several
    /// results are waiting, returns the newest (the last to arrive) and drops the
    /// older ones; every result it takes out is remembered for [`latest`](Self::latest).
    /// A message that fails its checks is counted in [`rejected`](Self::rejected)
    /// and does not end the wait.
    ///
    /// A zero `timeout` only looks at what is waiting. A signal the process
    /// handles ends the wait early with [`ClientError::Interrupted`].
    pub fn wait_next(&mut self, timeout: Duration) -> Result<Option<HolePoses>, ClientError> {
        let deadline = Instant::now().checked_add(timeout);
        loop {
            if let Some(newest) = self.drain_poses()? {
                return Ok(Some(newest));
            }
            let remaining = match deadline {
                Some(deadline) => deadline.saturating_duration_since(Instant::now()),
                None => MAX_WAIT_STEP, // a deadline too far to represent: wait for ever
            };
            if remaining.is_zero() {
                return Ok(None);
            }
            // Wakes on the first notification (or the timeout) and consumes all
            // pending ones; the loop then reads what they announced. A stale
            // notification (of a result `latest` already took) just loops once.
            match self.poses_listener.timed_wait(|_| {}, remaining.min(MAX_WAIT_STEP)) {
                Ok(_) => {}
                Err(ListenerWaitError::InterruptSignal) => return Err(ClientError::Interrupted),
                Err(source) => return Err(ClientError::Wait { service: service::HOLE_POSES, source }),
            }
        }
    }

    /// The newest result ever received (a clone), after taking out, without
    /// blocking, whatever is waiting. `None` until the first result arrives.
    ///
    /// The result may be old: check [`HolePoses::age`] before acting on it.
    pub fn latest(&mut self) -> Result<Option<HolePoses>, ClientError> {
        self.drain_poses()?;
        Ok(self.latest.clone())
    }

    /// When the newest result was received, `None` if none was yet. Reflects what
    /// [`wait_next`](Self::wait_next) and [`latest`](Self::latest) took out so far.
    pub fn last_result_at(&self) -> Option<SystemTime> {
        self.latest.as_ref().map(|p| p.received)
    }

    /// `Some(T)` when no result has been received for more than `max_age`: `T` is
    /// when the newest result was received, or when the client connected if none
    /// ever was. `None` while results are fresh.
    ///
    /// Like [`last_result_at`](Self::last_result_at) it reflects what was taken
    /// out so far: call it after [`wait_next`](Self::wait_next) or [`latest`](Self::latest).
    pub fn no_result_since(&self, max_age: Duration) -> Option<SystemTime> {
        self.no_result_since_at(SystemTime::now(), max_age)
    }

    /// [`no_result_since`](Self::no_result_since) at the time `now`.
    pub fn no_result_since_at(&self, now: SystemTime, max_age: Duration) -> Option<SystemTime> {
        let since = self.last_result_at().unwrap_or(self.connected_at);
        now.duration_since(since).is_ok_and(|silence| silence > max_age).then_some(since)
    }

    /// How many valid results this client has received.
    pub fn results(&self) -> u64 {
        self.results
    }

    /// How many hole-pose messages this client refused (wrong schema version,
    /// too many holes, non-finite values, unknown codes).
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    /// Why the last refused hole-pose message was refused.
    pub fn last_rejection(&self) -> Option<&Rejection> {
        self.last_rejection.as_ref()
    }

    /// How many heartbeats this client refused (wrong schema version).
    pub fn rejected_heartbeats(&self) -> u64 {
        self.rejected_heartbeats
    }

    /// The latest heartbeat of every service heard from since connecting, by
    /// service name (sorted), after taking out without blocking whatever is
    /// waiting. A service that stopped stays in the list with its last
    /// heartbeat: see [`Heartbeat::is_alive`].
    pub fn heartbeats(&mut self) -> Result<Vec<Heartbeat>, ClientError> {
        loop {
            let msg = match self.heartbeats.receive() {
                Ok(Some(sample)) => *sample.payload(),
                Ok(None) => break,
                Err(source) => return Err(ClientError::Receive { service: service::HEARTBEAT, source }),
            };
            match Heartbeat::from_msg(&msg, SystemTime::now()) {
                Ok(beat) => {
                    self.beats.insert(beat.service.clone(), beat);
                }
                Err(_) => self.rejected_heartbeats += 1,
            }
        }
        Ok(self.beats.values().cloned().collect())
    }

    /// Takes out every waiting hole-pose message; the newest valid one, if any.
    fn drain_poses(&mut self) -> Result<Option<HolePoses>, ClientError> {
        let mut newest = None;
        loop {
            // Copy the message out of shared memory and release the sample at once.
            let msg = match self.poses.receive() {
                Ok(Some(sample)) => *sample.payload(),
                Ok(None) => break,
                Err(source) => return Err(ClientError::Receive { service: service::HOLE_POSES, source }),
            };
            match HolePoses::from_msg(&msg, SystemTime::now()) {
                Ok(poses) => {
                    self.results += 1;
                    self.latest = Some(poses.clone());
                    newest = Some(poses);
                }
                Err(rejection) => {
                    self.rejected += 1;
                    self.last_rejection = Some(rejection);
                }
            }
        }
        Ok(newest)
    }
}
