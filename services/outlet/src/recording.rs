//! MCAP recordings (`outlet record`, `outlet replay`): what crossed the
//! sidecar's shared memory, in the file format of ROS 2 bags and Foxglove.
//!
//! Written: the camera's frames as `sensor_msgs/msg/Image` with a
//! `sensor_msgs/msg/CameraInfo` of each frame's intrinsics and distortion, the
//! stereo clouds as `sensor_msgs/msg/PointCloud2` (CDR, schema encoding
//! `ros2msg`, on the ROS 2 bridge's topics, in its frame), and the services'
//! results as JSON with a JSON Schema: detections, hole poses with their
//! covariances, wall planes and heartbeats ([`topic`]). Every message's log and
//! publish time is its capture time (a heartbeat's: when it was published); a
//! camera message's `sequence` is its frame id (low 32 bits).
//!
//! Read: any MCAP file with `sensor_msgs/msg/Image` (mono8, rgb8, bgr8),
//! `CameraInfo` and `PointCloud2` (float32 x, y, z at any offsets) in CDR, ours or
//! a ROS 2 tool's, told apart by schema name, not topic ([`choose_channels`]).
//! Every message is checked by the ROS 2 bridge's conversions; one that does
//! not fit is an error naming the file, the message and what was wrong.

use anyhow::{Context, Result, anyhow, bail};
use mcap::records::MessageHeader;
use mcap::sans_io::LinearReaderOptions;
use outlet_protocol::CameraModel;
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, FrameHeader, HeartbeatMsg, HolePosesMsg, SCHEMA_VERSION, WallPlaneMsg, pose_status,
};
use outlet_ros2_bridge::Ros2Config;
use outlet_ros2_bridge::cdr::{self, Definition};
use outlet_ros2_bridge::convert;
use outlet_ros2_bridge::msgs::{CameraInfo, Header, Image, PointCloud2};
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::io::{Read, Seek, Write};
use std::path::Path;

/// Topics of the services' results in a recording (JSON); the camera's are the
/// ROS 2 bridge's (`[ros2.topics]` image, camera_info, points).
pub mod topic {
    pub const DETECTIONS: &str = "/outlet/detections";
    pub const HOLE_POSES: &str = "/outlet/hole_poses";
    pub const WALL_PLANE: &str = "/outlet/wall_plane";
    pub const HEARTBEAT: &str = "/outlet/heartbeat";
}

/// The magic of the files `outlet record` wrote before it wrote MCAP.
const OLD_MAGIC: &[u8; 9] = b"OUTLETREC";
/// A record larger than this is not one a camera wrote (a 4K rgb8 frame is 25 MB).
const MAX_RECORD_BYTES: usize = 256 << 20;

/// Writes a recording.
pub struct Recorder<W: Write + Seek> {
    writer: mcap::Writer<W>,
    frame_id: String,
    image: u16,
    camera_info: u16,
    points: u16,
    detections: u16,
    hole_poses: u16,
    plane: u16,
    heartbeat: u16,
    /// Messages written per topic kind: frames, clouds, detections, hole poses, planes, heartbeats.
    pub counts: [u64; 6],
}

fn ros_channel<M: Definition>(writer: &mut mcap::Writer<impl Write + Seek>, topic: &str) -> Result<u16> {
    let schema = writer.add_schema(&M::schema_name(), cdr::SCHEMA_ENCODING, M::DEFINITION.as_bytes())?;
    Ok(writer.add_channel(schema, topic, cdr::MESSAGE_ENCODING, &BTreeMap::new())?)
}

fn json_channel(writer: &mut mcap::Writer<impl Write + Seek>, topic: &str, name: &str, schema: &Value) -> Result<u16> {
    let schema = writer.add_schema(name, "jsonschema", schema.to_string().as_bytes())?;
    Ok(writer.add_channel(schema, topic, "json", &BTreeMap::new())?)
}

impl<W: Write + Seek> Recorder<W> {
    /// A recording into `out`, on the camera topics and in the frame of `ros2`.
    pub fn new(out: W, ros2: &Ros2Config) -> Result<Self> {
        let options = mcap::WriteOptions::new().profile("").library(concat!("outlet ", env!("CARGO_PKG_VERSION")));
        let mut writer = options.create(out)?;
        let topics = &ros2.topics;
        Ok(Self {
            image: ros_channel::<Image>(&mut writer, &topics.image)?,
            camera_info: ros_channel::<CameraInfo>(&mut writer, &topics.camera_info)?,
            points: ros_channel::<PointCloud2>(&mut writer, &topics.points)?,
            detections: json_channel(&mut writer, topic::DETECTIONS, "outlet.Detection", &schema::detection())?,
            hole_poses: json_channel(&mut writer, topic::HOLE_POSES, "outlet.HolePoses", &schema::hole_poses())?,
            plane: json_channel(&mut writer, topic::WALL_PLANE, "outlet.WallPlane", &schema::wall_plane())?,
            heartbeat: json_channel(&mut writer, topic::HEARTBEAT, "outlet.Heartbeat", &schema::heartbeat())?,
            writer,
            frame_id: ros2.frame_id.clone(),
            counts: [0; 6],
        })
    }

    fn put(&mut self, channel_id: u16, sequence: u64, log_time: u64, publish_time: u64, data: &[u8]) -> Result<()> {
        let header = MessageHeader { channel_id, sequence: sequence as u32, log_time, publish_time };
        Ok(self.writer.write_to_known_channel(&header, data)?)
    }

    /// A camera frame: its Image and CameraInfo.
    pub fn frame(&mut self, frame: &FrameHeader, pixels: &[u8]) -> Result<()> {
        let (image, info) = convert::image_and_info_of(frame, pixels, &self.frame_id)?;
        let t = frame.capture_time_ns;
        self.put(self.camera_info, frame.frame_id, t, t, &cdr::encode(&info)?)?;
        self.put(self.image, frame.frame_id, t, t, &cdr::encode(&image)?)?;
        self.counts[0] += 1;
        Ok(())
    }

    /// A stereo cloud (x, y, z values, camera frame, metres).
    pub fn cloud(&mut self, cloud: &CloudHeader, xyz: &[f32]) -> Result<()> {
        cloud.validate(xyz.len()).map_err(|e| anyhow!("cloud {}: {e}", cloud.frame_id))?;
        let values = &xyz[..3 * cloud.points as usize];
        let header = Header { stamp: convert::ns_to_time(cloud.capture_time_ns), frame_id: self.frame_id.clone() };
        let t = cloud.capture_time_ns;
        self.put(self.points, cloud.frame_id, t, t, &cdr::encode(&convert::cloud_of_xyz(header, values))?)?;
        self.counts[1] += 1;
        Ok(())
    }

    pub fn detection(&mut self, d: &DetectionMsg) -> Result<()> {
        let t = d.capture_time_ns;
        self.put(self.detections, d.frame_id, t, t, detection_json(d).to_string().as_bytes())?;
        self.counts[2] += 1;
        Ok(())
    }

    pub fn hole_poses(&mut self, p: &HolePosesMsg) -> Result<()> {
        self.put(
            self.hole_poses,
            p.frame_id,
            p.capture_time_ns,
            p.published_ns,
            hole_poses_json(p).to_string().as_bytes(),
        )?;
        self.counts[3] += 1;
        Ok(())
    }

    pub fn plane(&mut self, p: &WallPlaneMsg) -> Result<()> {
        let t = p.capture_time_ns;
        self.put(self.plane, p.frame_id, t, t, wall_plane_json(p).to_string().as_bytes())?;
        self.counts[4] += 1;
        Ok(())
    }

    pub fn heartbeat(&mut self, b: &HeartbeatMsg) -> Result<()> {
        let t = b.published_ns;
        self.put(self.heartbeat, b.sequence, t, t, heartbeat_json(b).to_string().as_bytes())?;
        self.counts[5] += 1;
        Ok(())
    }

    /// Writes the summary and index; the recording is complete only after this.
    pub fn finish(mut self) -> Result<W> {
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }
}

fn kind_name(kind: u32) -> &'static str {
    match kind {
        1 => "power",
        2 => "ground",
        _ => "unknown",
    }
}

/// A detection as JSON: the frame, the paper's score, the camera and each
/// hole's kind, pixel (as captured), score and sigma.
pub fn detection_json(d: &DetectionMsg) -> Value {
    let n = (d.hole_count as usize).min(d.holes.len());
    json!({
        "frame_id": d.frame_id,
        "capture_time_ns": d.capture_time_ns,
        "schema_version": d.schema_version,
        "score": d.score,
        "detect_ms": d.detect_ms,
        "camera": {"width": d.width, "height": d.height, "intrinsics": d.intrinsics, "distortion": d.distortion},
        "holes": d.holes[..n].iter().map(|h| json!({
            "kind": kind_name(h.kind),
            "refined": h.refined == 1,
            "pixel": h.pixel,
            "score": h.score,
            "sigma_px": h.sigma_px,
            "shape": h.shape,
        })).collect::<Vec<_>>(),
    })
}

/// Hole poses as JSON: status and mode by name, the outlet's pose (null when
/// there is none), each hole's kind, position (camera frame, m), 3x3
/// covariance (row-major, m²) and whether its pixel was an outlier.
pub fn hole_poses_json(p: &HolePosesMsg) -> Value {
    let n = (p.hole_count as usize).min(p.positions_m.len());
    let ok = p.status == pose_status::OK;
    json!({
        "frame_id": p.frame_id,
        "capture_time_ns": p.capture_time_ns,
        "published_ns": p.published_ns,
        "schema_version": p.schema_version,
        "status": match p.status {
            pose_status::OK => "ok",
            pose_status::AMBIGUOUS => "ambiguous",
            pose_status::PLANE_MISMATCH => "plane_mismatch",
            _ => "unknown",
        },
        "mode": match p.mode { 1 => "mono", 2 => "normal", 3 => "plane", _ => "unknown" },
        "rotation": if ok { json!(p.rotation) } else { Value::Null },
        "translation_m": if ok { json!(p.translation_m) } else { Value::Null },
        "holes": (0..n).map(|k| json!({
            "kind": kind_name(p.kinds[k]),
            "position_m": p.positions_m[k],
            "covariance_m2": p.covariances_m2[k],
            "outlier": k < 32 && p.outlier_mask & (1 << k) != 0,
        })).collect::<Vec<_>>(),
    })
}

/// A wall plane `normal · X = distance_m` (camera frame) as JSON.
pub fn wall_plane_json(p: &WallPlaneMsg) -> Value {
    json!({
        "frame_id": p.frame_id,
        "capture_time_ns": p.capture_time_ns,
        "schema_version": p.schema_version,
        "normal": p.normal,
        "distance_m": p.distance_m,
        "inliers": p.inliers,
        "tangent": p.tangent,
        "covariance": p.covariance,
    })
}

/// A heartbeat as JSON (NaN latencies as null).
pub fn heartbeat_json(b: &HeartbeatMsg) -> Value {
    json!({
        "service": b.service_name(),
        "pid": b.pid,
        "sequence": b.sequence,
        "published_ns": b.published_ns,
        "started_ns": b.started_ns,
        "inputs": b.inputs,
        "outputs": b.outputs,
        "rejected": b.rejected,
        "dropped": b.dropped,
        "input_rate_hz": b.input_rate_hz,
        "output_rate_hz": b.output_rate_hz,
        "latency_p50_ms": b.latency_p50_ms,
        "latency_p99_ms": b.latency_p99_ms,
        "latency_max_ms": b.latency_max_ms,
        "work_p50_ms": b.work_p50_ms,
        "work_p99_ms": b.work_p99_ms,
        "last_output_ns": b.last_output_ns,
        "last_rejection": b.last_rejection(),
    })
}

/// The JSON Schemas of the result channels.
pub mod schema {
    use serde_json::{Value, json};

    fn numbers(n: usize) -> Value {
        json!({"type": "array", "items": {"type": ["number", "null"]}, "minItems": n, "maxItems": n})
    }

    fn object(title: &str, properties: Value) -> Value {
        json!({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "type": "object",
               "properties": properties})
    }

    const INT: &str = "integer";

    pub fn detection() -> Value {
        object(
            "outlet.Detection: the outlet found in a frame (no holes: none)",
            json!({
                "frame_id": {"type": INT}, "capture_time_ns": {"type": INT}, "schema_version": {"type": INT},
                "score": {"type": INT}, "detect_ms": {"type": "number"},
                "camera": {"type": "object", "properties": {"width": {"type": INT}, "height": {"type": INT},
                    "intrinsics": numbers(4), "distortion": numbers(5)}},
                "holes": {"type": "array", "items": {"type": "object", "properties": {
                    "kind": {"enum": ["power", "ground", "unknown"]}, "refined": {"type": "boolean"},
                    "pixel": numbers(2), "score": {"type": "number"}, "sigma_px": {"type": "number"},
                    "shape": numbers(3)}}},
            }),
        )
    }

    pub fn hole_poses() -> Value {
        object(
            "outlet.HolePoses: hole positions (camera frame, m) with covariances (m^2), the outlet's pose",
            json!({
                "frame_id": {"type": INT}, "capture_time_ns": {"type": INT}, "published_ns": {"type": INT},
                "schema_version": {"type": INT},
                "status": {"enum": ["ok", "ambiguous", "plane_mismatch", "unknown"]},
                "mode": {"enum": ["mono", "normal", "plane", "unknown"]},
                "rotation": {"oneOf": [numbers(9), {"type": "null"}]},
                "translation_m": {"oneOf": [numbers(3), {"type": "null"}]},
                "holes": {"type": "array", "items": {"type": "object", "properties": {
                    "kind": {"enum": ["power", "ground", "unknown"]}, "position_m": numbers(3),
                    "covariance_m2": numbers(9), "outlier": {"type": "boolean"}}}},
            }),
        )
    }

    pub fn wall_plane() -> Value {
        object(
            "outlet.WallPlane: normal . X = distance_m (camera frame), covariance of (da, db, dd) in the tangent basis",
            json!({
                "frame_id": {"type": INT}, "capture_time_ns": {"type": INT}, "schema_version": {"type": INT},
                "normal": numbers(3), "distance_m": {"type": "number"}, "inliers": {"type": INT},
                "tangent": {"type": "array", "items": numbers(3), "minItems": 2, "maxItems": 2},
                "covariance": numbers(9),
            }),
        )
    }

    pub fn heartbeat() -> Value {
        let mut properties = serde_json::Map::new();
        properties.insert("service".into(), json!({"type": "string"}));
        properties.insert("last_rejection".into(), json!({"type": "string"}));
        for k in ["pid", "sequence", "published_ns", "started_ns", "inputs", "outputs", "rejected", "dropped"] {
            properties.insert(k.into(), json!({"type": INT}));
        }
        properties.insert("last_output_ns".into(), json!({"type": INT}));
        for k in [
            "input_rate_hz",
            "output_rate_hz",
            "latency_p50_ms",
            "latency_p99_ms",
            "latency_max_ms",
            "work_p50_ms",
            "work_p99_ms",
        ] {
            properties.insert(k.into(), json!({"type": ["number", "null"]}));
        }
        object("outlet.Heartbeat: a service's health over its last period", Value::Object(properties))
    }
}

/// What the reader makes of a channel, by its schema name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Image,
    CameraInfo,
    Points,
}

impl Kind {
    /// ROS 2's schema names (`sensor_msgs/msg/Image`), and the short ones.
    pub fn of_schema(name: &str) -> Option<Self> {
        match name {
            "sensor_msgs/msg/Image" | "sensor_msgs/Image" => Some(Self::Image),
            "sensor_msgs/msg/CameraInfo" | "sensor_msgs/CameraInfo" => Some(Self::CameraInfo),
            "sensor_msgs/msg/PointCloud2" | "sensor_msgs/PointCloud2" => Some(Self::Points),
            _ => None,
        }
    }
}

/// A channel of a recording the reader can use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    pub topic: String,
    pub schema: String,
    pub message_encoding: String,
    pub kind: Kind,
    pub messages: u64,
}

/// The channels a replay reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channels {
    pub image: String,
    pub camera_info: String,
    pub points: Option<String>,
}

fn reader<R: Read>(source: R) -> mcap::io::MessageReader<R> {
    let options = LinearReaderOptions::default().with_record_length_limit(MAX_RECORD_BYTES);
    mcap::io::MessageReader::new_with_options(source, options)
}

fn mcap_error(name: &str, e: mcap::McapError, after: u64) -> anyhow::Error {
    let what = match e {
        mcap::McapError::BadMagic => "not an MCAP file (bad magic)".to_string(),
        mcap::McapError::UnexpectedEof => "the file ends in the middle of a record (truncated?)".to_string(),
        e => format!("not a valid MCAP file: {e}"),
    };
    anyhow!("{name}: {what}, after {after} messages")
}

/// Refuses the files `outlet record` wrote before MCAP, saying so.
fn check_not_old(head: &[u8], name: &str) -> Result<()> {
    if head.starts_with(OLD_MAGIC) {
        bail!(
            "{name}: a recording in the postcard format of earlier `outlet record` builds, which this build does not \
             read (it reads MCAP)"
        );
    }
    Ok(())
}

/// Every ROS 2 camera channel of a recording, with its message count, reading it
/// all (a truncated or corrupt file fails here, before anything is played).
pub fn scan<R: Read>(mut source: R, name: &str) -> Result<Vec<ChannelInfo>> {
    let mut head = [0u8; 9];
    let got = source.read(&mut head).with_context(|| format!("{name}: reading"))?;
    check_not_old(&head[..got], name)?;
    let mut channels: BTreeMap<u16, ChannelInfo> = BTreeMap::new();
    for (count, message) in reader((&head[..got]).chain(source)).enumerate() {
        let message = message.map_err(|e| mcap_error(name, e, count as u64))?;
        if let Some(c) = channels.get_mut(&message.channel.id) {
            c.messages += 1;
            continue;
        }
        let Some(schema) = &message.channel.schema else { continue };
        let Some(kind) = Kind::of_schema(&schema.name) else { continue };
        channels.insert(
            message.channel.id,
            ChannelInfo {
                topic: message.channel.topic.clone(),
                schema: schema.name.clone(),
                message_encoding: message.channel.message_encoding.clone(),
                kind,
                messages: 1,
            },
        );
    }
    Ok(channels.into_values().collect())
}

/// Which topics to replay when a recording has several of a kind.
#[derive(Debug, Clone, Default)]
pub struct TopicChoice {
    pub image: Option<String>,
    pub points: Option<String>,
}

/// The channels to replay: the image topic (given, or the only one), its
/// CameraInfo (the `camera_info` beside it, or the only one), the point cloud
/// topic (given, the only one, or none). Each must be CDR.
pub fn choose_channels(channels: &[ChannelInfo], choice: &TopicChoice, name: &str) -> Result<Channels> {
    let of = |kind| channels.iter().filter(move |c| c.kind == kind);
    let topics = |kind| of(kind).map(|c| c.topic.as_str()).collect::<Vec<_>>().join(", ");
    let pick = |kind, given: &Option<String>, what: &str, flag: &str| -> Result<Option<&ChannelInfo>> {
        let found: Vec<&ChannelInfo> = of(kind).collect();
        match (given, found.as_slice()) {
            (Some(t), _) => match found.iter().find(|c| &c.topic == t) {
                Some(c) => Ok(Some(*c)),
                None => bail!("{name}: no {what} channel on {t} (there are: {})", topics(kind)),
            },
            (None, []) => Ok(None),
            (None, [c]) => Ok(Some(*c)),
            (None, _) => bail!("{name}: several {what} channels ({}); choose one with {flag}", topics(kind)),
        }
    };
    let image = pick(Kind::Image, &choice.image, "sensor_msgs/msg/Image", "--image-topic")?
        .ok_or_else(|| anyhow!("{name}: no sensor_msgs/msg/Image channel: nothing to replay"))?;
    let sibling = image.topic.rsplit_once('/').map(|(parent, _)| format!("{parent}/camera_info"));
    let infos: Vec<&ChannelInfo> = of(Kind::CameraInfo).collect();
    let info = match (infos.iter().find(|c| Some(&c.topic) == sibling.as_ref()), infos.as_slice()) {
        (Some(c), _) | (None, [c]) => *c,
        (None, []) => bail!("{name}: no sensor_msgs/msg/CameraInfo channel: the images' camera is unknown"),
        (None, _) => bail!(
            "{name}: several CameraInfo channels ({}) and none is {} beside the images",
            topics(Kind::CameraInfo),
            sibling.unwrap_or_default()
        ),
    };
    let points = pick(Kind::Points, &choice.points, "sensor_msgs/msg/PointCloud2", "--points-topic")?;
    for c in [Some(image), Some(info), points].into_iter().flatten() {
        if c.message_encoding != cdr::MESSAGE_ENCODING {
            bail!(
                "{name}: channel {} ({}) has message encoding {:?}; only {:?} (ROS 2) is read",
                c.topic,
                c.schema,
                c.message_encoding,
                cdr::MESSAGE_ENCODING
            );
        }
    }
    Ok(Channels {
        image: image.topic.clone(),
        camera_info: info.topic.clone(),
        points: points.map(|c| c.topic.clone()),
    })
}

/// What a replay sends into shared memory.
#[derive(Debug, Clone, PartialEq)]
pub enum Sample {
    Frame { header: FrameHeader, pixels: Vec<u8> },
    Cloud { header: CloudHeader, xyz: Vec<f32> },
}

impl Sample {
    pub fn capture_time_ns(&self) -> u64 {
        match self {
            Self::Frame { header, .. } => header.capture_time_ns,
            Self::Cloud { header, .. } => header.capture_time_ns,
        }
    }
}

/// Reads the frames and clouds of a recording in file order.
pub struct Player<R: Read> {
    reader: mcap::io::MessageReader<R>,
    name: String,
    channels: Channels,
    camera: Option<CameraModel>,
    frames: u64,
    clouds: u64,
    read: u64,
    /// Images before the first CameraInfo, left out.
    pub without_camera: u64,
}

impl<R: Read> Player<R> {
    pub fn new(source: R, name: &str, channels: &Channels) -> Self {
        Self {
            reader: reader(source),
            name: name.into(),
            channels: channels.clone(),
            camera: None,
            frames: 0,
            clouds: 0,
            read: 0,
            without_camera: 0,
        }
    }

    /// A message's frame id: its `sequence` (the frame id in our recordings),
    /// or when that is 0 (as in many ROS 2 bags), one more than `before`.
    fn frame_id(sequence: u32, before: u64) -> u64 {
        if sequence != 0 { u64::from(sequence) } else { before + 1 }
    }

    /// The next frame or cloud with its log time (ns); None at the end. Frame
    /// ids are the messages' sequence numbers, or when those are 0, frames
    /// and clouds are numbered from 1 in file order.
    pub fn next_sample(&mut self) -> Result<Option<(u64, Sample)>> {
        loop {
            let Some(message) = self.reader.next() else { return Ok(None) };
            let message = message.map_err(|e| mcap_error(&self.name, e, self.read))?;
            self.read += 1;
            let topic = message.channel.topic.as_str();
            let at = || format!("{}: message {} on {topic} (log time {} ns)", self.name, self.read, message.log_time);
            let sample = if topic == self.channels.image {
                let image: Image = cdr::decode(&message.data).with_context(at)?;
                if self.camera.is_none() {
                    self.without_camera += 1;
                    continue;
                }
                let id = Self::frame_id(message.sequence, self.frames);
                let (header, pixels) = convert::frame_of(&image, self.camera.as_ref(), id).with_context(at)?;
                self.frames += 1;
                Sample::Frame { header, pixels: pixels.to_vec() }
            } else if topic == self.channels.camera_info {
                let info: CameraInfo = cdr::decode(&message.data).with_context(at)?;
                self.camera = Some(convert::camera_of(&info).with_context(at)?);
                continue;
            } else if Some(topic) == self.channels.points.as_deref() {
                let cloud: PointCloud2 = cdr::decode(&message.data).with_context(at)?;
                let (capture_time_ns, xyz) = convert::xyz_of(&cloud).with_context(at)?;
                self.clouds += 1;
                let header = CloudHeader {
                    schema_version: SCHEMA_VERSION,
                    reserved: 0,
                    frame_id: Self::frame_id(message.sequence, self.clouds - 1),
                    capture_time_ns,
                    points: (xyz.len() / 3) as u64,
                };
                Sample::Cloud { header, xyz }
            } else {
                continue;
            };
            return Ok(Some((message.log_time, sample)));
        }
    }
}

/// [`scan`] and [`choose_channels`] of a file.
pub fn channels_of_file(path: &Path, choice: &TopicChoice) -> Result<Channels> {
    let name = path.display().to_string();
    let file = std::fs::File::open(path).with_context(|| format!("opening {name}"))?;
    let channels = scan(std::io::BufReader::new(file), &name)?;
    choose_channels(&channels, choice, &name)
}

/// A [`Player`] of a file.
pub fn play_file(path: &Path, channels: &Channels) -> Result<Player<std::io::BufReader<std::fs::File>>> {
    let file = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    Ok(Player::new(std::io::BufReader::new(file), &path.display().to_string(), channels))
}

#[cfg(test)]
mod tests;
