//! The wire contract of the sidecar: zero-copy types that cross iceoryx2 shared
//! memory, and the names of the services. Every header carries the schema
//! version; a reader checks it, and the sizes, before trusting a sample.

use crate::camera::CameraModel;
use iceoryx2::prelude::ZeroCopySend;

/// Version of the types in this module; bumped on any change of their layout.
pub const SCHEMA_VERSION: u32 = 1;

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
}

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
    /// 1 mono, 2 normal, 3 plane.
    pub mode: u32,
    pub reserved: u32,
    /// Outlet to camera: row-major rotation, translation (m).
    pub rotation: [f64; 9],
    pub translation_m: [f64; 3],
    /// Camera frame, metres, template order.
    pub positions_m: [[f64; 3]; MAX_HOLES],
    /// Row-major 3x3 covariance per hole (m²).
    pub covariances_m2: [[f64; 9]; MAX_HOLES],
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
}
