//! The ROS 2 bridge: a ROS 2 camera driver feeds the pipeline, ROS 2 nodes get
//! its results.
//!
//! - In (DDS to shared memory): `sensor_msgs/Image` with the latest
//!   `sensor_msgs/CameraInfo` becomes a frame on [`service::FRAMES`],
//!   `sensor_msgs/PointCloud2` a cloud on [`service::CLOUDS`]; capture times are
//!   the messages' header stamps. These run on a thread of their own that waits
//!   on the subscriptions' async streams and has its own iceoryx2 node
//!   (iceoryx2 ports stay on the thread that made them).
//! - Out (shared memory to DDS), on the service's WaitSet: each
//!   [`service::HOLE_POSES`] message becomes a `geometry_msgs/PoseArray`, a
//!   `geometry_msgs/PoseStamped`, a `tf2_msgs/TFMessage` and a
//!   `vision_msgs/Detection3DArray`, whose scores come from the same frame's
//!   [`service::DETECTIONS`] message (read, with no notification, before each
//!   pose), and a `visualization_msgs/MarkerArray` with the wall plane
//!   ([`service::PLANES`], the one closest in time within the pose service's
//!   `max_plane_age_ms`, read with no notification before each pose); at each
//!   heartbeat tick the services' heartbeats ([`service::HEARTBEAT`], which
//!   carry no notification) become one `diagnostic_msgs/DiagnosticArray`.
//! - The debug image, only while a ROS 2 reader subscribes to it (asked of DDS
//!   discovery at most every half second): the frames ([`service::FRAMES`],
//!   whatever their source) are copied as they are read, at each detection
//!   ([`service::DETECTIONS`], whose notification wakes the bridge), and each
//!   is drawn with its detection and hole poses
//!   ([`outlet_ros2_bridge::debug_image::DebugImages`]), then encoded (JPEG)
//!   and published on a thread of its own, so that the poses never wait for
//!   it. With no such reader no frame is read and nothing is drawn or
//!   encoded: a detection's notification costs a wake-up.
//!
//! The heartbeat ("ros2-bridge") counts every ROS 2 message and hole-pose
//! message in as an input, every frame, cloud and pose pair out as an output, and
//! each message that does not fit as rejected (with a warning saying why). Its
//! latency is the inbound one: a message's header stamp to its frame or cloud
//! being in shared memory (the DDS transport and the bridge's work, when the
//! stamp is the publishing moment); pose outputs add no latency sample.

use super::{Runtime, clear};
use anyhow::{Context, Result};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use outlet::health::{Health, now_ns};
use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, FrameHeader, HolePosesMsg, SCHEMA_VERSION, WallPlaneMsg, service,
};
use outlet_ros2_bridge::convert::{self, Diagnostics};
use outlet_ros2_bridge::debug_image::{DebugImage, DebugImages};
use outlet_ros2_bridge::markers::RecentPlanes;
use outlet_ros2_bridge::perception::HoleScores;
use outlet_ros2_bridge::{Bridge, BridgeError, DebugPublisher, DebugSubscribers, Input, Inputs, Stop};
use std::sync::{Arc, Mutex, MutexGuard, mpsc};
use std::time::Instant;

/// Shared memory a frame or cloud of a VGA camera needs; larger ones grow it.
const VGA_BYTES: usize = 640 * 480 * 3;

fn lock(health: &Mutex<Health>) -> MutexGuard<'_, Health> {
    // A panic elsewhere while counting leaves the counters usable.
    health.lock().unwrap_or_else(|e| e.into_inner())
}

fn reject(health: &Mutex<Health>, reason: &str) {
    lock(health).rejected(reason);
    tracing::warn!("rejected: {reason}");
}

/// The debug images waiting for their thread: one. JPEG encoding takes
/// longer than a frame period at high resolutions; the poses never wait for
/// it, and a debug image that finds the thread busy is dropped.
const DEBUG_QUEUE: usize = 1;

/// The debug image thread and its queue. Dropping it ends the thread and
/// waits for it, so that the debug image's writers go before the bridge's
/// node (on every way out of [`run`], as it is made after the bridge).
struct DebugThread {
    queue: Option<mpsc::SyncSender<(DebugImage, DebugSubscribers)>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl DebugThread {
    /// Hands a debug image to the thread, or drops it when the thread is busy.
    fn send(&self, image: DebugImage, to: DebugSubscribers) {
        let Some(queue) = &self.queue else { return };
        match queue.try_send((image, to)) {
            Ok(()) => {}
            Err(mpsc::TrySendError::Full((image, _))) => {
                tracing::debug!("debug image of frame {} dropped: the last one is still being sent", image.frame_id)
            }
            Err(mpsc::TrySendError::Disconnected(_)) => tracing::warn!("the debug image thread ended"),
        }
    }
}

impl Drop for DebugThread {
    fn drop(&mut self) {
        self.queue.take();
        if let Some(thread) = self.thread.take()
            && thread.join().is_err()
        {
            tracing::warn!("the debug image thread panicked");
        }
    }
}

/// The debug image thread: encodes and publishes each image handed to it
/// until the queue's sender is dropped. One that cannot go (a reader too slow
/// to take it) is only logged: it is a view, the results went out already.
fn run_debug(publisher: DebugPublisher, queue: mpsc::Receiver<(DebugImage, DebugSubscribers)>) {
    for (image, to) in queue {
        let frame_id = image.frame_id;
        if let Err(e) = publisher.publish(image, to) {
            tracing::debug!("debug image of frame {frame_id} not sent: {e}");
        }
    }
}

/// Runs `f` with the asynchronous signals blocked on this thread, so that the
/// threads it starts (rustdds' event loop and discovery, the input thread)
/// inherit the block and every such signal reaches this thread, the WaitSet's,
/// alone. rustdds' event loop ends for good when a signal handler interrupts
/// its poll (and iceoryx2 installs handlers for SIGINT, SIGTERM, SIGCONT and
/// more); the WaitSet sees a termination request at once only when its own
/// wait is the one interrupted. Faults (SIGSEGV, ...) stay unblocked.
fn with_signals_blocked<T>(f: impl FnOnce() -> T) -> T {
    use nix::sys::signal::{SigSet, SigmaskHow, Signal};
    let mut set = SigSet::all();
    for fault in [
        Signal::SIGSEGV,
        Signal::SIGBUS,
        Signal::SIGILL,
        Signal::SIGFPE,
        Signal::SIGABRT,
        Signal::SIGTRAP,
        Signal::SIGSYS,
    ] {
        set.remove(fault);
    }
    let old = set.thread_swap_mask(SigmaskHow::SIG_BLOCK);
    let out = f();
    match old.map(|old| old.thread_set_mask()) {
        Ok(Ok(())) => {}
        Ok(Err(e)) | Err(e) => tracing::warn!("signal mask: {e}"),
    }
    out
}

pub fn run(rt: &Runtime) -> Result<()> {
    outlet_ros2_bridge::bridge::quiet_dds_logs();
    let config = &rt.config.ros2;
    let health = Arc::new(Mutex::new(Health::new(rt.name)));
    let (stop_handle, stop) = Stop::new();
    let (ready_tx, ready_rx) = mpsc::channel();
    let domain = rt.config.domain.clone();
    let input_health = Arc::clone(&health);
    let (debug_tx, debug_rx) = mpsc::sync_channel(DEBUG_QUEUE);
    let (bridge, input_thread, debug_thread) = with_signals_blocked(|| -> Result<_> {
        let mut bridge = Bridge::new(config).context("the ROS 2 node")?;
        let inputs = bridge.take_inputs().context("the ROS 2 subscriptions")?;
        let input_thread = std::thread::Builder::new()
            .name("ros2-inputs".into())
            .spawn(move || run_inputs(&domain, inputs, stop, &input_health, ready_tx))
            .context("starting the ROS 2 input thread")?;
        let debug_publisher = bridge.take_debug_publisher().context("the debug image publishers")?;
        let debug_thread = std::thread::Builder::new()
            .name("ros2-debug-image".into())
            .spawn(move || run_debug(debug_publisher, debug_rx))
            .context("starting the debug image thread")?;
        Ok((bridge, input_thread, debug_thread))
    })?;
    let debug_thread = DebugThread { queue: Some(debug_tx), thread: Some(debug_thread) };
    match ready_rx.recv() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => return Err(e.context("the ROS 2 input thread")),
        Err(_) => anyhow::bail!("the ROS 2 input thread ended before it was ready"),
    }

    let pose_sub = shm::messages::<HolePosesMsg>(&rt.node, service::HOLE_POSES)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("hole pose subscriber: {e:?}"))?;
    let pose_listener = rt.listener(service::HOLE_POSES)?;
    let detection_sub = shm::messages::<DetectionMsg>(&rt.node, service::DETECTIONS)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("detection subscriber: {e:?}"))?;
    let mut scores = HoleScores::default();
    let detection_listener = rt.listener(service::DETECTIONS)?;
    let plane_sub = shm::messages::<WallPlaneMsg>(&rt.node, service::PLANES)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("plane subscriber: {e:?}"))?;
    let mut planes = RecentPlanes::default();
    let max_plane_age_ms = rt.config.pose.max_plane_age_ms;
    let frame_sub =
        shm::frames(&rt.node)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("frame subscriber: {e:?}"))?;
    let mut debug = DebugImages::default();
    let beat_sub = shm::heartbeats(&rt.node)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("heartbeat subscriber: {e:?}"))?;
    let waitset = rt.waitset()?;
    let poses = waitset.attach_notification(&pose_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let detections = waitset.attach_notification(&detection_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    // Silent as `outlet status` has it: three periods and half a second.
    let silent_after_ns = (3 * rt.config.heartbeat_ms + 500) * 1_000_000;
    let mut diagnostics = Diagnostics::new(silent_after_ns, &rt.config.domain);
    let mut input_thread_ended = false;
    let topics = &config.topics;
    tracing::info!(
        "ros2-bridge ready: {} + {} -> {}, {} -> {}; {} -> {} + {} + {} + {} + {}; heartbeats -> {}; \
         debug image (while subscribed) -> {} + {}",
        topics.image,
        topics.camera_info,
        service::FRAMES,
        topics.points,
        service::CLOUDS,
        service::HOLE_POSES,
        topics.holes,
        topics.pose,
        topics.detections,
        topics.tf,
        topics.markers,
        topics.diagnostics,
        topics.debug_image,
        topics.debug_image_compressed
    );
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        // Who watches the debug image (DDS discovery, asked at most every half second).
        let watching = bridge.debug_subscribers();
        if !watching.any() && !debug.is_empty() {
            debug.clear();
        }
        if id.has_event_from(&tick) {
            rt.beat(&mut lock(&health));
            loop {
                match beat_sub.receive() {
                    Ok(Some(b)) => diagnostics.update(b.payload()),
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!("receiving heartbeats: {e:?}");
                        break;
                    }
                }
            }
            if !diagnostics.is_empty()
                && let Err(e) = bridge.publish_diagnostics(diagnostics.array(now_ns()))
            {
                tracing::warn!("{e}");
            }
            // A detection whose poses did not come in a whole period goes without.
            if watching.any()
                && let Some(image) = debug.tick()
            {
                debug_thread.send(image, watching);
            }
            if input_thread.is_finished() {
                input_thread_ended = true;
                return CallbackProgression::Stop;
            }
        }
        if id.has_event_from(&detections) {
            clear(&detection_listener);
        }
        // The detections of the poses about to be read came before them; with
        // someone watching, each also meets its frame (which came before it).
        if id.has_event_from(&poses) || (id.has_event_from(&detections) && watching.any()) {
            if watching.any() {
                loop {
                    match frame_sub.receive() {
                        Ok(Some(f)) => {
                            if let Err(r) = debug.add_frame(f.user_header(), f.payload()) {
                                tracing::debug!("debug image: frame {}: {r}", f.user_header().frame_id);
                            }
                        }
                        Ok(None) => break,
                        Err(e) => {
                            tracing::warn!("receiving frames: {e:?}");
                            break;
                        }
                    }
                }
            }
            loop {
                match detection_sub.receive() {
                    Ok(Some(d)) => {
                        scores.insert(d.payload());
                        if watching.any() {
                            for image in debug.detection(d.payload()) {
                                debug_thread.send(image, watching);
                            }
                        }
                    }
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!("receiving detections: {e:?}");
                        break;
                    }
                }
            }
        }
        if id.has_event_from(&poses) {
            clear(&pose_listener);
            loop {
                match plane_sub.receive() {
                    Ok(Some(p)) => planes.insert(*p.payload()),
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!("receiving wall planes: {e:?}");
                        break;
                    }
                }
            }
            loop {
                let sample = match pose_sub.receive() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!("receiving hole poses: {e:?}");
                        break;
                    }
                };
                let started = Instant::now();
                lock(&health).input();
                let msg = sample.payload();
                let hole_scores = scores.of(msg);
                if hole_scores.is_none() && msg.hole_count > 0 {
                    tracing::debug!("frame {}: its detection was not seen; the detections' scores are 0", msg.frame_id);
                }
                let plane = planes.nearest(msg.capture_time_ns, max_plane_age_ms);
                match bridge.publish_poses(msg, hole_scores, plane) {
                    // No latency sample: the heartbeat's latency is the inbound one.
                    Ok(()) => lock(&health).output(0, started.elapsed().as_secs_f64() * 1e3),
                    Err(BridgeError::Rejected(r)) => reject(&health, &r.to_string()),
                    Err(e) => tracing::warn!("{e}"),
                }
                if watching.any()
                    && let Some(image) = debug.poses(msg)
                {
                    debug_thread.send(image, watching);
                }
            }
        }
        CallbackProgression::Continue
    };
    let waited = super::run_until_stopped(&waitset, on_event);
    // The readers and the debug image's writers first, then the node and its DDS participant.
    stop_handle.stop();
    let joined = input_thread.join();
    drop(debug_thread);
    drop(bridge);
    rt.stopped(&lock(&health));
    waited?;
    match joined {
        Ok(Ok(())) if !input_thread_ended => Ok(()),
        Ok(Ok(())) => anyhow::bail!("the ROS 2 subscriptions ended"),
        Ok(Err(e)) => Err(e.context("the ROS 2 input thread")),
        Err(_) => anyhow::bail!("the ROS 2 input thread panicked"),
    }
}

/// The shared-memory ports of the input thread, on its own node.
struct InputPorts {
    frames: Publisher<ipc::Service, [u8], FrameHeader>,
    frame_note: Notifier<ipc::Service>,
    clouds: Publisher<ipc::Service, [f32], CloudHeader>,
    cloud_note: Notifier<ipc::Service>,
    // The ports above need their node alive.
    _node: Node<ipc::Service>,
}

impl InputPorts {
    fn open(domain: &str) -> Result<Self> {
        let node = shm::node(domain, "ros2-bridge-inputs")?;
        let frames = shm::frames(&node)?
            .publisher_builder()
            .initial_max_slice_len(VGA_BYTES)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| anyhow::anyhow!("frame publisher: {e:?}"))?;
        let clouds = shm::clouds(&node)?
            .publisher_builder()
            .initial_max_slice_len(VGA_BYTES)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| anyhow::anyhow!("cloud publisher: {e:?}"))?;
        let notifier = |name: &str| {
            shm::events(&node, name)?.notifier_builder().create().map_err(|e| anyhow::anyhow!("{name} notifier: {e:?}"))
        };
        let frame_note = notifier(service::FRAMES)?;
        let cloud_note = notifier(service::CLOUDS)?;
        Ok(Self { frames, frame_note, clouds, cloud_note, _node: node })
    }

    fn send_frame(&self, header: FrameHeader, pixels: &[u8]) -> Result<(), String> {
        let mut sample = self.frames.loan_slice_uninit(pixels.len()).map_err(|e| format!("frame: {e:?}"))?;
        *sample.user_header_mut() = header;
        sample.write_from_slice(pixels).send().map_err(|e| format!("frame: {e:?}"))?;
        if let Err(e) = self.frame_note.notify() {
            tracing::warn!("notifying frame readers: {e:?}");
        }
        Ok(())
    }

    fn send_cloud(&self, header: CloudHeader, xyz: &[f32]) -> Result<(), String> {
        let mut sample = self.clouds.loan_slice_uninit(xyz.len()).map_err(|e| format!("cloud: {e:?}"))?;
        *sample.user_header_mut() = header;
        sample.write_from_slice(xyz).send().map_err(|e| format!("cloud: {e:?}"))?;
        if let Err(e) = self.cloud_note.notify() {
            tracing::warn!("notifying cloud readers: {e:?}");
        }
        Ok(())
    }
}

/// The input thread: ROS 2 messages in, frames and clouds out, until `stop`.
fn run_inputs(
    domain: &str,
    inputs: Inputs,
    stop: Stop,
    health: &Mutex<Health>,
    ready: mpsc::Sender<Result<()>>,
) -> Result<()> {
    let ports = match InputPorts::open(domain) {
        Ok(p) => {
            let _ = ready.send(Ok(()));
            p
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return Ok(());
        }
    };
    let mut camera: Option<CameraModel> = None;
    let (mut frame_id, mut cloud_id) = (0u64, 0u64);
    inputs.run(stop, |input| {
        let started = Instant::now();
        lock(health).input();
        let sent = match input {
            Input::CameraInfo(info) => match convert::camera_of(&info) {
                Ok(c) => {
                    if camera != Some(c) {
                        tracing::info!(
                            "camera {}x{}, fx {:.1} fy {:.1} cx {:.1} cy {:.1}, distortion {:?}",
                            c.width,
                            c.height,
                            c.fx,
                            c.fy,
                            c.cx,
                            c.cy,
                            c.distortion
                        );
                    }
                    camera = Some(c);
                    return;
                }
                Err(r) => Err(r.to_string()),
            },
            Input::Image(image) => match convert::frame_of(&image, camera.as_ref(), frame_id + 1) {
                Ok((header, pixels)) => ports.send_frame(header, pixels).map(|()| {
                    frame_id += 1;
                    header.capture_time_ns
                }),
                Err(r) => Err(r.to_string()),
            },
            Input::Points(cloud) => match convert::xyz_of(&cloud) {
                Ok((capture_time_ns, xyz)) => {
                    let header = CloudHeader {
                        schema_version: SCHEMA_VERSION,
                        reserved: 0,
                        frame_id: cloud_id + 1,
                        capture_time_ns,
                        points: (xyz.len() / 3) as u64,
                    };
                    ports.send_cloud(header, &xyz).map(|()| {
                        cloud_id += 1;
                        capture_time_ns
                    })
                }
                Err(r) => Err(r.to_string()),
            },
            Input::Undecodable { topic, reason } => Err(format!("{topic}: a sample that does not decode: {reason}")),
        };
        match sent {
            Ok(capture_time_ns) => lock(health).output(capture_time_ns, started.elapsed().as_secs_f64() * 1e3),
            Err(reason) => reject(health, &reason),
        }
    });
    Ok(())
}
