//! The detector's heap use per frame stays small in the steady state (issue 15,
//! item 4): the candidate stage and the outline fits keep their buffers between
//! frames. dhat counts every allocation of this test binary (its only test).
//! A count, not a time: `cargo bench --bench allocations` reports the figures.

use outlet_detector::grey_of;
use outlet_protocol::CameraModel;
use outlet_sim::render_frame;

#[global_allocator]
static ALLOC: dhat::Alloc = dhat::Alloc;

mod common;

#[test]
fn a_frame_in_the_steady_state_allocates_little() {
    let _profiler = dhat::Profiler::builder().testing().build();
    let detector = common::detector();
    let camera = CameraModel::new(640, 480, [525.0, 525.0, 319.5, 239.5], [0.0; 5]).expect("camera");
    let frames: Vec<image::GrayImage> = (0..6)
        .map(|k| {
            let scene = common::plain_scene_seen_by(&camera, 7, 0.40 - 0.01 * k as f64, 12.0, 40.0, 5.0);
            grey_of(&render_frame(&scene, "x").frame.image)
        })
        .collect();
    for f in frames.iter().take(2) {
        let _ = detector.detect_grey(f, Some(&camera));
    }
    let before = dhat::HeapStats::get();
    let mut found = 0;
    for f in &frames[2..] {
        found += usize::from(detector.detect_grey(f, Some(&camera)).detection.is_some());
    }
    let after = dhat::HeapStats::get();
    let n = (frames.len() - 2) as u64;
    let (blocks, bytes) =
        ((after.total_blocks - before.total_blocks) / n, (after.total_bytes - before.total_bytes) / n);
    assert_eq!(found, frames.len() - 2, "the outlet is found in every frame");
    // Measured 67 blocks and 14 kB per frame; a 640x480 frame's labels alone
    // are 1.2 MB, an outline fit's vectors tens of kB.
    assert!(blocks <= 100 && bytes <= 100_000, "{blocks} allocations, {bytes} bytes per frame");
}
