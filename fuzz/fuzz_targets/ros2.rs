//! ROS 2 messages as the bridge receives them from DDS: any bytes decoded as
//! CDR (little-endian, as rustdds hands them over) into `Image`, `CameraInfo`
//! or `PointCloud2`, then converted for the sidecar. Decoding or conversion
//! refuses or accepts; what it accepts is safe to publish.
#![no_main]

use libfuzzer_sys::fuzz_target;
use outlet_ros2_bridge::convert::{camera_of, frame_of, xyz_of};
use outlet_ros2_bridge::msgs::{CameraInfo, Image, PointCloud2};
use outlet_ros2_bridge::ros2_client::dds::rustdds::cdr_encoding;
use byteorder::LittleEndian;

fn decode<T: for<'de> serde::Deserialize<'de>>(bytes: &[u8]) -> Option<T> {
    cdr_encoding::from_bytes::<T, LittleEndian>(bytes).ok().map(|(value, _)| value)
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, data)) = data.split_first() else { return };
    match which % 3 {
        0 => {
            // An image with a camera of its size, as its CameraInfo would give.
            let Some(image) = decode::<Image>(data) else { return };
            let camera = outlet_protocol::CameraModel::new(image.width, image.height, [500.0, 500.0, 320.0, 240.0], [0.0; 5]).ok();
            if let Ok((header, pixels)) = frame_of(&image, camera.as_ref(), 7) {
                let (format, _) = header.validate(pixels.len()).expect("an accepted frame passes the sidecar's check");
                assert!(header.stride as usize * header.height as usize <= pixels.len());
                assert!(header.width as usize * format.channels() <= header.stride as usize);
            }
        }
        1 => {
            let Some(info) = decode::<CameraInfo>(data) else { return };
            if let Ok(camera) = camera_of(&info) {
                // Every ray is finite at least near the principal point (far from it,
                // a wild distortion may leave the undistortion without a solution).
                assert!(camera.ray(nalgebra::Point2::new(camera.cx + 0.5, camera.cy)).iter().all(|v| v.is_finite()));
                let _ = camera.ray(nalgebra::Point2::new(0.0, 0.0));
            }
        }
        _ => {
            let Some(cloud) = decode::<PointCloud2>(data) else { return };
            if let Ok((_, xyz)) = xyz_of(&cloud) {
                assert_eq!(xyz.len() as u64, 3 * u64::from(cloud.width) * u64::from(cloud.height));
                assert!(xyz.len() <= 3 * cloud.data.len());
            }
        }
    }
});
