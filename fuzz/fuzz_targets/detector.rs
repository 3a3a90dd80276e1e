//! The detector on any image from 0x0 to 256x256, any content, with no camera,
//! a plausible camera or any camera that `CameraModel::new` accepts; and on a
//! rendered outlet damaged by the fuzzer, to reach hashing and refinement.
#![no_main]

use arbitrary::{Arbitrary, Unstructured};
use image::RgbImage;
use libfuzzer_sys::fuzz_target;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::CameraModel;
use std::sync::OnceLock;

fn detector() -> &'static Detector {
    static DETECTOR: OnceLock<Detector> = OnceLock::new();
    DETECTOR.get_or_init(|| Detector::new(outlet_fuzz::template_2x1().clone(), DetectorParams::default()))
}

fn image(u: &mut Unstructured) -> arbitrary::Result<RgbImage> {
    if bool::arbitrary(u)? {
        // A rendered outlet, cropped and with bytes overwritten.
        let base = outlet_fuzz::outlet_image();
        let (w, h) = (u.int_in_range(0..=base.width())?, u.int_in_range(0..=base.height())?);
        let (x0, y0) = (u.int_in_range(0..=base.width() - w)?, u.int_in_range(0..=base.height() - h)?);
        let mut out = image::imageops::crop_imm(base, x0, y0, w, h).to_image();
        let raw: &mut [u8] = &mut out;
        let patches = u.int_in_range(0..=16)?;
        for _ in 0..patches {
            if raw.is_empty() {
                break;
            }
            let at = u.choose_index(raw.len())?;
            let len = u.int_in_range(1..=64usize)?.min(raw.len() - at);
            let value = u8::arbitrary(u)?;
            raw[at..at + len].fill(value);
        }
        Ok(out)
    } else {
        let (w, h) = (u.int_in_range(0..=256u32)?, u.int_in_range(0..=256u32)?);
        let bytes = u.bytes(u.len().min(w as usize * h as usize * 3))?.to_vec();
        let mut data = vec![0u8; w as usize * h as usize * 3];
        if !bytes.is_empty() {
            // The fuzzer's bytes, repeated over the image.
            for (d, s) in data.iter_mut().zip(bytes.iter().cycle()) {
                *d = *s;
            }
        }
        Ok(RgbImage::from_raw(w, h, data).unwrap_or_default())
    }
}

fn camera(u: &mut Unstructured, width: u32, height: u32) -> arbitrary::Result<Option<CameraModel>> {
    Ok(match u.int_in_range(0..=2u8)? {
        0 => None,
        1 => {
            // Plausible: the image's size, f 50-1000 px, distortion within +-0.5.
            let f = u.int_in_range(50..=1000u32)? as f64;
            let k =
                |u: &mut Unstructured| -> arbitrary::Result<f64> { Ok(u.int_in_range(-500..=500i32)? as f64 / 1000.0) };
            let distortion = [k(u)?, k(u)? / 4.0, k(u)? / 50.0, k(u)? / 50.0, k(u)? / 10.0];
            let (cx, cy) = (width as f64 / 2.0 - 0.5, height as f64 / 2.0 - 0.5);
            CameraModel::new(width.max(1), height.max(1), [f, f, cx, cy], distortion).ok()
        }
        _ => {
            // Anything that passes the camera's own checks, as a header might carry.
            let v: [f64; 9] = Arbitrary::arbitrary(u)?;
            let (w, h) = (u32::arbitrary(u)?, u32::arbitrary(u)?);
            CameraModel::new(w, h, [v[0], v[1], v[2], v[3]], [v[4], v[5], v[6], v[7], v[8]]).ok()
        }
    })
}

fuzz_target!(|data: &[u8]| {
    let mut u = Unstructured::new(data);
    let Ok(image) = image(&mut u) else { return };
    let Ok(camera) = camera(&mut u, image.width(), image.height()) else { return };
    let report = detector().detect(&image, camera.as_ref());
    if let Some(d) = report.detection {
        assert_eq!(d.holes.len(), detector().template().geometry.holes.len());
        assert!(d.holes.iter().all(|h| h.pixel.x.is_finite() && h.pixel.y.is_finite()));
    }
});
