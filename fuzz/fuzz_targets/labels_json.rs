//! `outlet train --labels LABELS.json`: the labels read as `outlet train` reads
//! them (`{"holes": [{"kind", "pixel": [u, v]}]}`, serde_json values), then a
//! template trained on a small rendered image with those pixels, whatever they are.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nalgebra::Point2;
use outlet_detector::candidates::{CandidateParams, find_candidates};
use outlet_detector::descriptor::DescriptorParams;
use outlet_detector::grey_of;
use outlet_detector::template::{TrainingImage, train_template};
use outlet_protocol::OutletGeometry;
use serde_json::Value;

fuzz_target!(|data: &[u8]| {
    let Ok(labels) = serde_json::from_slice::<Value>(data) else { return };
    let Some(holes) = labels["holes"].as_array() else { return };
    let mut pixels = Vec::with_capacity(holes.len());
    for h in holes {
        let (Some(u), Some(v)) = (h["pixel"][0].as_f64(), h["pixel"][1].as_f64()) else { return };
        let _ = h["kind"].as_str().unwrap_or("");
        pixels.push(Point2::new(u, v));
    }
    let grey = grey_of(outlet_fuzz::outlet_image());
    let candidates = find_candidates(&grey, &CandidateParams::default());
    // Fewer poses than the default keep the target fast; the code paths are the same.
    let params = DescriptorParams { poses_per_feature: 4, noisy_copies: 1, ..DescriptorParams::default() };
    let view = TrainingImage { grey: &grey, holes: pixels, candidates };
    let _ = train_template("fuzz", OutletGeometry::us_2x1(), &[view], &[], &params, true);
});
