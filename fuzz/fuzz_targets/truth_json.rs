//! Ground-truth records (`NAME.json` beside rendered images, read by `outlet
//! eval` and the tests) and the pose/plane objects inside them, on any bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use outlet_protocol::truth::{GroundTruth, PlaneJson, PoseJson};

fuzz_target!(|data: &[u8]| {
    if let Ok(truth) = serde_json::from_slice::<GroundTruth>(data) {
        if let Some(pose) = truth.pose {
            let _ = pose.to_isometry();
        }
        let _ = truth.wall_plane.signed_distance(&nalgebra::Point3::new(0.0, 0.0, 1.0));
        let c = &truth.camera;
        let k = c.camera_matrix;
        let _ =
            outlet_protocol::CameraModel::new(c.width, c.height, [k[0], k[4], k[2], k[5]], c.distortion_coefficients);
        let _ = serde_json::to_string(&truth);
    }
    if let Ok(pose) = serde_json::from_slice::<PoseJson>(data) {
        let _ = pose.to_isometry();
    }
    let _ = serde_json::from_slice::<PlaneJson>(data);
});
