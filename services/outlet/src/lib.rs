//! What the `outlet` command shares with other programs and tests: the built-in
//! templates (trained from rendered views), the sidecar's configuration, and the
//! counters behind each service's heartbeat.

pub mod config;
pub mod health;
pub mod templates;

/// The wall plane fitted to a stereo cloud as the pose's measurement, with the
/// outlet's nominal face offset (its geometry's): what `outlet detect --points`,
/// `outlet eval` and its NEES table all solve plane mode from.
pub fn plane_measurement(
    plane: &outlet_normal::WallPlane,
    geometry: &outlet_protocol::OutletGeometry,
) -> outlet_pose::PlaneMeasurement {
    outlet_pose::PlaneMeasurement {
        normal: plane.normal,
        distance_m: plane.distance_m,
        covariance: plane.covariance,
        tangent: plane.tangent,
        face_offset_m: geometry.face_offset_mm / 1000.0,
    }
}
