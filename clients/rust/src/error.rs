//! What can go wrong: [`ClientError`] when the client cannot do what was asked,
//! [`Rejection`] when a message from shared memory is not one to trust.

use iceoryx2::port::ReceiveError;
use iceoryx2::port::listener::{ListenerCreateError, ListenerWaitError};
use iceoryx2::port::subscriber::SubscriberCreateError;
use outlet_protocol::shm::ShmError;
use outlet_protocol::wire::WireError;

/// Why a [`Client`](crate::Client) call failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// The domain is invalid, or iceoryx2 could not create the node or open a
    /// service (for example one created with other settings or another schema).
    #[error("setting up shared memory: {0}")]
    Shm(#[from] ShmError),
    /// A subscriber to `service` could not be created.
    #[error("subscribing to {service}: {source}")]
    Subscribe {
        /// The service name.
        service: &'static str,
        /// What iceoryx2 said.
        source: SubscriberCreateError,
    },
    /// A listener for the notifications of `service` could not be created.
    #[error("listening for notifications of {service}: {source}")]
    Listen {
        /// The service name.
        service: &'static str,
        /// What iceoryx2 said.
        source: ListenerCreateError,
    },
    /// Receiving a sample of `service` failed.
    #[error("receiving from {service}: {source}")]
    Receive {
        /// The service name.
        service: &'static str,
        /// What iceoryx2 said.
        source: ReceiveError,
    },
    /// Waiting for the notifications of `service` failed.
    #[error("waiting for notifications of {service}: {source}")]
    Wait {
        /// The service name.
        service: &'static str,
        /// What iceoryx2 said.
        source: ListenerWaitError,
    },
    /// A signal handled by the process (Ctrl-C or SIGTERM where iceoryx2 captures
    /// them) interrupted the wait. Nothing is lost: call again to go on waiting,
    /// or stop.
    #[error("interrupted by a signal while waiting for hole poses")]
    Interrupted,
}

/// Why a message read from shared memory was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Rejection {
    /// The message's own check ([`HolePosesMsg::validate`](outlet_protocol::wire::HolePosesMsg::validate)):
    /// schema version, hole count, finite positions.
    #[error("{0}")]
    Wire(String),
    /// The pose mode code is none of 1 (mono), 2 (normal), 3 (plane).
    #[error("result for frame {frame_id}: unknown pose mode code {code}")]
    UnknownMode {
        /// The frame the result is for.
        frame_id: u64,
        /// The code found.
        code: u32,
    },
    /// A hole's kind code is neither 1 (power) nor 2 (ground).
    #[error("result for frame {frame_id}: hole {index} has unknown kind code {code}")]
    UnknownHoleKind {
        /// The frame the result is for.
        frame_id: u64,
        /// The hole's index in the message.
        index: usize,
        /// The code found.
        code: u32,
    },
    /// The outlet's rotation or translation has a NaN or infinite value.
    #[error("result for frame {frame_id}: the outlet pose is not finite")]
    PoseNotFinite {
        /// The frame the result is for.
        frame_id: u64,
    },
}

impl From<WireError> for Rejection {
    fn from(e: WireError) -> Self {
        Rejection::Wire(e.to_string())
    }
}
