//! The arm controller's view of the outlet sidecar: hole poses as they are
//! published, and the health of every service, read from iceoryx2 shared memory.
//!
//! A [`Client`] joins one sidecar (a *domain*, see [`outlet_protocol::shm`]) and
//! reads two services of it:
//!
//! - the pose service's results ([`outlet_protocol::wire::service::HOLE_POSES`]):
//!   [`Client::wait_next`] sleeps on the service's notifications until a new
//!   result arrives, [`Client::latest`] returns the newest without blocking;
//!   every result is checked ([`HolePoses::from_msg`]) and one that fails is
//!   counted ([`Client::rejected`]) and dropped, never trusted;
//! - the heartbeats every service publishes about once a second
//!   ([`Client::heartbeats`], [`Heartbeat::is_alive`]).
//!
//! Every [`HolePoses`] carries the capture time of its frame, the time the pose
//! service published it and the time this client received it, so a controller
//! can refuse stale data ([`HolePoses::age`]) and tell "no result since T"
//! ([`Client::no_result_since`]).
//!
//! # Example
//!
//! ```no_run
//! use std::time::Duration;
//! use outlet_client::{Client, ClientError, HoleKind};
//!
//! fn main() -> Result<(), ClientError> {
//!     let mut client = Client::connect("outlet")?;
//!     loop {
//!         match client.wait_next(Duration::from_secs(1))? {
//!             // Ambiguous or plane mismatch: no pose this frame, and why.
//!             Some(poses) if !poses.is_usable() => {
//!                 println!("frame {}: no pose ({})", poses.frame_id, poses.status.as_str())
//!             }
//!             Some(poses) if poses.age() < Duration::from_millis(200) => {
//!                 for hole in poses.holes.iter().filter(|h| h.kind == HoleKind::Power) {
//!                     let [x, y, z] = hole.position_m;
//!                     println!("frame {}: power hole at ({x:.4}, {y:.4}, {z:.4}) m", poses.frame_id);
//!                 }
//!             }
//!             Some(poses) => println!("frame {} is {:?} old: not used", poses.frame_id, poses.age()),
//!             None => {
//!                 if let Some(since) = client.no_result_since(Duration::from_secs(1)) {
//!                     println!("no result since {since:?}");
//!                 }
//!             }
//!         }
//!     }
//! }
//! ```
//!
//! # Threads
//!
//! A [`Client`] uses iceoryx2's single-threaded ports: it is not [`Send`], so it
//! lives on the thread that connected it. Connect one client per thread if
//! several threads need results.
//!
//! # What a result means
//!
//! Every result carries a [`PoseStatus`]:
//!
//! - [`PoseStatus::Ok`]: each hole's position with a covariance meant to hold:
//!   over rendered scenes the normalised error `e^T C^-1 e` of a hole is
//!   checked against chi-square with 3 degrees of freedom (BENCHMARKS.md,
//!   "Honest covariances"). A hole marked [`Hole::outlier`] was not seen where the
//!   others put it; its position comes from them.
//! - [`PoseStatus::Ambiguous`]: from the pixels alone (mode mono, no stereo
//!   plane) two mirror-image poses explain the holes about equally; no holes.
//! - [`PoseStatus::PlaneMismatch`]: the wall plane from stereo cannot explain
//!   the detected holes; no holes. The sidecar does not fall back to a pose from
//!   the pixels alone, which in that case was seen to be centimetres off.
//!
//! A result without a pose is still a result: [`Client::no_result_since`] and
//! [`HolePoses::age`] count it, so a controller can tell "the sidecar sees the
//! outlet but cannot vouch for it" from "nothing".
//!
//! Frames and units: positions are in the camera frame of `CONTRACT.md` (x
//! right, y down, z forward), in metres; covariances in square metres.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod client;
mod error;
mod types;

pub use client::{Client, ClientBuilder, DEFAULT_NODE_NAME};
pub use error::{ClientError, Rejection};
pub use outlet_protocol::HoleKind;
pub use outlet_protocol::shm::DEFAULT_DOMAIN;
pub use types::{FaceErrors, Heartbeat, Hole, HolePoses, PoseMode, PoseStatus};
