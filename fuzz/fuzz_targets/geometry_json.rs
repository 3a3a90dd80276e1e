//! `GEOMETRY.json` outlet geometries on any bytes: parsed and validated as
//! `OutletGeometry::read` does; a geometry that passes builds a detector.
#![no_main]

use libfuzzer_sys::fuzz_target;
use outlet_detector::Class;
use outlet_detector::hashing::{HashParams, HashTable};
use outlet_detector::refine::HoleShape;
use outlet_protocol::OutletGeometry;

fuzz_target!(|data: &[u8]| {
    let Ok(geometry) = serde_json::from_slice::<OutletGeometry>(data) else { return };
    if geometry.validate("fuzz.json").is_err() || geometry.holes.len() > 24 {
        return;
    }
    // What `outlet train --geometry FILE` and `Detector::new` build from it.
    let points: Vec<_> = geometry.holes.iter().map(|h| h.position()).collect();
    let classes: Vec<_> = geometry.holes.iter().map(|h| Class::from(h.kind)).collect();
    let _ = HashTable::new(&points, &classes, &HashParams::default());
    let _ = HoleShape::us_outlines(&geometry);
});
