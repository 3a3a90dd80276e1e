//! Between ROS 2 messages and the sidecar's wire types: pure functions, no DDS,
//! no shared memory. Whatever comes from the network is checked here; a message
//! that does not fit is a [`Rejection`] that says what was wrong, with which value.

use crate::msgs::{
    CameraInfo, CompressedImage, DiagnosticArray, DiagnosticStatus, Header, Image, KeyValue, Point, PointCloud2,
    PointField, Pose, PoseArray, PoseStamped, Quaternion, Time,
};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
use outlet_protocol::CameraModel;
use outlet_protocol::wire::{FrameHeader, HeartbeatMsg, HolePosesMsg, PixelFormat, pose_status};
use std::collections::BTreeMap;

const NS_PER_S: u64 = 1_000_000_000;

/// Why a message was not bridged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Rejection {
    #[error("{what}: header.stamp {sec} s {nanosec} ns is not a time since the Unix epoch")]
    Stamp { what: &'static str, sec: i32, nanosec: u32 },
    #[error("image: encoding {0:?} is not mono8, rgb8 or bgr8")]
    Encoding(String),
    #[error("image: size {width}x{height} is empty")]
    EmptyImage { width: u32, height: u32 },
    #[error("image: step {step} is less than width {width} x {channels} bytes")]
    Step { step: u32, width: u32, channels: usize },
    #[error("image: {got} bytes of data, height {height} x step {step} = {expected} needed")]
    ShortImage { got: usize, height: u32, step: u32, expected: u64 },
    #[error("image: no CameraInfo has come yet")]
    NoCameraInfo,
    #[error("image: size {image_width}x{image_height}, the CameraInfo's {info_width}x{info_height}")]
    SizeMismatch { image_width: u32, image_height: u32, info_width: u32, info_height: u32 },
    #[error("image: {0}")]
    Frame(String),
    #[error("compressed image (format {format:?}): {reason}")]
    Compressed { format: String, reason: String },
    #[error("camera info: distortion model {model:?} with {coefficients} coefficients (plumb_bob or none expected)")]
    Distortion { model: String, coefficients: usize },
    #[error("camera info: binning {x}x{y} (only full-resolution images)")]
    Binning { x: u32, y: u32 },
    #[error("camera info: skew {skew} in K (a pinhole without skew expected)")]
    Skew { skew: f64 },
    #[error("camera info: K {k:?} is not a calibrated camera: {reason}")]
    Intrinsics { k: [f64; 9], reason: String },
    #[error("cloud: big-endian data (little-endian expected)")]
    BigEndian,
    #[error("cloud: no field {0:?}")]
    MissingField(&'static str),
    #[error("cloud: field {name:?} is {datatype_name} (datatype {datatype}), not float32")]
    FieldType { name: &'static str, datatype: u8, datatype_name: &'static str },
    #[error("cloud: field {name:?} at offset {offset} does not fit in point_step {point_step}")]
    FieldOffset { name: &'static str, offset: u32, point_step: u32 },
    #[error("cloud: row_step {row_step} is less than width {width} x point_step {point_step}")]
    RowStep { row_step: u32, width: u32, point_step: u32 },
    #[error("cloud: {got} bytes of data, {expected} needed for {height} rows of {width} points")]
    ShortCloud { got: usize, expected: u64, height: u32, width: u32 },
    #[error("cloud: {width}x{height} points is too many")]
    CloudSize { width: u32, height: u32 },
    #[error("hole poses of frame {frame_id}: {reason}")]
    Poses { frame_id: u64, reason: String },
    /// A result without a pose (ambiguous, or the plane disagrees): nothing is
    /// published as a pose; the bridge reports it in /diagnostics.
    #[error("frame {frame_id}: no pose ({status}), nothing published")]
    NoPose { frame_id: u64, status: &'static str },
}

/// A ROS time as nanoseconds since the Unix epoch; None when it is before the
/// epoch or its nanoseconds are not below a second.
pub fn time_to_ns(t: Time) -> Option<u64> {
    if t.sec < 0 || u64::from(t.nanosec) >= NS_PER_S {
        return None;
    }
    Some(t.sec as u64 * NS_PER_S + u64::from(t.nanosec))
}

/// Nanoseconds since the Unix epoch as a ROS time (the last second ROS can
/// hold, in 2038, for later times).
pub fn ns_to_time(ns: u64) -> Time {
    let sec = ns / NS_PER_S;
    match i32::try_from(sec) {
        Ok(sec) => Time { sec, nanosec: (ns % NS_PER_S) as u32 },
        Err(_) => Time { sec: i32::MAX, nanosec: (NS_PER_S - 1) as u32 },
    }
}

fn stamp_ns(what: &'static str, header: &Header) -> Result<u64, Rejection> {
    time_to_ns(header.stamp).ok_or(Rejection::Stamp { what, sec: header.stamp.sec, nanosec: header.stamp.nanosec })
}

/// The camera a CameraInfo describes: K's fx, fy, cx, cy and plumb_bob's five
/// coefficients (none: an undistorted image).
pub fn camera_of(info: &CameraInfo) -> Result<CameraModel, Rejection> {
    let distortion = match (info.distortion_model.as_str(), info.d.len()) {
        (_, 0) => [0.0; 5],
        ("plumb_bob", 5) => [info.d[0], info.d[1], info.d[2], info.d[3], info.d[4]],
        // Another model whose coefficients are all zero is no distortion either.
        (_, _) if info.d.iter().all(|&k| k == 0.0) => [0.0; 5],
        (model, n) => return Err(Rejection::Distortion { model: model.to_string(), coefficients: n }),
    };
    if info.binning_x > 1 || info.binning_y > 1 {
        return Err(Rejection::Binning { x: info.binning_x, y: info.binning_y });
    }
    let k = info.k;
    if k[1].is_nan() || k[1].abs() > 1e-6 * k[0].abs() {
        return Err(Rejection::Skew { skew: k[1] });
    }
    CameraModel::new(info.width, info.height, [k[0], k[4], k[2], k[5]], distortion)
        .map_err(|e| Rejection::Intrinsics { k, reason: e.to_string() })
}

/// The pixel format of a ROS image encoding the pipeline reads.
pub fn pixel_format(encoding: &str) -> Option<PixelFormat> {
    match encoding {
        "mono8" => Some(PixelFormat::Mono8),
        "rgb8" => Some(PixelFormat::Rgb8),
        "bgr8" => Some(PixelFormat::Bgr8),
        _ => None,
    }
}

/// A frame for the sidecar from an image and the latest camera (from
/// [`camera_of`]): its header (`frame_id` given by the caller, the capture time
/// the image's stamp, the stride its step) and its pixels, `height` rows of
/// `step` bytes (extra data past them is left out).
pub fn frame_of<'a>(
    image: &'a Image,
    camera: Option<&CameraModel>,
    frame_id: u64,
) -> Result<(FrameHeader, &'a [u8]), Rejection> {
    let format = pixel_format(&image.encoding).ok_or_else(|| Rejection::Encoding(image.encoding.clone()))?;
    let (width, height, step) = (image.width, image.height, image.step);
    if width == 0 || height == 0 {
        return Err(Rejection::EmptyImage { width, height });
    }
    let channels = format.channels();
    if (step as usize) < width as usize * channels {
        return Err(Rejection::Step { step, width, channels });
    }
    let expected = u64::from(height) * u64::from(step);
    let pixels = usize::try_from(expected).ok().and_then(|n| image.data.get(..n)).ok_or(Rejection::ShortImage {
        got: image.data.len(),
        height,
        step,
        expected,
    })?;
    let camera = camera.ok_or(Rejection::NoCameraInfo)?;
    if (camera.width, camera.height) != (width, height) {
        return Err(Rejection::SizeMismatch {
            image_width: width,
            image_height: height,
            info_width: camera.width,
            info_height: camera.height,
        });
    }
    let capture_time_ns = stamp_ns("image", &image.header)?;
    let mut header = FrameHeader::new(frame_id, capture_time_ns, format, camera);
    header.stride = step;
    // The sidecar's own check, so that what goes out is what every reader accepts.
    header.validate(pixels.len()).map_err(|e| Rejection::Frame(e.to_string()))?;
    Ok((header, pixels))
}

/// [`camera_of`] then [`frame_of`]: one image with its CameraInfo.
pub fn frame_from<'a>(
    image: &'a Image,
    info: &CameraInfo,
    frame_id: u64,
) -> Result<(FrameHeader, &'a [u8], CameraModel), Rejection> {
    let camera = camera_of(info)?;
    let (header, pixels) = frame_of(image, Some(&camera), frame_id)?;
    Ok((header, pixels, camera))
}

/// The byte offset of the float32 field `name` in a point.
fn float32_field(cloud: &PointCloud2, name: &'static str) -> Result<usize, Rejection> {
    let field = cloud.fields.iter().find(|f| f.name == name).ok_or(Rejection::MissingField(name))?;
    if field.datatype != PointField::FLOAT32 {
        return Err(Rejection::FieldType {
            name,
            datatype: field.datatype,
            datatype_name: PointField::datatype_name(field.datatype),
        });
    }
    if u64::from(field.offset) + 4 > u64::from(cloud.point_step) {
        return Err(Rejection::FieldOffset { name, offset: field.offset, point_step: cloud.point_step });
    }
    Ok(field.offset as usize)
}

/// The points of a cloud as x, y, z values (its frame, metres), NaN kept, in
/// row order; the capture time is the header's stamp. The x, y and z fields
/// must be float32, little-endian, at any offsets within any point_step; rows
/// may be padded (row_step); is_dense is not trusted (NaN points pass through).
pub fn xyz_of(cloud: &PointCloud2) -> Result<(u64, Vec<f32>), Rejection> {
    if cloud.is_bigendian {
        return Err(Rejection::BigEndian);
    }
    let offsets = [float32_field(cloud, "x")?, float32_field(cloud, "y")?, float32_field(cloud, "z")?];
    let (width, height) = (cloud.width, cloud.height);
    let (point_step, row_step) = (cloud.point_step as usize, cloud.row_step as usize);
    let row_bytes = u64::from(width) * u64::from(cloud.point_step);
    if (row_step as u64) < row_bytes {
        return Err(Rejection::RowStep { row_step: cloud.row_step, width, point_step: cloud.point_step });
    }
    let points = u64::from(width) * u64::from(height);
    if points > 1 << 28 {
        return Err(Rejection::CloudSize { width, height });
    }
    // The last row needs its points only, not its padding.
    let expected = if height == 0 { 0 } else { (u64::from(height) - 1) * row_step as u64 + row_bytes };
    if (cloud.data.len() as u64) < expected {
        return Err(Rejection::ShortCloud { got: cloud.data.len(), expected, height, width });
    }
    let capture_time_ns = stamp_ns("cloud", &cloud.header)?;
    let mut xyz = Vec::with_capacity(3 * points as usize);
    for row in 0..height as usize {
        let start = row * row_step;
        let Some(row) = cloud.data.get(start..start + row_bytes as usize) else { break };
        for point in row.chunks_exact(point_step.max(1)).take(width as usize) {
            for &offset in &offsets {
                let value = point.get(offset..offset + 4).and_then(|b| <[u8; 4]>::try_from(b).ok());
                xyz.push(value.map_or(f32::NAN, f32::from_le_bytes));
            }
        }
    }
    Ok((capture_time_ns, xyz))
}

/// The CameraInfo of a camera (plumb_bob, no rectification), the other way
/// from [`camera_of`]: for programs that play a ROS 2 camera driver.
pub fn camera_info_of(camera: &CameraModel, header: Header) -> CameraInfo {
    let (fx, fy, cx, cy) = (camera.fx, camera.fy, camera.cx, camera.cy);
    CameraInfo {
        header,
        height: camera.height,
        width: camera.width,
        distortion_model: "plumb_bob".into(),
        d: camera.distortion.to_vec(),
        k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        binning_x: 0,
        binning_y: 0,
        roi: Default::default(),
    }
}

/// The ROS encoding of a pixel format.
pub fn encoding_of(format: PixelFormat) -> &'static str {
    match format {
        PixelFormat::Mono8 => "mono8",
        PixelFormat::Rgb8 => "rgb8",
        PixelFormat::Bgr8 => "bgr8",
    }
}

/// A packed RGB image (`width` x `height` x 3 bytes) as an Image of `format`
/// with rows of `step` bytes (zero padding past the pixels): for programs that
/// play a ROS 2 camera driver. None when `rgb` is not that size or `step` is
/// too short.
pub fn image_of(header: Header, width: u32, height: u32, rgb: &[u8], format: PixelFormat, step: u32) -> Option<Image> {
    let (w, h) = (width as usize, height as usize);
    let row_bytes = w * format.channels();
    if rgb.len() != w * h * 3 || (step as usize) < row_bytes {
        return None;
    }
    let mut data = vec![0u8; step as usize * h];
    for (src, dst) in rgb.chunks_exact(w * 3).zip(data.chunks_exact_mut(step as usize)) {
        let dst = &mut dst[..row_bytes];
        match format {
            PixelFormat::Rgb8 => dst.copy_from_slice(src),
            PixelFormat::Bgr8 => {
                for (s, d) in src.chunks_exact(3).zip(dst.chunks_exact_mut(3)) {
                    d.copy_from_slice(&[s[2], s[1], s[0]]);
                }
            }
            PixelFormat::Mono8 => {
                for (s, d) in src.chunks_exact(3).zip(dst.iter_mut()) {
                    *d = ((u16::from(s[0]) + u16::from(s[1]) + u16::from(s[2])) / 3) as u8;
                }
            }
        }
    }
    Some(Image { header, height, width, encoding: encoding_of(format).into(), is_bigendian: 0, step, data })
}

/// The largest compressed image decoded (pixels a side): a 16k camera; a
/// header claiming more is refused before any memory is allocated for it.
pub const MAX_COMPRESSED_SIDE: u32 = 16_384;

/// A sensor_msgs/CompressedImage (JPEG or PNG, whatever `format` says: the
/// bytes tell the codec) as an rgb8 Image with its header, for the image path.
pub fn image_of_compressed(msg: &CompressedImage) -> Result<Image, Rejection> {
    let bad = |reason: String| Rejection::Compressed { format: msg.format.clone(), reason };
    let reader = image::ImageReader::new(std::io::Cursor::new(&msg.data))
        .with_guessed_format()
        .map_err(|e| bad(format!("{e}")))?;
    match reader.format() {
        Some(image::ImageFormat::Jpeg | image::ImageFormat::Png) => {}
        Some(other) => return Err(bad(format!("{other:?} data (JPEG or PNG expected)"))),
        None => return Err(bad(format!("{} bytes that are neither JPEG nor PNG", msg.data.len()))),
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_COMPRESSED_SIDE);
    limits.max_image_height = Some(MAX_COMPRESSED_SIDE);
    let mut reader = reader;
    reader.limits(limits);
    let rgb = reader.decode().map_err(|e| bad(format!("{e}")))?.into_rgb8();
    let (width, height) = rgb.dimensions();
    if width == 0 || height == 0 {
        return Err(Rejection::EmptyImage { width, height });
    }
    Ok(Image {
        header: msg.header.clone(),
        height,
        width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: width * 3,
        data: rgb.into_raw(),
    })
}

/// Points (x, y, z, metres) as an unorganised PointCloud2 of float32 x, y, z
/// packed in 12-byte points: for programs that play a ROS 2 depth camera.
pub fn cloud_of(header: Header, points: &[[f32; 3]]) -> PointCloud2 {
    cloud_of_xyz(header, points.as_flattened())
}

/// [`cloud_of`] for x, y, z values one after the other, as a cloud crosses
/// shared memory (a last incomplete point is left out).
pub fn cloud_of_xyz(header: Header, xyz: &[f32]) -> PointCloud2 {
    let field = |name: &str, offset| PointField { name: name.into(), offset, datatype: PointField::FLOAT32, count: 1 };
    let width = (xyz.len() / 3).min(u32::MAX as usize / 12) as u32;
    let values = &xyz[..3 * width as usize];
    PointCloud2 {
        header,
        height: 1,
        width,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        is_bigendian: false,
        point_step: 12,
        row_step: 12 * width,
        data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        is_dense: values.iter().all(|v| v.is_finite()),
    }
}

/// A frame from shared memory as a ROS 2 camera driver publishes it, the other
/// way from [`frame_of`]: the Image (its rows as they are, `step` the frame's
/// stride) and the CameraInfo of its intrinsics and distortion, both stamped
/// with the capture time, in `frame_id` (the camera's optical frame).
pub fn image_and_info_of(frame: &FrameHeader, pixels: &[u8], frame_id: &str) -> Result<(Image, CameraInfo), Rejection> {
    let (format, camera) = frame.validate(pixels.len()).map_err(|e| Rejection::Frame(e.to_string()))?;
    let header = Header { stamp: ns_to_time(frame.capture_time_ns), frame_id: frame_id.to_string() };
    let rows = frame.stride as usize * frame.height as usize;
    let data = pixels.get(..rows).ok_or_else(|| Rejection::Frame(format!("{} bytes of pixels", pixels.len())))?;
    let image = Image {
        header: header.clone(),
        height: frame.height,
        width: frame.width,
        encoding: encoding_of(format).into(),
        is_bigendian: 0,
        step: frame.stride,
        data: data.to_vec(),
    };
    Ok((image, camera_info_of(&camera, header)))
}

/// A rotation matrix as a unit quaternion; None when it is not a rotation
/// (not finite, not orthonormal within 1e-6, or a reflection).
pub fn quaternion_of(rotation_row_major: &[f64; 9]) -> Option<UnitQuaternion<f64>> {
    let m = Matrix3::from_row_slice(rotation_row_major);
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    let orthonormal = (m.transpose() * m - Matrix3::identity()).norm() < 1e-6;
    if !orthonormal || m.determinant() <= 0.0 {
        return None;
    }
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    // One of the two quaternions of a rotation, always the same one: w >= 0.
    Some(if q.w < 0.0 { UnitQuaternion::new_unchecked(-q.into_inner()) } else { q })
}

pub(crate) fn ros_quaternion(q: &UnitQuaternion<f64>) -> Quaternion {
    Quaternion { x: q.i, y: q.j, z: q.k, w: q.w }
}

/// The hole poses of one frame as ROS 2 messages: a PoseArray with one pose per
/// hole in template order (position the hole's, camera frame, metres;
/// orientation the outlet's) and a PoseStamped of the outlet; both stamped with
/// the frame's capture time, in `frame_id`. A result without a pose (status
/// ambiguous or plane mismatch) is [`Rejection::NoPose`]: an arm listening on
/// ROS is never handed a pose the sidecar cannot vouch for.
pub fn poses_of(msg: &HolePosesMsg, frame_id: &str) -> Result<(PoseArray, PoseStamped), Rejection> {
    let reject = |reason: String| Rejection::Poses { frame_id: msg.frame_id, reason };
    msg.validate().map_err(|e| reject(e.to_string()))?;
    match msg.status {
        pose_status::OK => {}
        pose_status::AMBIGUOUS => return Err(Rejection::NoPose { frame_id: msg.frame_id, status: "ambiguous" }),
        _ => return Err(Rejection::NoPose { frame_id: msg.frame_id, status: "plane_mismatch" }),
    }
    let q = quaternion_of(&msg.rotation).ok_or_else(|| reject(format!("rotation {:?} is not one", msg.rotation)))?;
    if !msg.translation_m.iter().all(|v| v.is_finite()) {
        return Err(reject(format!("translation {:?} is not finite", msg.translation_m)));
    }
    let orientation = ros_quaternion(&q);
    let header = Header { stamp: ns_to_time(msg.capture_time_ns), frame_id: frame_id.to_string() };
    let poses = msg.positions_m[..msg.hole_count as usize]
        .iter()
        .map(|p| Pose { position: Point { x: p[0], y: p[1], z: p[2] }, orientation })
        .collect();
    let [x, y, z] = msg.translation_m;
    let outlet = Pose { position: Point { x, y, z }, orientation };
    Ok((PoseArray { header: header.clone(), poses }, PoseStamped { header, pose: outlet }))
}

/// The services' heartbeats as ROS diagnostics: the newest beat of each service
/// seen, and how many rejections it had counted in the beat before.
#[derive(Debug, Clone)]
pub struct Diagnostics {
    services: BTreeMap<String, Tracked>,
    silent_after_ns: u64,
    hardware_id: String,
}

#[derive(Debug, Clone)]
struct Tracked {
    beat: HeartbeatMsg,
    rejected_before: Option<u64>,
}

impl Diagnostics {
    /// A service whose last beat is older than `silent_after_ns` is an ERROR;
    /// `hardware_id` goes into every status (the sidecar's domain, say).
    pub fn new(silent_after_ns: u64, hardware_id: &str) -> Self {
        Self { services: BTreeMap::new(), silent_after_ns, hardware_id: hardware_id.to_string() }
    }

    /// Takes a heartbeat; an older or repeated one of the same process is ignored.
    pub fn update(&mut self, beat: &HeartbeatMsg) {
        let name = beat.service_name().to_string();
        match self.services.get_mut(&name) {
            Some(t) if t.beat.pid == beat.pid => {
                if beat.sequence > t.beat.sequence {
                    t.rejected_before = Some(t.beat.rejected);
                    t.beat = *beat;
                }
            }
            // A new service, or the same one restarted (its counters start over).
            _ => {
                self.services.insert(name, Tracked { beat: *beat, rejected_before: None });
            }
        }
    }

    /// The services seen so far.
    pub fn len(&self) -> usize {
        self.services.len()
    }

    pub fn is_empty(&self) -> bool {
        self.services.is_empty()
    }

    /// One DiagnosticArray with a status per service seen, as of `now_ns`.
    pub fn array(&self, now_ns: u64) -> DiagnosticArray {
        DiagnosticArray {
            header: Header { stamp: ns_to_time(now_ns), frame_id: String::new() },
            status: self
                .services
                .values()
                .map(|t| status_of(&t.beat, t.rejected_before, now_ns, self.silent_after_ns, &self.hardware_id))
                .collect(),
        }
    }
}

fn number(v: f64) -> String {
    if v.is_finite() { format!("{v:.3}") } else { "nan".to_string() }
}

/// One service's heartbeat as a DiagnosticStatus named `outlet/<service>`:
/// ERROR when the service has been silent for longer than `silent_after_ns`,
/// WARN when its rejections grew since `rejected_before` or nothing went out in
/// its last period, OK otherwise; the counters and latencies as key-values.
pub fn status_of(
    beat: &HeartbeatMsg,
    rejected_before: Option<u64>,
    now_ns: u64,
    silent_after_ns: u64,
    hardware_id: &str,
) -> DiagnosticStatus {
    let silent_ns = now_ns.saturating_sub(beat.published_ns);
    let new_rejections = beat.rejected.saturating_sub(rejected_before.unwrap_or(0));
    let (level, message) = if silent_ns > silent_after_ns {
        (DiagnosticStatus::ERROR, format!("silent for {:.1} s", silent_ns as f64 / 1e9))
    } else if new_rejections > 0 {
        (DiagnosticStatus::WARN, format!("{new_rejections} rejected: {}", beat.last_rejection()))
    } else if beat.output_rate_hz <= 0.0 {
        (DiagnosticStatus::WARN, format!("no output in the last period ({} Hz in)", number(beat.input_rate_hz)))
    } else {
        (
            DiagnosticStatus::OK,
            format!("{} Hz out, latency p50 {} ms", number(beat.output_rate_hz), number(beat.latency_p50_ms)),
        )
    };
    let kv = |key: &str, value: String| KeyValue { key: key.to_string(), value };
    DiagnosticStatus {
        level,
        name: format!("outlet/{}", beat.service_name()),
        message,
        hardware_id: hardware_id.to_string(),
        values: vec![
            kv("pid", beat.pid.to_string()),
            kv("sequence", beat.sequence.to_string()),
            kv("inputs", beat.inputs.to_string()),
            kv("outputs", beat.outputs.to_string()),
            kv("rejected", beat.rejected.to_string()),
            kv("dropped", beat.dropped.to_string()),
            kv("input_rate_hz", number(beat.input_rate_hz)),
            kv("output_rate_hz", number(beat.output_rate_hz)),
            kv("latency_p50_ms", number(beat.latency_p50_ms)),
            kv("latency_p99_ms", number(beat.latency_p99_ms)),
            kv("latency_max_ms", number(beat.latency_max_ms)),
            kv("work_p50_ms", number(beat.work_p50_ms)),
            kv("work_p99_ms", number(beat.work_p99_ms)),
            kv("silent_ms", number(silent_ns as f64 / 1e6)),
            kv("last_rejection", beat.last_rejection().to_string()),
        ],
    }
}

/// The heartbeats as one DiagnosticArray (each beat taken as its service's
/// newest, without the history of [`Diagnostics`]).
pub fn diagnostics_of(beats: &[HeartbeatMsg], now_ns: u64, silent_after_ns: u64, hardware_id: &str) -> DiagnosticArray {
    let mut d = Diagnostics::new(silent_after_ns, hardware_id);
    beats.iter().for_each(|b| d.update(b));
    d.array(now_ns)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn compressed(format: image::ImageFormat, name: &str) -> (image::RgbImage, CompressedImage) {
        let rgb = image::RgbImage::from_fn(40, 30, |x, y| image::Rgb([(x * 6) as u8, (y * 8) as u8, 128]));
        let mut data = Vec::new();
        rgb.write_to(&mut std::io::Cursor::new(&mut data), format).expect("encodes");
        let header = Header { stamp: Time { sec: 3, nanosec: 4 }, frame_id: "cam".into() };
        (rgb, CompressedImage { header, format: name.into(), data })
    }

    #[test]
    fn png_and_jpeg_compressed_images_become_rgb8_images() {
        let (rgb, png) = compressed(image::ImageFormat::Png, "png");
        let image = image_of_compressed(&png).expect("png");
        assert_eq!((image.width, image.height, image.step, image.encoding.as_str()), (40, 30, 120, "rgb8"));
        assert_eq!(image.header, png.header);
        assert_eq!(image.data, rgb.as_raw().clone(), "PNG is lossless");
        // image_transport's format string says more than the codec; the bytes decide.
        let (rgb, jpeg) = compressed(image::ImageFormat::Jpeg, "rgb8; jpeg compressed bgr8");
        let image = image_of_compressed(&jpeg).expect("jpeg");
        assert_eq!((image.width, image.height), (40, 30));
        let worst = image.data.iter().zip(rgb.as_raw()).map(|(a, b)| a.abs_diff(*b)).max().unwrap_or(u8::MAX);
        assert!(worst < 40, "JPEG off by {worst} grey levels");
    }

    #[test]
    fn compressed_data_that_is_not_an_image_is_refused_with_its_format() {
        let header = Header::default();
        for data in [Vec::new(), b"not an image at all".to_vec(), vec![0x89, b'P', b'N', b'G', 13, 10, 26, 10, 0, 0]] {
            let msg = CompressedImage { header: header.clone(), format: "png".into(), data };
            match image_of_compressed(&msg) {
                Err(Rejection::Compressed { format, .. }) => assert_eq!(format, "png"),
                other => panic!("{other:?}"),
            }
        }
        // A PNG whose header claims 100000 pixels a side: refused, nothing allocated for it.
        let (_, mut png) = compressed(image::ImageFormat::Png, "png");
        png.data[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        assert!(image_of_compressed(&png).is_err());
    }

    use crate::msgs::RegionOfInterest;
    use nalgebra::Vector3;
    use outlet_protocol::wire::{MAX_HOLES, SCHEMA_VERSION};

    fn info(width: u32, height: u32) -> CameraInfo {
        CameraInfo {
            header: Header::default(),
            height,
            width,
            distortion_model: "plumb_bob".into(),
            d: vec![-0.06, 0.03, 0.0, 0.0, 0.0],
            k: [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [525.0, 0.0, 319.5, 0.0, 0.0, 525.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest::default(),
        }
    }

    fn image(encoding: &str, width: u32, height: u32, step: u32) -> Image {
        Image {
            header: Header { stamp: Time { sec: 1_700_000_000, nanosec: 250 }, frame_id: "cam".into() },
            height,
            width,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data: (0..step * height).map(|v| v as u8).collect(),
        }
    }

    #[test]
    fn ros_times_and_nanoseconds_convert_both_ways() {
        let t = Time { sec: 1_700_000_000, nanosec: 123_456_789 };
        assert_eq!(time_to_ns(t), Some(1_700_000_000_123_456_789));
        assert_eq!(ns_to_time(1_700_000_000_123_456_789), t);
        assert_eq!(time_to_ns(Time::default()), Some(0));
        assert_eq!(time_to_ns(Time { sec: -1, nanosec: 0 }), None);
        assert_eq!(time_to_ns(Time { sec: 1, nanosec: 1_000_000_000 }), None);
        assert_eq!(ns_to_time(u64::MAX), Time { sec: i32::MAX, nanosec: 999_999_999 });
    }

    #[test]
    fn an_image_with_its_camera_info_becomes_a_frame() {
        let img = image("rgb8", 640, 480, 640 * 3 + 8);
        let (header, pixels, camera) = frame_from(&img, &info(640, 480), 7).expect("bridged");
        assert_eq!(camera, CameraModel::default_vga());
        assert_eq!(header.frame_id, 7);
        assert_eq!(header.capture_time_ns, 1_700_000_000_000_000_250);
        assert_eq!(header.stride, 640 * 3 + 8);
        assert_eq!(PixelFormat::from_code(header.pixel_format), Some(PixelFormat::Rgb8));
        assert_eq!(header.intrinsics, [525.0, 525.0, 319.5, 239.5]);
        assert_eq!(header.distortion, [-0.06, 0.03, 0.0, 0.0, 0.0]);
        assert_eq!(pixels.len(), (640 * 3 + 8) * 480);
        assert!(header.validate(pixels.len()).is_ok());
        for (encoding, format) in [("mono8", PixelFormat::Mono8), ("bgr8", PixelFormat::Bgr8)] {
            let (h, _, _) = frame_from(&image(encoding, 640, 480, 640 * 3), &info(640, 480), 1).expect(encoding);
            assert_eq!(h.pixel_format, format as u32);
        }
    }

    #[test]
    fn extra_image_data_is_left_out() {
        let mut img = image("mono8", 4, 2, 4);
        img.data.extend([1, 2, 3]);
        let camera = CameraModel::new(4, 2, [3.0, 3.0, 2.0, 1.0], [0.0; 5]).expect("camera");
        let (_, pixels) = frame_of(&img, Some(&camera), 1).expect("bridged");
        assert_eq!(pixels, &img.data[..8]);
    }

    #[test]
    fn images_that_do_not_fit_are_rejected_saying_why() {
        let camera = camera_of(&info(640, 480)).expect("camera");
        let reject = |img: &Image, camera: Option<&CameraModel>| frame_of(img, camera, 1).expect_err("rejected");
        assert_eq!(reject(&image("yuv422", 640, 480, 1280), Some(&camera)), Rejection::Encoding("yuv422".into()));
        assert_eq!(reject(&image("RGB8", 640, 480, 1920), Some(&camera)), Rejection::Encoding("RGB8".into()));
        let mut short = image("rgb8", 640, 480, 1920);
        short.data.truncate(1920 * 479);
        assert_eq!(
            reject(&short, Some(&camera)),
            Rejection::ShortImage { got: 1920 * 479, height: 480, step: 1920, expected: 1920 * 480 }
        );
        assert_eq!(
            reject(&image("rgb8", 640, 480, 1000), Some(&camera)),
            Rejection::Step { step: 1000, width: 640, channels: 3 }
        );
        assert!(matches!(reject(&image("mono8", 0, 480, 0), Some(&camera)), Rejection::EmptyImage { .. }));
        assert_eq!(reject(&image("rgb8", 640, 480, 1920), None), Rejection::NoCameraInfo);
        assert!(matches!(reject(&image("rgb8", 320, 240, 960), Some(&camera)), Rejection::SizeMismatch { .. }));
        let mut before_epoch = image("rgb8", 640, 480, 1920);
        before_epoch.header.stamp.sec = -5;
        assert!(matches!(reject(&before_epoch, Some(&camera)), Rejection::Stamp { what: "image", sec: -5, .. }));
        // A message says what was wrong, with the value.
        let text = reject(&image("yuv422", 640, 480, 1280), Some(&camera)).to_string();
        assert!(text.contains("yuv422"), "{text}");
    }

    #[test]
    fn camera_infos_that_do_not_describe_a_pinhole_are_rejected() {
        let mut none = info(640, 480);
        none.distortion_model = String::new();
        none.d.clear();
        assert!(camera_of(&none).expect("no distortion").is_rectified());
        let mut zeros = info(640, 480);
        zeros.distortion_model = "rational_polynomial".into();
        zeros.d = vec![0.0; 8];
        assert!(camera_of(&zeros).expect("zero coefficients").is_rectified());
        let mut fisheye = info(640, 480);
        fisheye.distortion_model = "equidistant".into();
        fisheye.d = vec![0.1, 0.0, 0.0, 0.0];
        assert!(matches!(camera_of(&fisheye), Err(Rejection::Distortion { coefficients: 4, .. })));
        let mut uncalibrated = info(640, 480);
        uncalibrated.k = [0.0; 9];
        assert!(matches!(camera_of(&uncalibrated), Err(Rejection::Intrinsics { .. })));
        let mut binned = info(640, 480);
        binned.binning_x = 2;
        assert!(matches!(camera_of(&binned), Err(Rejection::Binning { x: 2, y: 0 })));
        let mut skewed = info(640, 480);
        skewed.k[1] = 3.0;
        assert!(matches!(camera_of(&skewed), Err(Rejection::Skew { .. })));
        let mut nan = info(640, 480);
        nan.d[0] = f64::NAN;
        assert!(matches!(camera_of(&nan), Err(Rejection::Intrinsics { .. })));
    }

    fn field(name: &str, offset: u32, datatype: u8) -> PointField {
        PointField { name: name.into(), offset, datatype, count: 1 }
    }

    /// A cloud of `points` with x, y, z float32 at `offsets` in points of
    /// `point_step` bytes (other bytes 0xEE), `width` per row padded to `row_step`.
    fn cloud(points: &[[f32; 3]], offsets: [u32; 3], point_step: u32, width: u32, row_step: u32) -> PointCloud2 {
        let height = points.len() as u32 / width;
        let mut data = vec![0xEE; (row_step * height) as usize];
        for (k, p) in points.iter().enumerate() {
            let (row, col) = (k as u32 / width, k as u32 % width);
            let base = (row * row_step + col * point_step) as usize;
            for (v, o) in p.iter().zip(offsets) {
                data[base + o as usize..base + o as usize + 4].copy_from_slice(&v.to_le_bytes());
            }
        }
        PointCloud2 {
            header: Header { stamp: Time { sec: 3, nanosec: 4 }, frame_id: "cam".into() },
            height,
            width,
            fields: vec![
                field("intensity", 0, PointField::FLOAT32),
                field("z", offsets[2], PointField::FLOAT32),
                field("x", offsets[0], PointField::FLOAT32),
                field("y", offsets[1], PointField::FLOAT32),
            ],
            is_bigendian: false,
            point_step,
            row_step,
            data,
            is_dense: false,
        }
    }

    fn sample_points() -> Vec<[f32; 3]> {
        (0..12).map(|k| [k as f32, -(k as f32) * 0.5, if k == 5 { f32::NAN } else { 1.0 + k as f32 }]).collect()
    }

    fn same(a: &[f32], b: &[[f32; 3]]) -> bool {
        a.len() == 3 * b.len() && a.iter().zip(b.iter().flatten()).all(|(x, y)| x == y || (x.is_nan() && y.is_nan()))
    }

    #[test]
    fn clouds_give_xyz_at_any_offsets_steps_and_row_padding() {
        let points = sample_points();
        // Plain xyz, packed.
        let (stamp, xyz) = xyz_of(&cloud(&points, [0, 4, 8], 12, 12, 144)).expect("packed");
        assert_eq!(stamp, 3_000_000_004);
        assert!(same(&xyz, &points));
        // Intensity first, then z, x, y; 20-byte points; organised 4x3 with padded rows.
        let (_, xyz) = xyz_of(&cloud(&points, [8, 12, 4], 20, 4, 4 * 20 + 6)).expect("shuffled");
        assert!(same(&xyz, &points), "NaN kept, order kept");
        // An odd point_step: unaligned floats.
        let (_, xyz) = xyz_of(&cloud(&points, [1, 5, 9], 13, 3, 39)).expect("odd point_step");
        assert!(same(&xyz, &points));
        // The last row without its padding is enough data.
        let mut c = cloud(&points, [0, 4, 8], 12, 4, 64);
        c.data.truncate(c.data.len() - 16);
        assert!(same(&xyz_of(&c).expect("unpadded last row").1, &points));
        // No points at all.
        let empty = PointCloud2 { width: 0, height: 1, ..cloud(&points, [0, 4, 8], 12, 12, 144) };
        assert!(xyz_of(&empty).expect("empty").1.is_empty());
    }

    #[test]
    fn what_a_driver_would_publish_comes_back_as_it_went() {
        let camera = CameraModel::default_vga();
        let header = Header { stamp: Time { sec: 9, nanosec: 8 }, frame_id: "cam".into() };
        assert_eq!(camera_of(&camera_info_of(&camera, header.clone())), Ok(camera));
        let rgb: Vec<u8> = (0..640 * 480 * 3).map(|v| (v % 253) as u8).collect();
        let bgr = image_of(header.clone(), 640, 480, &rgb, PixelFormat::Bgr8, 1928).expect("image");
        let (frame, pixels) = frame_of(&bgr, Some(&camera), 1).expect("frame");
        assert_eq!((frame.stride, frame.capture_time_ns), (1928, 9_000_000_008));
        assert_eq!(&pixels[..6], &[rgb[2], rgb[1], rgb[0], rgb[5], rgb[4], rgb[3]]);
        assert_eq!(&pixels[1920..1928], &[0; 8], "padding");
        assert!(image_of(header.clone(), 640, 480, &rgb, PixelFormat::Rgb8, 100).is_none());
        let mono = image_of(header.clone(), 640, 480, &rgb, PixelFormat::Mono8, 640).expect("mono");
        assert_eq!(mono.data[0], ((rgb[0] as u16 + rgb[1] as u16 + rgb[2] as u16) / 3) as u8);
        let points = sample_points();
        let (stamp, xyz) = xyz_of(&cloud_of(header, &points)).expect("cloud");
        assert_eq!(stamp, 9_000_000_008);
        assert!(same(&xyz, &points));
    }

    #[test]
    fn a_frame_from_shared_memory_becomes_an_image_and_its_camera_info_and_back() {
        let camera =
            CameraModel::new(4, 2, [500.0, 501.0, 1.5, 0.5], [-0.1, 0.01, 0.001, -0.002, 0.0]).expect("camera");
        let mut frame = FrameHeader::new(7, 1_700_000_000_250_000_000, PixelFormat::Bgr8, &camera);
        frame.stride = 14;
        let pixels: Vec<u8> = (0..28).collect();
        let (image, info) = image_and_info_of(&frame, &pixels, "cam").expect("converted");
        assert_eq!((image.width, image.height, image.step, image.encoding.as_str()), (4, 2, 14, "bgr8"));
        assert_eq!(image.data, pixels);
        assert_eq!(image.header.stamp, Time { sec: 1_700_000_000, nanosec: 250_000_000 });
        assert_eq!(info.header, image.header);
        assert_eq!(info.k, [500.0, 0.0, 1.5, 0.0, 501.0, 0.5, 0.0, 0.0, 1.0]);
        assert_eq!(info.d, camera.distortion.to_vec());
        let (back, back_pixels, back_camera) = frame_from(&image, &info, 7).expect("back");
        assert_eq!((back, back_pixels, back_camera), (frame, &pixels[..], camera));
        assert!(matches!(image_and_info_of(&frame, &pixels[..27], "cam"), Err(Rejection::Frame(_))));
        // Flat x, y, z values; an incomplete last point is left out.
        let (_, xyz) = xyz_of(&cloud_of_xyz(image.header, &[1.0, 2.0, 3.0, f32::NAN, 5.0, 6.0, 7.0])).expect("cloud");
        assert!(same(&xyz, &[[1.0, 2.0, 3.0], [f32::NAN, 5.0, 6.0]]));
    }

    #[test]
    fn clouds_that_do_not_fit_are_rejected_saying_why() {
        let points = sample_points();
        let good = cloud(&points, [0, 4, 8], 16, 12, 192);
        let mut missing = good.clone();
        missing.fields.retain(|f| f.name != "y");
        assert_eq!(xyz_of(&missing), Err(Rejection::MissingField("y")));
        let mut double = good.clone();
        double.fields[1].datatype = PointField::FLOAT64;
        assert_eq!(
            xyz_of(&double),
            Err(Rejection::FieldType { name: "z", datatype: PointField::FLOAT64, datatype_name: "float64" })
        );
        let mut outside = good.clone();
        outside.fields[1].offset = 13;
        assert_eq!(xyz_of(&outside), Err(Rejection::FieldOffset { name: "z", offset: 13, point_step: 16 }));
        let mut short = good.clone();
        short.data.truncate(100);
        assert!(matches!(xyz_of(&short), Err(Rejection::ShortCloud { got: 100, .. })));
        let mut rows = good.clone();
        rows.row_step = 100;
        assert!(matches!(xyz_of(&rows), Err(Rejection::RowStep { row_step: 100, .. })));
        let big = PointCloud2 { is_bigendian: true, ..good.clone() };
        assert_eq!(xyz_of(&big), Err(Rejection::BigEndian));
        let huge = PointCloud2 { width: u32::MAX, height: u32::MAX, row_step: u32::MAX, point_step: 16, ..good };
        assert!(xyz_of(&huge).is_err());
    }

    fn rotation(axis: Vector3<f64>, angle: f64) -> [f64; 9] {
        let r = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
        std::array::from_fn(|k| r[(k / 3, k % 3)])
    }

    #[test]
    fn rotations_round_trip_through_quaternions() {
        for (axis, angle) in [
            (Vector3::new(0.0, 0.0, 1.0), 0.0),
            (Vector3::new(1.0, 2.0, 3.0), 0.7),
            (Vector3::new(-1.0, 0.5, 0.2), 3.1),
            (Vector3::new(0.0, 1.0, 0.0), std::f64::consts::PI),
        ] {
            let m = rotation(axis, angle);
            let q = quaternion_of(&m).expect("a rotation");
            assert!(q.w >= 0.0);
            let back = q.to_rotation_matrix();
            for k in 0..9 {
                assert!((back[(k / 3, k % 3)] - m[k]).abs() < 1e-12, "{axis:?} {angle}");
            }
        }
        // About z by 90°: (0, 0, sin 45°, cos 45°).
        let q = quaternion_of(&rotation(Vector3::z(), std::f64::consts::FRAC_PI_2)).expect("a rotation");
        assert!((q.k - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12 && (q.w - q.k).abs() < 1e-12);
        assert!(quaternion_of(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0]).is_none(), "a reflection");
        assert!(quaternion_of(&[2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]).is_none(), "a scale");
        assert!(quaternion_of(&[f64::NAN; 9]).is_none());
    }

    fn hole_poses() -> HolePosesMsg {
        let mut positions_m = [[0.0; 3]; MAX_HOLES];
        for (k, p) in positions_m.iter_mut().take(6).enumerate() {
            *p = [0.01 * k as f64, -0.02, 0.5 + 0.001 * k as f64];
        }
        HolePosesMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 6,
            frame_id: 42,
            capture_time_ns: 1_700_000_000_500_000_000,
            published_ns: 0,
            mode: 3,
            status: 1,
            outlier_mask: 0,
            reserved: 0,
            rotation: rotation(Vector3::new(0.2, 1.0, 0.1), 0.4),
            translation_m: [0.02, -0.01, 0.5],
            kinds: [0; MAX_HOLES],
            positions_m,
            covariances_m2: [[0.0; 9]; MAX_HOLES],
        }
    }

    #[test]
    fn hole_poses_become_a_pose_array_and_a_pose_stamped() {
        let msg = hole_poses();
        let (array, stamped) = poses_of(&msg, "camera_optical_frame").expect("converted");
        let stamp = Time { sec: 1_700_000_000, nanosec: 500_000_000 };
        assert_eq!(array.header, Header { stamp, frame_id: "camera_optical_frame".into() });
        assert_eq!(stamped.header, array.header);
        assert_eq!(array.poses.len(), 6);
        for (pose, p) in array.poses.iter().zip(&msg.positions_m) {
            assert_eq!([pose.position.x, pose.position.y, pose.position.z], *p);
            assert_eq!(pose.orientation, stamped.pose.orientation);
        }
        assert_eq!([stamped.pose.position.x, stamped.pose.position.y, stamped.pose.position.z], msg.translation_m);
        let o = stamped.pose.orientation;
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(o.w, o.x, o.y, o.z));
        let expected = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(Vector3::new(0.2, 1.0, 0.1)), 0.4);
        assert!(q.to_rotation_matrix().angle_to(&expected) < 1e-12);
    }

    #[test]
    fn hole_poses_that_are_not_valid_are_rejected() {
        let mut wrong = hole_poses();
        wrong.rotation[0] = 3.0;
        assert!(matches!(poses_of(&wrong, "f"), Err(Rejection::Poses { frame_id: 42, .. })));
        // A result without a pose is not published as one.
        let none = HolePosesMsg { status: pose_status::AMBIGUOUS, hole_count: 0, ..hole_poses() };
        assert_eq!(poses_of(&none, "f").err(), Some(Rejection::NoPose { frame_id: 42, status: "ambiguous" }));
        let mismatch = HolePosesMsg { status: pose_status::PLANE_MISMATCH, hole_count: 0, ..hole_poses() };
        assert!(matches!(poses_of(&mismatch, "f"), Err(Rejection::NoPose { status: "plane_mismatch", .. })));
        let mut nan = hole_poses();
        nan.positions_m[2][1] = f64::NAN;
        assert!(poses_of(&nan, "f").is_err());
        let mut too_many = hole_poses();
        too_many.hole_count = MAX_HOLES as u32 + 1;
        assert!(poses_of(&too_many, "f").is_err());
        let mut schema = hole_poses();
        schema.schema_version = 99;
        assert!(poses_of(&schema, "f").is_err());
        let mut away = hole_poses();
        away.translation_m[0] = f64::INFINITY;
        assert!(poses_of(&away, "f").is_err());
    }

    fn beat(service: &str, sequence: u64, published_ns: u64, rejected: u64, output_rate_hz: f64) -> HeartbeatMsg {
        let mut b = HeartbeatMsg::new(service, 100, 0);
        b.sequence = sequence;
        b.published_ns = published_ns;
        b.rejected = rejected;
        b.output_rate_hz = output_rate_hz;
        b.latency_p50_ms = 12.5;
        b
    }

    #[test]
    fn heartbeats_become_diagnostics_ok_warn_or_error() {
        let s = 1_000_000_000u64;
        let now = 100 * s;
        let array = diagnostics_of(
            &[
                beat("detector", 1, now - s / 2, 0, 10.0),
                beat("pose", 1, now - 10 * s, 0, 10.0),
                beat("normal", 1, now, 0, 0.0),
            ],
            now,
            3 * s,
            "outlet",
        );
        assert_eq!(array.header.stamp, ns_to_time(now));
        let by_name: BTreeMap<&str, &DiagnosticStatus> = array.status.iter().map(|s| (s.name.as_str(), s)).collect();
        assert_eq!(by_name.len(), 3);
        assert_eq!(by_name["outlet/detector"].level, DiagnosticStatus::OK);
        assert_eq!(by_name["outlet/pose"].level, DiagnosticStatus::ERROR, "silent");
        assert!(by_name["outlet/pose"].message.contains("silent"));
        assert_eq!(by_name["outlet/normal"].level, DiagnosticStatus::WARN, "no output");
        let detector = by_name["outlet/detector"];
        assert_eq!(detector.hardware_id, "outlet");
        let value = |k: &str| detector.values.iter().find(|kv| kv.key == k).map(|kv| kv.value.as_str());
        assert_eq!(value("latency_p50_ms"), Some("12.500"));
        assert_eq!(value("rejected"), Some("0"));
        assert_eq!(value("latency_p99_ms"), Some("nan"));
    }

    #[test]
    fn growing_rejections_warn_until_they_stop() {
        let s = 1_000_000_000u64;
        let mut d = Diagnostics::new(3 * s, "outlet");
        let mut b = beat("ros2-bridge", 1, 10 * s, 0, 30.0);
        d.update(&b);
        assert_eq!(d.array(10 * s).status[0].level, DiagnosticStatus::OK);
        b.sequence = 2;
        b.rejected = 3;
        b.set_last_rejection("image: encoding \"yuv422\" is not mono8, rgb8 or bgr8");
        d.update(&b);
        let status = &d.array(11 * s).status[0];
        assert_eq!(status.level, DiagnosticStatus::WARN);
        assert!(status.message.contains("3 rejected") && status.message.contains("yuv422"), "{}", status.message);
        // An old beat again changes nothing; the next one without new rejections is OK.
        d.update(&b);
        b.sequence = 3;
        d.update(&b);
        assert_eq!(d.array(12 * s).status[0].level, DiagnosticStatus::OK);
        // The same service restarted (another pid) starts over.
        let mut restarted = beat("ros2-bridge", 1, 13 * s, 1, 30.0);
        restarted.pid = 101;
        d.update(&restarted);
        assert_eq!(d.len(), 1);
        assert_eq!(d.array(13 * s).status[0].level, DiagnosticStatus::WARN);
    }
}
