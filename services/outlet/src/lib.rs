//! What the `outlet` command shares with other programs and tests: the built-in
//! templates (trained from rendered views), the sidecar's configuration, and the
//! counters behind each service's heartbeat.

pub mod config;
pub mod health;
pub mod templates;
