//! The PLY reader on any bytes: points or an error, never a panic, and no
//! allocation beyond what the data can hold.
#![no_main]

use libfuzzer_sys::fuzz_target;
use outlet_protocol::ply::parse_ply;

fuzz_target!(|data: &[u8]| {
    if let Ok(points) = parse_ply(data) {
        // Every vertex takes at least one byte of the body.
        assert!(points.len() <= data.len(), "{} points from {} bytes", points.len(), data.len());
    }
});
