//! The DDS side of the bridge: one ros2-client node on a rustdds
//! DomainParticipant that uses only the configured network interfaces.
//!
//! # Confining DDS to some interfaces (rustdds 0.15)
//!
//! [`DomainParticipantBuilder::with_only_networks`] takes the IP addresses of
//! the interfaces DDS may use. With `[ros2] interfaces = ["lo"]` that is
//! 127.0.0.1, and then (read from rustdds 0.15.1's sources):
//! - the participant advertises unicast locators on 127.0.0.1 only (SPDP and
//!   SEDP), so peers send to loopback only;
//! - multicast is joined and sent only on the listed interfaces that are
//!   multicast-capable. Linux's `lo` is not (no MULTICAST flag), so no
//!   multicast socket is made at all: no multicast leaves the machine, and none
//!   goes anywhere;
//! - discovery then runs on "same-host loopback" (`same_host_loopback(true)`,
//!   rustdds' default, set here explicitly): SPDP goes unicast to
//!   127.0.0.1 at the well-known discovery ports of participant ids 0..12
//!   (7400 + 250 x domain + 10 + 2 x id, the RTPS port mapping), and a peer
//!   whose packets come from a loopback address is answered on its loopback
//!   locator. Cyclone DDS with `AllowMulticast=false` and
//!   `Peers=127.0.0.1` sends its SPDP to the same ports of participant indices
//!   0..MaxAutoParticipantIndex, and rustdds listens on the first free one of
//!   them, so each finds the other with no multicast at all.
//!
//! It is not a firewall: rustdds' unicast sockets are bound to 0.0.0.0 (a
//! datagram sent to another address of the machine is still read), but nothing
//! tells any peer elsewhere where to send, and this participant sends only to
//! the locators peers advertise. Checked on the test machine: tcpdump on eth0
//! saw no UDP (nor IGMP) packet while the loopback tests and the Cyclone DDS
//! interop test ran, and on `lo` the whole exchange. Empty `interfaces` is
//! rustdds' default: every interface, multicast discovery on 239.255.0.1.

use crate::Ros2Config;
use crate::convert::{self, Rejection};
use crate::debug_image::{DebugImage, JPEG_QUALITY};
use crate::markers;
use crate::msgs::{
    CameraInfo, CompressedImage, Detection3DArray, DiagnosticArray, Image, MarkerArray, PointCloud2, PoseArray,
    PoseStamped, RosMessage, TFMessage,
};
use crate::perception;
use futures::StreamExt;
use futures::channel::oneshot;
use outlet_protocol::wire::{HolePosesMsg, MAX_HOLES, WallPlaneMsg};
use ros2_client::dds::rustdds::{DomainParticipant, DomainParticipantBuilder, TopicDescription};
use ros2_client::dds::{Context, Node, Publisher, Subscription};
use ros2_client::qos::{History, WhenFull};
use ros2_client::{Name, NodeName, NodeOptions, QosProfile};
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Why the bridge could not be set up, or a message not sent.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error("network interface {name:?}: {reason}")]
    Interface { name: String, reason: String },
    #[error("{what}: {detail}")]
    Dds { what: String, detail: String },
    #[error(transparent)]
    Rejected(#[from] Rejection),
}

fn dds(what: impl Into<String>, e: impl std::fmt::Debug) -> BridgeError {
    BridgeError::Dds { what: what.into(), detail: format!("{e:?}") }
}

/// What camera drivers publish with ("sensor data"): best-effort, volatile,
/// the last 5. A best-effort reader matches best-effort and reliable writers,
/// volatile and transient-local ones alike, so every input uses it (camera
/// info included: drivers often publish it best-effort too).
pub const SENSOR_QOS: QosProfile = QosProfile::subscription_default().history(History::KeepLast { depth: 5 });

/// The outputs: reliable, volatile, the last 10. A `publish` waits at most
/// 20 ms for a full send window (a reader that stopped acknowledging).
pub const RESULT_QOS: QosProfile = QosProfile::publisher_default()
    .reliability_reliable(WhenFull::Wait(Duration::from_millis(20)))
    .history(History::KeepLast { depth: 10 });

/// `/tf`: reliable, volatile, the last 100, as tf2_ros' TransformBroadcaster
/// (`DynamicBroadcasterQoS`) publishes it.
pub const TF_QOS: QosProfile = QosProfile::publisher_default()
    .reliability_reliable(WhenFull::Wait(Duration::from_millis(20)))
    .history(History::KeepLast { depth: 100 });

/// The debug images: reliable (so that reliable and best-effort readers
/// match), volatile, the last 2. A reader that stops acknowledging holds a
/// publish for at most 20 ms, then that image is dropped.
pub const DEBUG_IMAGE_QOS: QosProfile = QosProfile::publisher_default()
    .reliability_reliable(WhenFull::Wait(Duration::from_millis(20)))
    .history(History::KeepLast { depth: 2 });

/// How long the answer to "does anyone subscribe to the debug image?" is
/// reused before DDS discovery is asked again.
pub const DEBUG_SUBSCRIBERS_CHECK: Duration = Duration::from_millis(500);

/// Keeps only the errors of rustdds' and ros2-client's logs (they log through
/// the `log` crate) unless RUST_LOG is set. On loopback only, rustdds 0.15
/// warns on every message its own participant sends itself ("No locators for
/// RtpsReaderProxy", tens a second): it matches itself as a remote
/// participant whose only locators are loopback ones, which it uses only for a
/// peer it has heard from a loopback address. Harmless, and too many to read.
pub fn quiet_dds_logs() {
    if std::env::var_os("RUST_LOG").is_none() {
        log::set_max_level(log::LevelFilter::Error);
    }
}

/// A ROS 2 topic name (`/camera/image_raw`), checked as ros2-client checks it.
pub fn topic_name(topic: &str) -> Result<Name, String> {
    Name::parse(topic).map_err(|e| format!("{topic:?} is not a ROS 2 topic name ({e})"))
}

/// The IPv4 addresses of `interfaces`, each a name (`lo`, `eth0`) or an
/// address of this machine (`127.0.0.1`).
pub fn interface_addresses(interfaces: &[String]) -> Result<Vec<IpAddr>, BridgeError> {
    let local = netdev::get_interfaces();
    let mut addresses = Vec::new();
    for name in interfaces {
        let found: Vec<IpAddr> = match name.parse::<IpAddr>() {
            Ok(ip) => {
                local.iter().flat_map(|i| i.ipv4.iter().map(|n| IpAddr::V4(n.addr()))).filter(|a| *a == ip).collect()
            }
            Err(_) => local
                .iter()
                .filter(|i| &i.name == name)
                .flat_map(|i| i.ipv4.iter().map(|n| IpAddr::V4(n.addr())))
                .collect(),
        };
        if found.is_empty() {
            let known: Vec<&str> = local.iter().map(|i| i.name.as_str()).collect();
            return Err(BridgeError::Interface {
                name: name.clone(),
                reason: format!(
                    "no such interface with an IPv4 address on this machine (rustdds speaks IPv4; interfaces: {})",
                    known.join(", ")
                ),
            });
        }
        addresses.extend(found);
    }
    addresses.dedup();
    Ok(addresses)
}

/// A rustdds DomainParticipant in `config.domain_id` on `config.interfaces`
/// only (every interface when empty); see the module's documentation.
pub fn participant(config: &Ros2Config) -> Result<DomainParticipant, BridgeError> {
    let mut builder = DomainParticipantBuilder::new(config.domain_id).same_host_loopback(true);
    if !config.interfaces.is_empty() {
        let addresses = interface_addresses(&config.interfaces)?;
        tracing::info!("DDS domain {} on {} only ({addresses:?})", config.domain_id, config.interfaces.join(", "));
        builder = builder.with_only_networks(addresses);
    } else {
        tracing::info!("DDS domain {} on every interface", config.domain_id);
    }
    builder.build().map_err(|e| dds(format!("DDS participant in domain {}", config.domain_id), e))
}

/// A ros2-client context on [`participant`].
pub fn context(config: &Ros2Config) -> Result<Context, BridgeError> {
    Context::from_domain_participant(participant(config)?).map_err(|e| dds("ROS 2 context", e))
}

/// A node named `name` in the root namespace, without rosout logging or
/// parameter services (the bridge has neither).
pub fn node(context: &Context, name: &str) -> Result<Node, BridgeError> {
    let node_name = NodeName::new("/", name).map_err(|e| dds(format!("node name {name:?}"), e))?;
    context
        .new_node(node_name, NodeOptions::new().enable_rosout(false).start_parameter_services(false))
        .map_err(|e| dds(format!("node {name}"), e))
}

/// A publisher of `M` on `topic`.
pub fn publisher<M: RosMessage>(node: &mut Node, topic: &str, qos: &QosProfile) -> Result<Publisher<M>, BridgeError> {
    publisher_on(node, topic, qos).map(|(p, _)| p)
}

/// [`publisher`], and the DDS topic it writes (`rt/outlet/debug_image`).
fn publisher_on<M: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<(Publisher<M>, DdsTopic), BridgeError> {
    let name = topic_name(topic).map_err(|e| dds("topic", e))?;
    let t = node.create_topic(&name, M::type_name(), qos).map_err(|e| dds(format!("topic {topic}"), e))?;
    let publisher =
        node.create_publisher(&t, Some(qos.clone())).map_err(|e| dds(format!("publisher on {topic}"), e))?;
    Ok((publisher, DdsTopic { name: t.name(), type_name: M::DDS_TYPE }))
}

/// A topic as DDS names it, with its type.
#[derive(Debug, Clone, PartialEq, Eq)]
struct DdsTopic {
    name: String,
    type_name: &'static str,
}

/// Readers that DDS discovery knows of on `topic` (in other participants, of
/// this process or elsewhere), of its type.
fn readers_of(participant: &DomainParticipant, topic: &DdsTopic) -> usize {
    participant
        .discovered_readers()
        .iter()
        .filter(|r| {
            let data = &r.subscription_topic_data;
            *data.topic_name() == topic.name && data.type_name() == topic.type_name
        })
        .count()
}

/// Who subscribes to the debug images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DebugSubscribers {
    /// The rgb8 Image.
    pub image: bool,
    /// The JPEG CompressedImage.
    pub compressed: bool,
}

impl DebugSubscribers {
    pub fn any(&self) -> bool {
        self.image || self.compressed
    }
}

/// A subscription to `M` on `topic`.
pub fn subscription<M: RosMessage>(
    node: &mut Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<Subscription<M>, BridgeError> {
    let name = topic_name(topic).map_err(|e| dds("topic", e))?;
    let t = node.create_topic(&name, M::type_name(), qos).map_err(|e| dds(format!("topic {topic}"), e))?;
    node.create_subscription(&t, Some(qos.clone())).map_err(|e| dds(format!("subscription to {topic}"), e))
}

/// The debug images' publishers ([`Bridge::take_debug_publisher`]).
pub struct DebugPublisher {
    image: Publisher<Image>,
    compressed: Publisher<CompressedImage>,
    frame_id: String,
}

impl DebugPublisher {
    /// Publishes a debug image on the topics `to` names: the rgb8 Image, a
    /// JPEG CompressedImage (encoded here, the cost: 8 to 20 ms a VGA frame),
    /// or both.
    pub fn publish(&self, image: DebugImage, to: DebugSubscribers) -> Result<(), BridgeError> {
        if to.compressed {
            let jpeg = image.to_jpeg(&self.frame_id, JPEG_QUALITY).map_err(|e| dds("encoding the debug image", e))?;
            self.compressed.publish(jpeg).map_err(|e| dds("publishing the compressed debug image", e))?;
        }
        if to.image {
            self.image.publish(image.into_image(&self.frame_id)).map_err(|e| dds("publishing the debug image", e))?;
        }
        Ok(())
    }
}

/// What came in from ROS 2.
#[derive(Debug)]
pub enum Input {
    Image(Image),
    /// Boxed: the largest message by far on the stack, and the rarest.
    CameraInfo(Box<CameraInfo>),
    Points(PointCloud2),
    /// A sample that did not decode as its type (`topic` is the configured key).
    Undecodable {
        topic: &'static str,
        reason: String,
    },
}

/// Ends [`Inputs::run`]: [`StopHandle::stop`], or dropping the handle.
pub struct Stop(oneshot::Receiver<()>);

/// The other end of a [`Stop`].
pub struct StopHandle(oneshot::Sender<()>);

impl Stop {
    pub fn new() -> (StopHandle, Stop) {
        let (tx, rx) = oneshot::channel();
        (StopHandle(tx), Stop(rx))
    }
}

impl StopHandle {
    pub fn stop(self) {
        // The receiver gone means the inputs ended already.
        let _ = self.0.send(());
    }
}

/// The subscriptions, to be run on a thread of their own ([`Inputs::run`]).
pub struct Inputs {
    image: Subscription<Image>,
    compressed: Subscription<CompressedImage>,
    camera_info: Subscription<CameraInfo>,
    points: Subscription<PointCloud2>,
}

impl Inputs {
    /// Hands each message to `on_input` as it arrives, until `stop`. It waits
    /// on the subscriptions' async streams (woken by rustdds' event loop, no
    /// polling) in a single-threaded executor.
    pub fn run(self, stop: Stop, mut on_input: impl FnMut(Input)) {
        let Inputs { image, compressed, camera_info, points } = self;
        futures::executor::block_on(async move {
            let images = image.async_stream();
            let compressed = compressed.async_stream();
            let infos = camera_info.async_stream();
            let clouds = points.async_stream();
            futures::pin_mut!(images, compressed, infos, clouds);
            let mut stop = stop.0;
            let undecodable =
                |topic: &'static str, e: ros2_client::ReadError| Input::Undecodable { topic, reason: format!("{e:?}") };
            loop {
                futures::select! {
                    m = images.next() => match m {
                        Some(Ok((msg, _))) => on_input(Input::Image(msg)),
                        Some(Err(e)) => on_input(undecodable("image", e)),
                        None => break,
                    },
                    // Decoded here, on the inputs' thread: the image path
                    // downstream is the same as for a raw image.
                    m = compressed.next() => match m {
                        Some(Ok((msg, _))) => match crate::convert::image_of_compressed(&msg) {
                            Ok(image) => on_input(Input::Image(image)),
                            Err(e) => on_input(Input::Undecodable { topic: "image_compressed", reason: e.to_string() }),
                        },
                        Some(Err(e)) => on_input(undecodable("image_compressed", e)),
                        None => break,
                    },
                    m = infos.next() => match m {
                        Some(Ok((msg, _))) => on_input(Input::CameraInfo(Box::new(msg))),
                        Some(Err(e)) => on_input(undecodable("camera_info", e)),
                        None => break,
                    },
                    m = clouds.next() => match m {
                        Some(Ok((msg, _))) => on_input(Input::Points(msg)),
                        Some(Err(e)) => on_input(undecodable("points", e)),
                        None => break,
                    },
                    _ = stop => break,
                    complete => break,
                }
            }
        });
    }
}

/// The bridge's ROS 2 node: its inputs (taken once, to run on their own
/// thread), its publishers, and the debug images' publishers (taken once, to
/// run on another thread). To end, stop the inputs and drop the debug
/// publisher, then drop the bridge (the DDS participant goes last, after
/// every reader and writer).
///
/// The node runs no ros2-client spinner: the bridge needs none of what it
/// serves (parameters, simulated time, graph events). The node is still
/// announced on `ros_discovery_info` (by its context), so `ros2 node list`
/// shows `/outlet_ros2_bridge`.
pub struct Bridge {
    holes: Publisher<PoseArray>,
    pose: Publisher<PoseStamped>,
    detections: Publisher<Detection3DArray>,
    tf: Publisher<TFMessage>,
    diagnostics: Publisher<DiagnosticArray>,
    markers: Publisher<MarkerArray>,
    debug: Option<DebugPublisher>,
    debug_topics: [DdsTopic; 2],
    /// The last answer of [`Bridge::debug_subscribers`] and when it was asked.
    debug_subscribers: Mutex<Option<(Instant, DebugSubscribers)>>,
    inputs: Option<Inputs>,
    frame_id: String,
    outlet_frame: String,
    hole_frames: bool,
    // Dropped after the publishers and subscriptions: the node, then the participant.
    _node: Node,
    context: Context,
}

impl Bridge {
    /// The node `outlet_ros2_bridge` with its subscriptions and publishers, on
    /// the configured domain and interfaces.
    pub fn new(config: &Ros2Config) -> Result<Self, BridgeError> {
        let context = context(config)?;
        let mut node = node(&context, "outlet_ros2_bridge")?;
        let topics = &config.topics;
        let inputs = Inputs {
            image: subscription(&mut node, &topics.image, &SENSOR_QOS)?,
            compressed: subscription(&mut node, &topics.image_compressed, &SENSOR_QOS)?,
            camera_info: subscription(&mut node, &topics.camera_info, &SENSOR_QOS)?,
            points: subscription(&mut node, &topics.points, &SENSOR_QOS)?,
        };
        let (debug_image, image_topic) = publisher_on(&mut node, &topics.debug_image, &DEBUG_IMAGE_QOS)?;
        let (debug_compressed, compressed_topic) =
            publisher_on(&mut node, &topics.debug_image_compressed, &DEBUG_IMAGE_QOS)?;
        Ok(Self {
            holes: publisher(&mut node, &topics.holes, &RESULT_QOS)?,
            pose: publisher(&mut node, &topics.pose, &RESULT_QOS)?,
            detections: publisher(&mut node, &topics.detections, &RESULT_QOS)?,
            tf: publisher(&mut node, &topics.tf, &TF_QOS)?,
            diagnostics: publisher(&mut node, &topics.diagnostics, &RESULT_QOS)?,
            markers: publisher(&mut node, &topics.markers, &RESULT_QOS)?,
            debug: Some(DebugPublisher {
                image: debug_image,
                compressed: debug_compressed,
                frame_id: config.frame_id.clone(),
            }),
            debug_topics: [image_topic, compressed_topic],
            debug_subscribers: Mutex::new(None),
            inputs: Some(inputs),
            frame_id: config.frame_id.clone(),
            outlet_frame: config.outlet_frame.clone(),
            hole_frames: config.hole_frames,
            _node: node,
            context,
        })
    }

    /// The subscriptions, once.
    pub fn take_inputs(&mut self) -> Option<Inputs> {
        self.inputs.take()
    }

    /// Publishes one frame's hole poses: a PoseArray on the holes topic, a
    /// PoseStamped on the pose topic, the outlet's (and the holes') transforms
    /// on tf, the holes as a Detection3DArray with `scores` (the detector's
    /// of each hole, from the same frame's detection; 0 where None), and the
    /// rviz markers ([`markers::markers_of`]) with the wall `plane` of the
    /// result's moment, if any. Nothing for a result without a pose
    /// ([`convert::Rejection::NoPose`]).
    pub fn publish_poses(
        &self,
        msg: &HolePosesMsg,
        scores: Option<&[f64; MAX_HOLES]>,
        plane: Option<&WallPlaneMsg>,
    ) -> Result<(), BridgeError> {
        let (array, stamped) = convert::poses_of(msg, &self.frame_id)?;
        let tf = perception::tf_of(&array, &stamped, &self.outlet_frame, self.hole_frames);
        // Made before anything is sent; a covariance that is not one holds back
        // only the detections and markers.
        let detections = perception::detections_of(&array, msg, scores);
        let markers = markers::markers_of(&array, msg, plane);
        self.holes.publish(array).map_err(|e| dds("publishing the hole poses", e))?;
        self.pose.publish(stamped).map_err(|e| dds("publishing the outlet pose", e))?;
        self.tf.publish(tf).map_err(|e| dds("publishing tf", e))?;
        self.detections.publish(detections?).map_err(|e| dds("publishing the detections", e))?;
        self.markers.publish(markers?).map_err(|e| dds("publishing the markers", e))
    }

    /// Who subscribes to the debug images now: readers of their topics and
    /// types that DDS discovery knows of, asked at most every
    /// [`DEBUG_SUBSCRIBERS_CHECK`] (the answer in between is the last one).
    ///
    /// ros2-client's `Publisher::get_subscription_count` counts matched
    /// readers only while the node runs a ros2-client spinner, which the
    /// bridge does not, and the rustdds DataWriter (whose
    /// `get_matched_subscriptions` would say it) is private to ros2-client's
    /// Publisher; the participant's discovery database is what both read.
    pub fn debug_subscribers(&self) -> DebugSubscribers {
        let mut last = self.debug_subscribers.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((at, answer)) = *last
            && at.elapsed() < DEBUG_SUBSCRIBERS_CHECK
        {
            return answer;
        }
        let participant = self.context.domain_participant();
        let [image, compressed] = &self.debug_topics;
        let answer = DebugSubscribers {
            image: readers_of(&participant, image) > 0,
            compressed: readers_of(&participant, compressed) > 0,
        };
        *last = Some((Instant::now(), answer));
        answer
    }

    /// The debug images' publishers, once: to publish (and encode) them on a
    /// thread of their own. Drop it before the bridge.
    pub fn take_debug_publisher(&mut self) -> Option<DebugPublisher> {
        self.debug.take()
    }

    /// Publishes a debug image on this thread ([`DebugPublisher::publish`]),
    /// unless the debug publisher was taken.
    pub fn publish_debug_image(&self, image: DebugImage, to: DebugSubscribers) -> Result<(), BridgeError> {
        let publisher = self.debug.as_ref().ok_or_else(|| dds("the debug image", "its publisher was taken"))?;
        publisher.publish(image, to)
    }

    pub fn publish_diagnostics(&self, array: DiagnosticArray) -> Result<(), BridgeError> {
        self.diagnostics.publish(array).map_err(|e| dds("publishing diagnostics", e))
    }
}
