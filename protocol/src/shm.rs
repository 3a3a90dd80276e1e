//! Opening the sidecar's iceoryx2 services, one way for every process, so that
//! every participant asks for the same buffer sizes and limits (iceoryx2 refuses
//! to open a service with settings it was not created with).
//!
//! A *domain* names one sidecar: its shared-memory files start with
//! `<domain>_`, so two sidecars (or two tests) on one machine never see each
//! other. Every segment iceoryx2 makes for a domain is readable and writable by
//! the owning user only, except its 4-byte node counter; see [`node`].

use crate::wire::{CloudHeader, FrameHeader, HeartbeatMsg, service};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use std::os::unix::fs::PermissionsExt;

/// The domain when none is configured.
pub const DEFAULT_DOMAIN: &str = "outlet";

/// Why shared memory could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum ShmError {
    #[error("domain {0:?}: use 1 to 32 characters of a-z, 0-9, '_' or '-'")]
    Domain(String),
    #[error("{what}: {detail}")]
    Iceoryx { what: String, detail: String },
}

fn err(what: impl Into<String>, e: impl std::fmt::Debug) -> ShmError {
    ShmError::Iceoryx { what: what.into(), detail: format!("{e:?}") }
}

/// The shared-memory file prefix of a domain.
pub fn prefix(domain: &str) -> Result<String, ShmError> {
    let ok = !domain.is_empty()
        && domain.len() <= 32
        && domain.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-');
    if ok { Ok(format!("{domain}_")) } else { Err(ShmError::Domain(domain.to_string())) }
}

/// The iceoryx2 configuration of `domain`: iceoryx2's defaults, not a global
/// iceoryx2 file (the domain is the configuration), with the domain's prefix.
pub fn config(domain: &str) -> Result<Config, ShmError> {
    let mut config = Config::default();
    let prefix = prefix(domain)?;
    config.global.prefix = FileName::new(prefix.as_bytes()).map_err(|e| err(format!("domain {domain:?}"), e))?;
    Ok(config)
}

/// A node in `domain`, named for the logs and `iox2 node list`. Creating it
/// removes what nodes killed in this domain left behind.
pub fn node(domain: &str, node_name: &str) -> Result<Node<ipc::Service>, ShmError> {
    let config = config(domain)?;
    let prefix = prefix(domain)?;
    let name = NodeName::new(node_name).map_err(|e| err(format!("node name {node_name:?}"), e))?;
    let node =
        NodeBuilder::new().name(&name).config(&config).create::<ipc::Service>().map_err(|e| err("iceoryx2 node", e))?;
    if !cfg!(feature = "shared-access") {
        restrict_node_counter(&prefix);
    }
    Ok(node)
}

/// iceoryx2 creates one segment per domain open to every user: a counter of
/// nodes. Everything else it makes is owner-only; make this owner-only too, so
/// that no other user can touch the domain. Shared access across users is a
/// build option (`outlet` built with `--features shm-shared-access`).
fn restrict_node_counter(prefix: &str) {
    for_node_counter(prefix, |path| {
        // Fails harmlessly when another user owns it: then it is theirs to restrict.
        let _ = std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600));
    });
}

/// Removes the node counter iceoryx2 keeps for `domain` after its last node is
/// gone: what a domain used once (a test's, a demo's) leaves otherwise.
pub fn remove_node_counter(domain: &str) {
    if let Ok(prefix) = prefix(domain) {
        for_node_counter(&prefix, |path| {
            let _ = std::fs::remove_file(path);
        });
    }
}

/// Nodes of `domain` that may still be running: alive, or whose state this
/// process cannot tell (dead nodes, which the next node cleans up, are not
/// counted).
pub fn nodes_not_dead(domain: &str) -> Result<usize, ShmError> {
    let config = config(domain)?;
    let mut count = 0;
    Node::<ipc::Service>::list(&config, |state| {
        if !matches!(state, NodeState::Dead(_)) {
            count += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("listing the domain's nodes", e))?;
    Ok(count)
}

/// Called by a process whose nodes of `domain` are all gone: when no node of
/// the domain may still run, removes iceoryx2's node counter, the one file a
/// domain otherwise keeps after its last service stops cleanly. A node that
/// starts meanwhile is unharmed: node ids also hold the process id and the
/// creation time, so a counter starting again from 0 repeats none.
pub fn remove_node_counter_if_last(domain: &str) {
    if matches!(nodes_not_dead(domain), Ok(0)) {
        remove_node_counter(domain);
    }
}

fn for_node_counter(prefix: &str, mut f: impl FnMut(&std::path::Path)) {
    let Ok(entries) = std::fs::read_dir("/dev/shm") else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(prefix) && name.ends_with(".global_mgmt") {
            f(&entry.path());
        }
    }
}

fn service_name(name: &str) -> Result<ServiceName, ShmError> {
    ServiceName::new(name).map_err(|e| err(format!("service name {name:?}"), e))
}

/// Frames: [`FrameHeader`] and pixel bytes. Readers keep at most two frames: a
/// slow reader skips to the newest rather than falling behind.
pub fn frames(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, [u8], FrameHeader>, ShmError> {
    node.service_builder(&service_name(service::FRAMES)?)
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .max_publishers(4)
        .max_subscribers(8)
        .subscriber_max_buffer_size(2)
        .open_or_create()
        .map_err(|e| err(service::FRAMES, e))
}

/// Stereo clouds: [`CloudHeader`] and x, y, z values.
pub fn clouds(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, [f32], CloudHeader>, ShmError> {
    node.service_builder(&service_name(service::CLOUDS)?)
        .publish_subscribe::<[f32]>()
        .user_header::<CloudHeader>()
        .max_publishers(4)
        .max_subscribers(8)
        .subscriber_max_buffer_size(2)
        .open_or_create()
        .map_err(|e| err(service::CLOUDS, e))
}

/// A service of fixed-size messages (planes, detections, hole poses, truth):
/// readers keep the last 16.
pub fn messages<T: std::fmt::Debug + ZeroCopySend + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<publish_subscribe::PortFactory<ipc::Service, T, ()>, ShmError> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .max_publishers(4)
        .max_subscribers(16)
        .subscriber_max_buffer_size(16)
        .open_or_create()
        .map_err(|e| err(name, e))
}

/// Heartbeats: one publisher per service, each keeping its last beat for
/// readers that join late.
pub fn heartbeats(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, HeartbeatMsg, ()>, ShmError> {
    node.service_builder(&service_name(service::HEARTBEAT)?)
        .publish_subscribe::<HeartbeatMsg>()
        .max_publishers(16)
        .max_subscribers(16)
        .history_size(1)
        .subscriber_max_buffer_size(32)
        .open_or_create()
        .map_err(|e| err(service::HEARTBEAT, e))
}

/// Configuration snapshots: postcard bytes, one publisher per service, the
/// last kept for readers that join late.
pub fn snapshots(
    node: &Node<ipc::Service>,
) -> Result<publish_subscribe::PortFactory<ipc::Service, [u8], ()>, ShmError> {
    node.service_builder(&service_name(service::CONFIG)?)
        .publish_subscribe::<[u8]>()
        .max_publishers(16)
        .max_subscribers(16)
        .history_size(1)
        .subscriber_max_buffer_size(32)
        .open_or_create()
        .map_err(|e| err(service::CONFIG, e))
}

/// The notifications that go with the service `name`: a publisher notifies
/// after each send so readers can sleep until then.
pub fn events(node: &Node<ipc::Service>, name: &str) -> Result<event::PortFactory<ipc::Service>, ShmError> {
    node.service_builder(&service_name(name)?)
        .event()
        .max_notifiers(16)
        .max_listeners(16)
        .open_or_create()
        .map_err(|e| err(format!("{name} events"), e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn domains_are_checked() {
        assert_eq!(prefix("outlet").ok().as_deref(), Some("outlet_"));
        assert!(prefix("").is_err());
        assert!(prefix("a/b").is_err());
        assert!(prefix("UPPER").is_err());
        assert!(prefix(&"x".repeat(33)).is_err());
    }
}
