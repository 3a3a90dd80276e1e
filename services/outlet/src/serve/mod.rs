//! `outlet serve`: the sidecar's services as processes on iceoryx2 shared memory.
//! Each waits on a WaitSet for its inputs' notifications and its heartbeat timer
//! (no polling) and keeps serving whatever arrives: a bad input is counted,
//! logged and dropped. SIGINT or SIGTERM ends a service cleanly.

mod camera_out;
mod detector;
mod files;
mod normal;
mod pose;
mod ros2_bridge;
mod sim_camera;
mod viewer;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use outlet::config::Config;
use outlet::health::Health;
use outlet_protocol::shm;
use outlet_protocol::wire::HeartbeatMsg;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Args, Debug)]
pub struct ServeArgs {
    /// A TOML configuration file (see `outlet.example.toml`); flags override it.
    #[arg(long, global = true)]
    pub config: Option<PathBuf>,
    /// The shared-memory domain (`domain` in the file).
    #[arg(long, global = true)]
    pub domain: Option<String>,
    /// Heartbeat period in ms (`heartbeat_ms`).
    #[arg(long, global = true)]
    pub heartbeat_ms: Option<u64>,
    #[command(subcommand)]
    pub service: Service,
}

#[derive(Subcommand, Debug)]
pub enum Service {
    /// The normal estimator: stereo clouds in, wall planes out.
    Normal {
        /// Depth noise of the stereo camera at 1 m, metres (`normal.sigma_at_1m`).
        #[arg(long)]
        sigma_at_1m: Option<f64>,
    },
    /// The detector: camera frames in, detections out.
    Detector {
        /// `2x1`, `2x2` or a file written by `outlet train` (`detector.template`).
        #[arg(long)]
        template: Option<String>,
    },
    /// The pose service: detections and wall planes in, hole poses out.
    Pose {
        /// The detector's template, for its hole geometry (`pose.template`).
        #[arg(long)]
        template: Option<String>,
        /// A plane further in time from a detection is not used, ms (`pose.max_plane_age_ms`).
        #[arg(long)]
        max_plane_age_ms: Option<f64>,
    },
    /// The renderer as a camera: frames and stereo clouds at a rate, the truth on a side channel.
    SimCamera(SimCameraArgs),
    /// Photographs as a camera: PNG or JPEG files (and stereo clouds) at a rate, in sorted order.
    Files(files::FilesArgs),
    /// The live view: frames, holes, poses, the wall and every service's health on a
    /// Foxglove WebSocket server (open Foxglove, connect to ws://HOST:PORT).
    Viewer {
        /// The address to listen on; 0.0.0.0 lets other machines connect.
        #[arg(long, default_value = "127.0.0.1")]
        host: String,
        /// The port (Foxglove's default 8765; 0: any free one, printed at start).
        #[arg(long, default_value_t = 8765)]
        port: u16,
    },
    /// The ROS 2 bridge: images, camera info and clouds in from ROS 2, hole poses and diagnostics out.
    Ros2Bridge {
        /// The DDS domain id, ROS_DOMAIN_ID (`ros2.domain_id`).
        #[arg(long)]
        ros_domain_id: Option<u16>,
        /// A network interface DDS may use, by name or IPv4 address; repeatable (`ros2.interfaces`).
        #[arg(long = "interface")]
        interfaces: Vec<String>,
    },
}

#[derive(Args, Debug, Default, Clone)]
pub struct SimCameraArgs {
    /// Frames per second (`sim_camera.rate_hz`).
    #[arg(long)]
    pub rate: Option<f64>,
    /// Scenario, as for `outlet render` (`sim_camera.scenario`).
    #[arg(long)]
    pub scenario: Option<String>,
    #[arg(long)]
    pub seed: Option<u64>,
    #[arg(long)]
    pub width: Option<u32>,
    #[arg(long)]
    pub height: Option<u32>,
    /// Render this many views once and replay them; 0 renders every frame (`sim_camera.views`).
    #[arg(long)]
    pub views: Option<u32>,
    /// Frames each scene is seen for, the camera approaching it; 1: a new scene every frame (`sim_camera.frames_per_scene`).
    #[arg(long)]
    pub frames_per_scene: Option<u32>,
    /// No stereo clouds.
    #[arg(long)]
    pub no_cloud: bool,
}

impl SimCameraArgs {
    pub fn apply(&self, config: &mut Config) {
        let sim = &mut config.sim_camera;
        if let Some(v) = self.rate {
            sim.rate_hz = v;
        }
        if let Some(v) = &self.scenario {
            sim.scenario = v.clone();
        }
        if let Some(v) = self.seed {
            sim.seed = v;
        }
        if let Some(v) = self.width {
            sim.width = v;
        }
        if let Some(v) = self.height {
            sim.height = v;
        }
        if let Some(v) = self.views {
            sim.views = v;
        }
        if let Some(v) = self.frames_per_scene {
            sim.frames_per_scene = v;
        }
        if self.no_cloud {
            sim.cloud = false;
        }
    }
}

pub fn serve(args: ServeArgs) -> Result<()> {
    let mut config = Config::load(args.config.as_deref())?;
    if let Some(d) = args.domain {
        config.domain = d;
    }
    if let Some(h) = args.heartbeat_ms {
        config.heartbeat_ms = h;
    }
    let name = match &args.service {
        Service::Normal { sigma_at_1m } => {
            if let Some(s) = sigma_at_1m {
                config.normal.sigma_at_1m = *s;
            }
            "normal"
        }
        Service::Detector { template } => {
            if let Some(t) = template {
                config.detector.template = t.clone();
            }
            "detector"
        }
        Service::Pose { template, max_plane_age_ms } => {
            if let Some(t) = template {
                config.pose.template = t.clone();
            }
            if let Some(a) = max_plane_age_ms {
                config.pose.max_plane_age_ms = *a;
            }
            "pose"
        }
        Service::SimCamera(sim) => {
            sim.apply(&mut config);
            "sim-camera"
        }
        Service::Files(_) => "files",
        Service::Viewer { .. } => "viewer",
        Service::Ros2Bridge { ros_domain_id, interfaces } => {
            if let Some(d) = ros_domain_id {
                config.ros2.domain_id = *d;
            }
            if !interfaces.is_empty() {
                config.ros2.interfaces = interfaces.clone();
            }
            "ros2-bridge"
        }
    };
    config.check().context("configuration")?;
    let domain = config.domain.clone();
    let runtime = Runtime::start(name, config)?;
    let result = match args.service {
        Service::Normal { .. } => normal::run(&runtime),
        Service::Detector { .. } => detector::run(&runtime),
        Service::Pose { .. } => pose::run(&runtime),
        Service::SimCamera(_) => sim_camera::run(&runtime),
        Service::Files(files) => files::run(&runtime, &files),
        Service::Viewer { host, port } => viewer::run(&runtime, &host, port),
        Service::Ros2Bridge { .. } => ros2_bridge::run(&runtime),
    };
    // The node goes first; the last service of the domain to stop leaves
    // nothing in /dev/shm behind it.
    drop(runtime);
    outlet_protocol::shm::remove_node_counter_if_last(&domain);
    result.with_context(|| format!("{name} service"))
}

/// What every service has: its node, configuration, heartbeat and counters.
pub struct Runtime {
    pub name: &'static str,
    pub node: Node<ipc::Service>,
    pub config: Config,
    heartbeat: Publisher<ipc::Service, HeartbeatMsg, ()>,
    // Kept alive so that late readers still get the snapshot from its history.
    _snapshot: Publisher<ipc::Service, [u8], ()>,
}

impl Runtime {
    fn start(name: &'static str, config: Config) -> Result<Self> {
        let node = shm::node(&config.domain, name)?;
        let heartbeat = shm::heartbeats(&node)?
            .publisher_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("heartbeat publisher: {e:?}"))?;
        let bytes = postcard::to_allocvec(&(name, &config))?;
        let snapshot = shm::snapshots(&node)?
            .publisher_builder()
            .initial_max_slice_len(bytes.len())
            .create()
            .map_err(|e| anyhow::anyhow!("configuration publisher: {e:?}"))?;
        match snapshot.loan_slice_uninit(bytes.len()) {
            Ok(s) => {
                if let Err(e) = s.write_from_slice(&bytes).send() {
                    tracing::warn!("publishing the configuration: {e:?}");
                }
            }
            Err(e) => tracing::warn!("publishing the configuration: {e:?}"),
        }
        tracing::info!(domain = %config.domain, "{name} starting");
        Ok(Self { name, node, config, heartbeat, _snapshot: snapshot })
    }

    pub fn heartbeat_period(&self) -> Duration {
        Duration::from_millis(self.config.heartbeat_ms)
    }

    /// Publishes the heartbeat of the period now ending.
    pub fn beat(&self, health: &mut Health) {
        let beat = health.beat();
        let sent = match self.heartbeat.loan_uninit() {
            Ok(s) => s.write_payload(beat).send().map(|_| ()).map_err(|e| format!("{e:?}")),
            Err(e) => Err(format!("{e:?}")),
        };
        if let Err(e) = sent {
            tracing::warn!("publishing the heartbeat: {e}");
        }
        tracing::debug!(
            inputs = beat.inputs,
            outputs = beat.outputs,
            rejected = beat.rejected,
            latency_p50_ms = beat.latency_p50_ms,
            "{} heartbeat",
            self.name
        );
    }

    /// A WaitSet that wakes on the heartbeat timer and ends on SIGINT or SIGTERM.
    pub fn waitset(&self) -> Result<WaitSet<ipc::Service>> {
        WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<ipc::Service>()
            .map_err(|e| anyhow::anyhow!("waitset: {e:?}"))
    }

    /// The listener woken by `service_name`'s publishers.
    pub fn listener(&self, service_name: &str) -> Result<Listener<ipc::Service>> {
        shm::events(&self.node, service_name)?
            .listener_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("{service_name} listener: {e:?}"))
    }

    pub fn stopped(&self, health: &Health) {
        let t = health.totals();
        tracing::info!(
            inputs = t.inputs,
            outputs = t.outputs,
            rejected = t.rejected,
            dropped = t.dropped,
            "{} stops",
            self.name
        );
    }
}

/// An output of fixed-size messages: a publisher and the notifier that wakes its readers.
pub struct Output<T: std::fmt::Debug + ZeroCopySend + 'static> {
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
}

impl<T: std::fmt::Debug + ZeroCopySend + 'static> Output<T> {
    pub fn open(runtime: &Runtime, service_name: &str) -> Result<Self> {
        let publisher = shm::messages::<T>(&runtime.node, service_name)?
            .publisher_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("{service_name} publisher: {e:?}"))?;
        Ok(Self { publisher, notifier: notifier(runtime, service_name)? })
    }

    /// Publishes and notifies; true when sent. A failure is logged, the service goes on.
    pub fn send(&self, msg: T) -> bool {
        let sent = match self.publisher.loan_uninit() {
            Ok(s) => s.write_payload(msg).send().map_err(|e| format!("{e:?}")),
            Err(e) => Err(format!("{e:?}")),
        };
        match sent {
            Ok(_) => {
                if let Err(e) = self.notifier.notify() {
                    tracing::warn!("notifying readers: {e:?}");
                }
                true
            }
            Err(e) => {
                tracing::warn!("publishing: {e}");
                false
            }
        }
    }
}

pub fn notifier(runtime: &Runtime, service_name: &str) -> Result<Notifier<ipc::Service>> {
    shm::events(&runtime.node, service_name)?
        .notifier_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("{service_name} notifier: {e:?}"))
}

/// Runs `waitset` until SIGINT or SIGTERM, or until `on_event` stops it. A
/// signal that only interrupts the wait (SIGCONT after Ctrl-Z and `fg`, SIGURG,
/// SIGWINCH) does not end a service: iceoryx2 reports every interrupted wait
/// alike, so the signal it recorded last is asked.
pub fn run_until_stopped(
    waitset: &WaitSet<ipc::Service>,
    mut on_event: impl FnMut(WaitSetAttachmentId<ipc::Service>) -> CallbackProgression,
) -> Result<()> {
    loop {
        match waitset.wait_and_process(&mut on_event) {
            Ok(iceoryx2::waitset::WaitSetRunResult::Interrupt) if !interrupted_to_stop() => continue,
            Ok(_) => return Ok(()),
            Err(e) => return Err(anyhow::anyhow!("waiting: {e:?}")),
        }
    }
}

/// Whether the signal that interrupted a wait asks the service to stop (SIGINT,
/// SIGTERM). Takes iceoryx2's record of the last signal.
pub fn interrupted_to_stop() -> bool {
    iceoryx2_bb_posix::signal::SignalHandler::termination_requested()
}

/// A subscriber of the fixed-size messages of `name` (as the readers of results take them).
pub fn subscriber<T: std::fmt::Debug + ZeroCopySend + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<Subscriber<ipc::Service, T, ()>> {
    shm::messages::<T>(node, name)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("{name}: {e:?}"))
}

/// Clears a listener's pending notifications (the samples are what count).
pub fn clear(listener: &Listener<ipc::Service>) {
    if let Err(e) = listener.try_wait(|_| {}) {
        tracing::warn!("clearing notifications: {e:?}");
    }
}

/// Takes every waiting sample and keeps the newest: a service that takes longer
/// than the input period works on the freshest input, the older ones are dropped.
pub fn newest<P, H>(
    subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, [P], H>,
    health: &mut Health,
) -> Option<iceoryx2::sample::Sample<ipc::Service, [P], H>>
where
    P: std::fmt::Debug + ZeroCopySend + 'static,
    H: std::fmt::Debug + ZeroCopySend + 'static,
{
    let mut newest = None;
    loop {
        match subscriber.receive() {
            Ok(Some(s)) => {
                health.input();
                if newest.replace(s).is_some() {
                    health.dropped(1);
                }
            }
            Ok(None) => return newest,
            Err(e) => {
                tracing::warn!("receiving: {e:?}");
                return newest;
            }
        }
    }
}
