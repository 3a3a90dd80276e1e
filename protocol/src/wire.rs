//! The wire contract of the sidecar: zero-copy types that cross iceoryx2 shared
//! memory, and the names of the services. Every header carries the schema
//! version; a reader checks it, and the sizes, before trusting a sample.

use crate::camera::CameraModel;
use iceoryx2::prelude::ZeroCopySend;

/// Version of the types in this module; bumped on any change of their layout.
pub const SCHEMA_VERSION: u32 = 3;

/// Service names, one place for every process.
pub mod service {
    /// Camera frames: [`super::FrameHeader`] user header, pixel bytes payload.
    pub const FRAMES: &str = "outlet/camera/frames";
    /// Stereo clouds: [`super::CloudHeader`] user header, `[x, y, z]` f32 payload.
    pub const CLOUDS: &str = "outlet/camera/cloud";
    /// Wall planes fitted to the clouds: [`super::WallPlaneMsg`].
    pub const PLANES: &str = "outlet/wall/plane";
    /// Detections: [`super::DetectionMsg`].
    pub const DETECTIONS: &str = "outlet/detector/detections";
    /// Hole poses: [`super::HolePosesMsg`].
    pub const HOLE_POSES: &str = "outlet/pose/holes";
    /// Every service's heartbeat: [`super::HeartbeatMsg`], one publisher per service.
    pub const HEARTBEAT: &str = "outlet/heartbeat";
    /// Each service's resolved configuration, postcard-encoded `[u8]`.
    pub const CONFIG: &str = "outlet/config";
    /// The simulated camera's ground truth: [`super::TruthMsg`].
    pub const TRUTH: &str = "outlet/sim/truth";
    /// Which file each frame of `outlet serve files` came from, and the files
    /// it skipped: [`super::FileFrameMsg`].
    pub const FILES: &str = "outlet/files/frames";
}

/// The largest frame a frame source publishes, pixel bytes (64 MiB: a
/// 22-megapixel RGB image). Every reader's share of a frame service holds
/// several frames of the largest size sent, in shared memory; `outlet serve
/// files` reports and skips a larger image before decoding it.
pub const MAX_FRAME_BYTES: usize = 64 << 20;

/// Holes a message carries at most (a 2x2 has 12).
pub const MAX_HOLES: usize = 24;

/// Pixel layouts a frame may have.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum PixelFormat {
    Mono8 = 1,
    Rgb8 = 2,
    Bgr8 = 3,
}

impl PixelFormat {
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            1 => Some(Self::Mono8),
            2 => Some(Self::Rgb8),
            3 => Some(Self::Bgr8),
            _ => None,
        }
    }

    pub fn channels(self) -> usize {
        match self {
            Self::Mono8 => 1,
            Self::Rgb8 | Self::Bgr8 => 3,
        }
    }
}

/// Why a sample from shared memory was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WireError {
    #[error("schema version {found}, this build speaks {expected}")]
    Schema { found: u32, expected: u32 },
    #[error("frame {frame_id}: size {width}x{height} is empty")]
    EmptyFrame { frame_id: u64, width: u32, height: u32 },
    #[error("frame {frame_id}: unknown pixel format code {code}")]
    UnknownFormat { frame_id: u64, code: u32 },
    #[error("frame {frame_id}: stride {stride} is less than width {width} x {channels} channels")]
    Stride { frame_id: u64, stride: u32, width: u32, channels: usize },
    #[error("frame {frame_id}: {got} bytes of pixels, {expected} needed")]
    ShortFrame { frame_id: u64, got: usize, expected: usize },
    #[error("frame {frame_id}: bad intrinsics: {reason}")]
    Intrinsics { frame_id: u64, reason: String },
    #[error("cloud {frame_id}: header says {claimed} points, payload holds {got}")]
    CloudSize { frame_id: u64, claimed: u64, got: usize },
    #[error("result for frame {frame_id}: {reason}")]
    Result { frame_id: u64, reason: &'static str },
}

/// The header of a camera frame; the pixels follow as the sample's `[u8]` payload,
/// `height` rows of `stride` bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("outlet::FrameHeader")]
pub struct FrameHeader {
    pub schema_version: u32,
    /// [`PixelFormat`] as its code.
    pub pixel_format: u32,
    pub frame_id: u64,
    /// Capture time, nanoseconds since the Unix epoch.
    pub capture_time_ns: u64,
    pub width: u32,
    pub height: u32,
    /// Bytes per row.
    pub stride: u32,
    pub reserved: u32,
    /// fx, fy, cx, cy (pixels).
    pub intrinsics: [f64; 4],
    /// plumb_bob k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
}

impl FrameHeader {
    pub fn new(frame_id: u64, capture_time_ns: u64, format: PixelFormat, camera: &CameraModel) -> Self {
        Self {
            schema_version: SCHEMA_VERSION,
            pixel_format: format as u32,
            frame_id,
            capture_time_ns,
            width: camera.width,
            height: camera.height,
            stride: camera.width * format.channels() as u32,
            reserved: 0,
            intrinsics: [camera.fx, camera.fy, camera.cx, camera.cy],
            distortion: camera.distortion,
        }
    }

    /// Checks the header against the payload's length; the camera it describes.
    pub fn validate(&self, payload_len: usize) -> Result<(PixelFormat, CameraModel), WireError> {
        let frame_id = self.frame_id;
        if self.schema_version != SCHEMA_VERSION {
            return Err(WireError::Schema { found: self.schema_version, expected: SCHEMA_VERSION });
        }
        if self.width == 0 || self.height == 0 {
            return Err(WireError::EmptyFrame { frame_id, width: self.width, height: self.height });
        }
        let format = PixelFormat::from_code(self.pixel_format)
            .ok_or(WireError::UnknownFormat { frame_id, code: self.pixel_format })?;
        let channels = format.channels();
        if (self.stride as usize) < self.width as usize * channels {
            return Err(WireError::Stride { frame_id, stride: self.stride, width: self.width, channels });
        }
        let expected = self.stride as usize * self.height as usize;
        if payload_len < expected {
            return Err(WireError::ShortFrame { frame_id, got: payload_len, expected });
        }
        let [fx, fy, cx, cy] = self.intrinsics;
        let camera = CameraModel::new(self.width, self.height, [fx, fy, cx, cy], self.distortion)
            .map_err(|e| WireError::Intrinsics { frame_id, reason: e.to_string() })?;
        Ok((format, camera))
    }
}

/// The header of a stereo cloud; the points follow as `[f32]`, x, y, z each
/// (camera frame, metres, NaN where stereo failed).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("outlet::CloudHeader")]
pub struct CloudHeader {
    pub schema_version: u32,
    pub reserved: u32,
    pub frame_id: u64,
    pub capture_time_ns: u64,
    pub points: u64,
}

impl CloudHeader {
    /// Checks the header against the payload's length (in f32 values).
    pub fn validate(&self, payload_values: usize) -> Result<(), WireError> {
        if self.schema_version != SCHEMA_VERSION {
            return Err(WireError::Schema { found: self.schema_version, expected: SCHEMA_VERSION });
        }
        if self.points.checked_mul(3).is_none_or(|n| n as usize > payload_values) {
            return Err(WireError::CloudSize {
                frame_id: self.frame_id,
                claimed: self.points,
                got: payload_values / 3,
            });
        }
        Ok(())
    }
}

/// A wall plane `normal · X = distance_m` (camera frame) with the covariance of
/// (δa, δb, δd) in the `tangent` basis.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("outlet::WallPlaneMsg")]
pub struct WallPlaneMsg {
    pub schema_version: u32,
    pub inliers: u32,
    pub frame_id: u64,
    pub capture_time_ns: u64,
    pub normal: [f64; 3],
    pub distance_m: f64,
    pub tangent: [[f64; 3]; 2],
    /// Row-major 3x3.
    pub covariance: [f64; 9],
}

/// One detected hole.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("outlet::HoleMsg")]
pub struct HoleMsg {
    /// 1 power, 2 ground.
    pub kind: u32,
    /// 1 when the sub-pixel fit found it, 0 when predicted from the others.
    pub refined: u32,
    /// Pixel in the image as captured.
    pub pixel: [f64; 2],
    /// Evidence in 0..1 that the hole was seen where the outlet's geometry puts it:
    /// its outline fitted there, with the predicted shape, contrast and a small
    /// residual (the detector's verification). Holes of a reported outlet are all
    /// verified; the score says how clearly.
    pub score: f64,
    /// Standard deviation of `pixel` per axis (pixels), from the sub-pixel fit's own
    /// residuals (with a floor).
    pub sigma_px: f64,
    /// How `sigma_px`'s variance divides among the image axes, `[xx, xy, yy]` of
    /// a symmetric matrix with trace 2: the pixel covariance is `sigma_px²` times
    /// it (a slot's centre is surer across it than along it). All zero where
    /// not given: the same on both axes.
    pub shape: [f64; 3],
}

/// The outlet found in a frame, or none (`hole_count` 0).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("outlet::DetectionMsg")]
pub struct DetectionMsg {
    pub schema_version: u32,
    pub hole_count: u32,
    pub frame_id: u64,
    pub capture_time_ns: u64,
    /// The paper's score S.
    pub score: u32,
    pub reserved: u32,
    pub detect_ms: f64,
    /// The frame's camera, so that a pose can be solved from this alone.
    pub width: u32,
    pub height: u32,
    /// fx, fy, cx, cy (pixels) and plumb_bob k1, k2, p1, p2, k3.
    pub intrinsics: [f64; 4],
    pub distortion: [f64; 5],
    pub holes: [HoleMsg; MAX_HOLES],
}

impl DetectionMsg {
    /// The camera the detection was made with.
    pub fn camera(&self) -> Result<CameraModel, WireError> {
        let [fx, fy, cx, cy] = self.intrinsics;
        CameraModel::new(self.width, self.height, [fx, fy, cx, cy], self.distortion)
            .map_err(|e| WireError::Intrinsics { frame_id: self.frame_id, reason: e.to_string() })
    }
}

/// Hole positions and the outlet's pose for one frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("outlet::HolePosesMsg")]
pub struct HolePosesMsg {
    pub schema_version: u32,
    pub hole_count: u32,
    pub frame_id: u64,
    pub capture_time_ns: u64,
    /// When the pose was published, nanoseconds since the Unix epoch.
    pub published_ns: u64,
    /// 1 mono, 2 normal, 3 plane: what the pose was (or, when `status` is not
    /// [`pose_status::OK`], would have been) solved with.
    pub mode: u32,
    /// [`pose_status`]: whether there is a pose to act on.
    pub status: u32,
    /// Bit k set: hole k's pixel could not be explained and was not used; its
    /// position comes from the other holes through the outlet's geometry.
    pub outlier_mask: u32,
    pub reserved: u32,
    /// Outlet to camera: row-major rotation, translation (m); NaN unless `status`
    /// is [`pose_status::OK`].
    pub rotation: [f64; 9],
    pub translation_m: [f64; 3],
    /// 1 power, 2 ground, per hole.
    pub kinds: [u32; MAX_HOLES],
    /// Camera frame, metres, template order.
    pub positions_m: [[f64; 3]; MAX_HOLES],
    /// Row-major 3x3 covariance per hole (m²).
    pub covariances_m2: [[f64; 9]; MAX_HOLES],
}

/// [`HolePosesMsg::status`] codes.
pub mod pose_status {
    /// The holes and the pose hold, within their covariances.
    pub const OK: u32 = 1;
    /// From pixels alone (mono) two mirror poses explain the holes about equally:
    /// no pose, no holes (`hole_count` 0).
    pub const AMBIGUOUS: u32 = 2;
    /// A wall plane was measured but cannot explain the detected holes (a wrong
    /// hole, or a plane of something else): no pose, no holes. Never quietly
    /// solved from the pixels alone instead.
    pub const PLANE_MISMATCH: u32 = 3;
}

impl HolePosesMsg {
    /// Whether the message is one this build can read: a known status, finite
    /// positions, and no holes unless the status is [`pose_status::OK`].
    pub fn validate(&self) -> Result<(), WireError> {
        if self.schema_version != SCHEMA_VERSION {
            return Err(WireError::Schema { found: self.schema_version, expected: SCHEMA_VERSION });
        }
        let n = self.hole_count as usize;
        if n > MAX_HOLES || !self.positions_m[..n].iter().flatten().all(|v| v.is_finite()) {
            return Err(WireError::Result { frame_id: self.frame_id, reason: "hole count or positions invalid" });
        }
        match self.status {
            pose_status::OK => Ok(()),
            pose_status::AMBIGUOUS | pose_status::PLANE_MISMATCH if n == 0 => Ok(()),
            pose_status::AMBIGUOUS | pose_status::PLANE_MISMATCH => {
                Err(WireError::Result { frame_id: self.frame_id, reason: "holes in a result without a pose" })
            }
            _ => Err(WireError::Result { frame_id: self.frame_id, reason: "unknown status" }),
        }
    }
}

/// A fixed-size, NUL-padded text field.
fn text<const N: usize>(s: &str) -> [u8; N] {
    let mut out = [0u8; N];
    // Cut at a character boundary so the field stays valid UTF-8.
    let mut end = s.len().min(N);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    out[..end].copy_from_slice(&s.as_bytes()[..end]);
    out
}

fn text_str(bytes: &[u8]) -> &str {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    match std::str::from_utf8(&bytes[..end]) {
        Ok(s) => s,
        Err(e) => std::str::from_utf8(&bytes[..e.valid_up_to()]).unwrap_or(""),
    }
}

/// A service's health, published periodically: what came in, what went out,
/// what was refused, and how long it took over the last period.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("outlet::HeartbeatMsg")]
pub struct HeartbeatMsg {
    pub schema_version: u32,
    pub pid: u32,
    /// The service's name (`detector`, `normal`, `pose`, `sim-camera`), NUL-padded.
    pub service: [u8; 16],
    pub sequence: u64,
    /// Nanoseconds since the Unix epoch.
    pub published_ns: u64,
    pub started_ns: u64,
    /// Totals since the service started.
    pub inputs: u64,
    pub outputs: u64,
    pub rejected: u64,
    /// Inputs skipped because a newer one was already waiting.
    pub dropped: u64,
    /// Rates over the last period (Hz).
    pub input_rate_hz: f64,
    pub output_rate_hz: f64,
    /// Capture to publish over the last period (ms); NaN when nothing went out.
    pub latency_p50_ms: f64,
    pub latency_p99_ms: f64,
    pub latency_max_ms: f64,
    /// The service's own work per input over the last period (ms).
    pub work_p50_ms: f64,
    pub work_p99_ms: f64,
    /// When the last output went out (ns since the Unix epoch, 0 never).
    pub last_output_ns: u64,
    /// Why the last input was refused, NUL-padded.
    pub last_rejection: [u8; 120],
}

impl HeartbeatMsg {
    pub fn new(service: &str, pid: u32, started_ns: u64) -> Self {
        Self {
            schema_version: SCHEMA_VERSION,
            pid,
            service: text(service),
            sequence: 0,
            published_ns: 0,
            started_ns,
            inputs: 0,
            outputs: 0,
            rejected: 0,
            dropped: 0,
            input_rate_hz: 0.0,
            output_rate_hz: 0.0,
            latency_p50_ms: f64::NAN,
            latency_p99_ms: f64::NAN,
            latency_max_ms: f64::NAN,
            work_p50_ms: f64::NAN,
            work_p99_ms: f64::NAN,
            last_output_ns: 0,
            last_rejection: [0; 120],
        }
    }

    pub fn service_name(&self) -> &str {
        text_str(&self.service)
    }

    pub fn last_rejection(&self) -> &str {
        text_str(&self.last_rejection)
    }

    pub fn set_last_rejection(&mut self, reason: &str) {
        self.last_rejection = text(reason);
    }
}

/// What the simulated camera rendered: the holes where they really are.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("outlet::TruthMsg")]
pub struct TruthMsg {
    pub schema_version: u32,
    /// 0 when the frame shows no outlet of the template.
    pub hole_count: u32,
    pub frame_id: u64,
    pub capture_time_ns: u64,
    /// Camera frame, metres, template order.
    pub positions_m: [[f64; 3]; MAX_HOLES],
    /// Outlet to camera: row-major rotation, translation (m).
    pub rotation: [f64; 9],
    pub translation_m: [f64; 3],
}

/// [`FileFrameMsg::status`] codes.
pub mod file_status {
    /// The file went out as frame `frame_id` (with its cloud, if any).
    pub const SENT: u32 = 1;
    /// The file could not be sent (`reason` says why) and is skipped.
    pub const SKIPPED: u32 = 2;
    /// Every file has been through once and no more will come (no `--loop`).
    pub const END: u32 = 3;
}

/// What `outlet serve files` did with one file of its list, published after
/// the frame: the frame's file for whoever wants to name it (`outlet demo
/// --images`), a skipped file and why, or the end of the list. The pipeline's
/// services never read it: to them the frames are a camera's.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("outlet::FileFrameMsg")]
pub struct FileFrameMsg {
    pub schema_version: u32,
    /// [`file_status`].
    pub status: u32,
    /// The file's place in the sorted list (from 0) and the pass through it
    /// (from 0; more than one with `--loop`).
    pub index: u32,
    pub pass: u32,
    /// Files in the list.
    pub files: u32,
    pub reserved: u32,
    /// The frame the file went out as; 0 when it did not.
    pub frame_id: u64,
    pub capture_time_ns: u64,
    /// The image's path, NUL-padded UTF-8 (cut at 1024 bytes).
    pub image: [u8; 1024],
    /// Why it was skipped, NUL-padded.
    pub reason: [u8; 256],
}

impl FileFrameMsg {
    pub fn new(status: u32, index: u32, pass: u32, files: u32, image: &str) -> Self {
        Self {
            schema_version: SCHEMA_VERSION,
            status,
            index,
            pass,
            files,
            reserved: 0,
            frame_id: 0,
            capture_time_ns: 0,
            image: text(image),
            reason: [0; 256],
        }
    }

    pub fn image(&self) -> &str {
        text_str(&self.image)
    }

    pub fn reason(&self) -> &str {
        text_str(&self.reason)
    }

    pub fn set_reason(&mut self, reason: &str) {
        self.reason = text(reason);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> FrameHeader {
        FrameHeader::new(7, 123, PixelFormat::Rgb8, &CameraModel::default_vga())
    }

    #[test]
    fn frame_headers_are_checked_against_their_payload() {
        let h = header();
        assert!(h.validate(640 * 480 * 3).is_ok());
        assert_eq!(h.validate(100), Err(WireError::ShortFrame { frame_id: 7, got: 100, expected: 640 * 480 * 3 }));
        assert!(matches!(FrameHeader { width: 0, ..h }.validate(1 << 20), Err(WireError::EmptyFrame { .. })));
        assert!(matches!(
            FrameHeader { pixel_format: 9, ..h }.validate(1 << 20),
            Err(WireError::UnknownFormat { code: 9, .. })
        ));
        assert!(matches!(FrameHeader { stride: 10, ..h }.validate(1 << 22), Err(WireError::Stride { .. })));
        assert!(matches!(FrameHeader { schema_version: 99, ..h }.validate(1 << 22), Err(WireError::Schema { .. })));
        let nan = FrameHeader { intrinsics: [f64::NAN, 525.0, 320.0, 240.0], ..h };
        assert!(matches!(nan.validate(1 << 22), Err(WireError::Intrinsics { .. })));
    }

    #[test]
    fn cloud_headers_cannot_claim_more_points_than_they_carry() {
        let c =
            CloudHeader { schema_version: SCHEMA_VERSION, reserved: 0, frame_id: 1, capture_time_ns: 0, points: 10 };
        assert!(c.validate(30).is_ok());
        assert!(c.validate(29).is_err());
        assert!(CloudHeader { points: u64::MAX, ..c }.validate(30).is_err());
    }

    #[test]
    fn heartbeat_text_fields_round_trip_and_truncate_at_a_character() {
        let mut h = HeartbeatMsg::new("detector", 1, 0);
        assert_eq!(h.service_name(), "detector");
        let long = "é".repeat(100);
        h.set_last_rejection(&long);
        assert_eq!(h.last_rejection(), "é".repeat(60));
        assert_eq!(HeartbeatMsg::new("a-very-long-service-name", 1, 0).service_name(), "a-very-long-serv");
    }

    #[test]
    fn a_file_frame_names_its_image_and_why_it_was_skipped() {
        let mut m = FileFrameMsg::new(file_status::SKIPPED, 3, 0, 9, "/photos/bad.png");
        m.set_reason("not a PNG");
        assert_eq!((m.image(), m.reason(), m.status, m.index, m.files), ("/photos/bad.png", "not a PNG", 2, 3, 9));
        let long = format!("/{}", "ü".repeat(600));
        assert_eq!(FileFrameMsg::new(file_status::SENT, 0, 0, 1, &long).image().len(), 1023);
    }
}
