//! Template files on any bytes. The first byte chooses how the rest is used:
//! - as the file itself (the header's magic, version, length and CRC-32 refuse
//!   almost everything);
//! - as a payload behind a valid header, so that the postcard decoder is reached;
//! - as damage (byte overwrites) to a tiny real template's payload behind a valid
//!   header, so that the checks after decoding and detection with what passes
//!   them are reached.
//!
//! A template that loads must encode again and detect without panicking.
#![no_main]

use image::RgbImage;
use libfuzzer_sys::fuzz_target;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_detector::template::Template;

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else { return };
    let file = match mode % 3 {
        0 => rest.to_vec(),
        1 => outlet_fuzz::template_file(rest),
        _ => {
            let mut payload = outlet_fuzz::tiny_template_payload().to_vec();
            for patch in rest.chunks(3) {
                if let [hi, lo, value] = *patch {
                    let at = usize::from(u16::from_le_bytes([lo, hi])) % payload.len();
                    payload[at] = value;
                } else if let [cut, ..] = *patch {
                    // A short last patch truncates the payload.
                    payload.truncate(payload.len() * usize::from(cut) / 256);
                }
            }
            outlet_fuzz::template_file(&payload)
        }
    };
    let Ok(template) = Template::from_bytes(&file, "fuzz.template") else { return };
    let bytes = template.to_bytes().expect("a decoded template encodes");
    assert_eq!(Template::from_bytes(&bytes, "again").ok().as_ref(), Some(&template));
    let detector = Detector::new(template, DetectorParams::default());
    let image = RgbImage::from_fn(48, 40, |x, y| image::Rgb([((x * 5) ^ (y * 3)) as u8; 3]));
    let _ = detector.detect(&image, None);
    let _ = detector.detect(outlet_fuzz::outlet_image(), None);
});
