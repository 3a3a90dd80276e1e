//! What every outlet process shares: the camera model, the outlet geometry of
//! `CONTRACT.md`, the ground-truth record, and the camera_info YAML and PLY formats.
//!
//! Frames and units follow `CONTRACT.md`: the camera frame is REP 103's optical
//! frame (x right, y down, z forward, metres); pixels follow OpenCV (centre of the
//! top-left pixel at (0, 0)).

pub mod camera;
pub mod camera_info;
pub mod geometry;
pub mod math;
pub mod ply;
pub mod shm;
pub mod truth;
pub mod wire;

pub use camera::{CameraError, CameraModel};
pub use geometry::{HoleKind, OutletGeometry, TemplateHole};
