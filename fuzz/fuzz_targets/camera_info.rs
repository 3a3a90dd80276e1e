//! The camera_info YAML reader on any text: a checked camera or an error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use outlet_protocol::camera_info::{parse_camera_info, write_camera_info};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    if let Ok(camera) = parse_camera_info(&text) {
        // A camera that was accepted is valid, and writes and reads back as itself.
        let again = outlet_protocol::CameraModel::new(
            camera.width,
            camera.height,
            [camera.fx, camera.fy, camera.cx, camera.cy],
            camera.distortion,
        );
        assert_eq!(again.as_ref().ok(), Some(&camera));
        let written = write_camera_info(&camera, "fuzz");
        assert_eq!(parse_camera_info(&written).ok(), Some(camera), "{written}");
        // What a camera does with pixels must not panic either.
        let _ = camera.ray(nalgebra::Point2::new(camera.cx + 1.0, camera.cy - 1.0));
    }
});
