//! Inputs the `ros2` fuzz target (fuzz/fuzz_targets/ros2.rs) found, kept so that
//! plain `cargo test` runs them: the first byte picks the message (0 Image,
//! 1 CameraInfo, 2 PointCloud2), the rest is its CDR body as rustdds hands it over.

use byteorder::LittleEndian;
use outlet_ros2_bridge::convert::{camera_of, frame_of, xyz_of};
use outlet_ros2_bridge::msgs::{CameraInfo, Image, PointCloud2};
use outlet_ros2_bridge::ros2_client::dds::rustdds::cdr_encoding;
use std::path::Path;

fn regression(name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions/ros2").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn a_camera_info_with_a_focal_length_of_1e_minus_37_is_refused_naming_it() {
    // It was accepted, and every ray through the camera was infinite.
    let bytes = regression("camera-info-tiny-focal-length");
    assert_eq!(bytes[0] % 3, 1, "a CameraInfo");
    let (info, _) = cdr_encoding::from_bytes::<CameraInfo, LittleEndian>(&bytes[1..]).expect("decodes");
    assert!(info.k[0] > 0.0 && info.k[0] < 1e-30, "fx = {}", info.k[0]);
    let err = camera_of(&info).expect_err("refused");
    assert!(err.to_string().contains("focal length"), "{err}");
}

#[test]
fn a_camera_info_with_a_distortion_coefficient_of_1e306_is_refused_naming_it() {
    // It was accepted, and the ray through the principal point overflowed.
    let bytes = regression("camera-info-huge-distortion");
    assert_eq!(bytes[0] % 3, 1, "a CameraInfo");
    let (info, _) = cdr_encoding::from_bytes::<CameraInfo, LittleEndian>(&bytes[1..]).expect("decodes");
    assert!(info.d.iter().any(|k| k.abs() > 1e300), "d = {:?}", info.d);
    let err = camera_of(&info).expect_err("refused");
    assert!(err.to_string().contains("distortion coefficient"), "{err}");
}

#[test]
fn every_kept_input_is_refused_or_converted_without_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions/ros2");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).expect("the regressions folder") {
        let bytes = std::fs::read(entry.expect("an entry").path()).expect("readable");
        let Some((&which, body)) = bytes.split_first() else { continue };
        match which % 3 {
            1 => {
                if let Ok((info, _)) = cdr_encoding::from_bytes::<CameraInfo, LittleEndian>(body)
                    && let Ok(camera) = camera_of(&info)
                {
                    assert!(camera.ray(nalgebra::Point2::new(camera.cx, camera.cy)).iter().all(|v| v.is_finite()));
                }
            }
            2 => {
                if let Ok((cloud, _)) = cdr_encoding::from_bytes::<PointCloud2, LittleEndian>(body) {
                    let _ = xyz_of(&cloud);
                }
            }
            _ => {
                if let Ok((image, _)) = cdr_encoding::from_bytes::<Image, LittleEndian>(body) {
                    let camera = outlet_protocol::CameraModel::new(
                        image.width,
                        image.height,
                        [500.0, 500.0, 320.0, 240.0],
                        [0.0; 5],
                    );
                    let _ = frame_of(&image, camera.ok().as_ref(), 0);
                }
            }
        }
        seen += 1;
    }
    assert!(seen >= 1, "no kept input in {}", dir.display());
}
