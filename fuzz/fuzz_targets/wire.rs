//! The sidecar's wire types as a subscriber finds them in shared memory: any
//! field values, any payload length. Validation refuses or accepts; what it
//! accepts is safe to use.
#![no_main]

use libfuzzer_sys::fuzz_target;
use outlet_fuzz::read_plain;
use outlet_protocol::wire::{CloudHeader, DetectionMsg, FrameHeader, HeartbeatMsg, HolePosesMsg, MAX_HOLES};

fn length(bytes: &[u8]) -> usize {
    let mut b = [0u8; 8];
    let n = bytes.len().min(8);
    b[..n].copy_from_slice(&bytes[..n]);
    u64::from_le_bytes(b) as usize
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, data)) = data.split_first() else { return };
    match which % 5 {
        0 => {
            let (header, rest) = read_plain::<FrameHeader>(data);
            let payload_len = length(rest);
            if let Ok((format, camera)) = header.validate(payload_len) {
                // What the detector service relies on: the rows fit the payload.
                let row = header.width as usize * format.channels();
                assert!(row <= header.stride as usize);
                assert!(header.stride as usize * header.height as usize <= payload_len);
                assert_eq!((camera.width, camera.height), (header.width, header.height));
                let _ = camera.ray(nalgebra::Point2::new(0.0, 0.0));
            }
        }
        1 => {
            let (header, rest) = read_plain::<CloudHeader>(data);
            let payload_values = length(rest);
            if header.validate(payload_values).is_ok() {
                assert!(header.points as u128 * 3 <= payload_values as u128);
            }
        }
        2 => {
            let (msg, _) = read_plain::<HolePosesMsg>(data);
            if msg.validate().is_ok() {
                let n = msg.hole_count as usize;
                assert!(n <= MAX_HOLES);
                assert!(msg.positions_m[..n].iter().flatten().all(|v| v.is_finite()));
            }
        }
        3 => {
            let (msg, _) = read_plain::<DetectionMsg>(data);
            let _ = msg.camera();
        }
        _ => {
            let (msg, _) = read_plain::<HeartbeatMsg>(data);
            let _ = (msg.service_name().len(), msg.last_rejection().len());
        }
    }
});
