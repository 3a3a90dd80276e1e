//! JSON records of `CONTRACT.md`: the rendered ground truth, and the pose, hole
//! and plane objects that `outlet detect` reuses.

use crate::camera::CameraModel;
use crate::geometry::HoleKind;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// A rigid transform from the outlet frame to the camera frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseJson {
    /// Row-major rotation matrix.
    pub rotation: [[f64; 3]; 3],
    pub translation_m: [f64; 3],
}

impl PoseJson {
    pub fn from_isometry(pose: &Isometry3<f64>) -> Self {
        let r = pose.rotation.to_rotation_matrix();
        let m = r.matrix();
        let t = pose.translation.vector;
        Self {
            rotation: [
                [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
                [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
                [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
            ],
            translation_m: [t.x, t.y, t.z],
        }
    }

    /// The transform, with the rotation re-orthonormalised (JSON rounds it).
    pub fn to_isometry(&self) -> Isometry3<f64> {
        let r = self.rotation;
        let m = Matrix3::new(r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2]);
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&m));
        let t = self.translation_m;
        Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), rotation)
    }
}

/// One hole: its kind, its pixel in the image as written (distorted), its centre
/// in the camera frame (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HoleJson {
    pub kind: HoleKind,
    pub pixel: [f64; 2],
    pub position_m: Option<[f64; 3]>,
}

/// A plane `normal · X = distance_m` in the camera frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlaneJson {
    pub normal: [f64; 3],
    pub distance_m: f64,
}

impl PlaneJson {
    pub fn normal(&self) -> Vector3<f64> {
        Vector3::from(self.normal)
    }
    /// Signed distance of a point from the plane (metres).
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        self.normal().dot(&p.coords) - self.distance_m
    }
}

/// The camera as recorded beside rendered images.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraJson {
    pub width: u32,
    pub height: u32,
    /// Row-major 3x3 K.
    pub camera_matrix: [f64; 9],
    pub distortion_model: String,
    pub distortion_coefficients: [f64; 5],
}

impl From<&CameraModel> for CameraJson {
    fn from(c: &CameraModel) -> Self {
        Self {
            width: c.width,
            height: c.height,
            camera_matrix: [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
            distortion_model: "plumb_bob".into(),
            distortion_coefficients: c.distortion,
        }
    }
}

/// How the outlet was seen: what `outlet eval` plots detection rates against.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ViewJson {
    /// Distance from the camera centre to the outlet origin (metres).
    pub distance_m: f64,
    /// Angle between the line of sight to the outlet and the wall normal (degrees).
    pub off_axis_deg: f64,
    /// In-plane rotation of the outlet in the image, 0 = upright ground down (degrees).
    pub roll_deg: f64,
    pub ground_up: bool,
}

/// The ground truth that `outlet render` writes beside each image (`NAME.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    pub image: String,
    pub scenario: String,
    /// The outlet in the image, `null` when none of the sought kind is there.
    pub template: Option<String>,
    /// The template a detector should look for in this image.
    pub search_template: String,
    pub pose: Option<PoseJson>,
    pub holes: Vec<HoleJson>,
    pub wall_plane: PlaneJson,
    pub camera: CameraJson,
    pub view: Option<ViewJson>,
}
