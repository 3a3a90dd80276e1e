//! The detector takes (almost) nothing from the heap per frame in the steady
//! state (issue 15, item 4): every stage keeps its buffers between frames, and
//! what a frame still allocates is the report's own vectors, nothing with a
//! report kept by the caller (`Detector::detect_grey_into`). dhat counts every
//! allocation of this test binary (its only test: the counts are global). A
//! count, not a time: `cargo bench --bench allocations` reports the figures.

use nalgebra::Vector3;
use outlet_detector::detect::{DetectReport, Detector};
use outlet_detector::grey_of;
use outlet_detector::track::{Searched, TrackParams, Tracker};
use outlet_protocol::CameraModel;
use outlet_sim::render_frame;

#[global_allocator]
static ALLOC: dhat::Alloc = dhat::Alloc;

mod common;

/// Blocks and bytes allocated per call of `f` over `n` calls.
fn per_call(n: usize, mut f: impl FnMut(usize)) -> (u64, u64) {
    let before = dhat::HeapStats::get();
    for k in 0..n {
        f(k);
    }
    let after = dhat::HeapStats::get();
    let n = n as u64;
    ((after.total_blocks - before.total_blocks) / n, (after.total_bytes - before.total_bytes) / n)
}

/// An approach at 30 Hz seen by `camera` (the allocations and tracking
/// benches' frames).
fn approach(camera: &CameraModel, n: usize) -> Vec<image::GrayImage> {
    (0..n)
        .map(|k| {
            let k = k as f64;
            let mut scene =
                common::plain_scene_seen_by(camera, 7, 0.40 - 0.005 * k, 12.0 + 0.5 * k, 40.0, 5.0 - 0.4 * k);
            scene.pose.translation.vector += Vector3::new(0.001 * k, -0.0005 * k, 0.0);
            grey_of(&render_frame(&scene, "x").frame.image)
        })
        .collect()
}

const WARM: usize = 3;

fn time(k: usize) -> f64 {
    k as f64 / 30.0
}

/// Blocks and bytes per full frame of `detect_grey`, then in all of the
/// frames' second pass of `detect_grey_into` with one report kept throughout.
fn full_frames(detector: &Detector, camera: &CameraModel, frames: &[image::GrayImage]) -> [(u64, u64); 2] {
    // Warm up: the first calls size what is kept between frames.
    for f in &frames[..WARM] {
        let _ = detector.detect_grey(f, Some(camera));
    }
    let steady = &frames[WARM..];
    let mut found = 0;
    let returned = per_call(steady.len(), |k| {
        found += usize::from(detector.detect_grey(&steady[k], Some(camera)).detection.is_some());
    });
    // The kept report's vectors grow to the most candidates of these frames
    // in the first pass; the second takes nothing.
    let mut report = DetectReport::default();
    for f in frames {
        detector.detect_grey_into(f, Some(camera), &mut report);
    }
    let kept = per_call(1, |_| {
        for f in frames {
            detector.detect_grey_into(f, Some(camera), &mut report);
            found += usize::from(report.detection.is_some());
        }
    });
    assert_eq!(found, steady.len() + frames.len(), "the outlet is found in every frame");
    [returned, kept]
}

/// Blocks and bytes per frame of a tracker, following the last outlet or
/// (`follow` off) searching the window around it.
fn tracked_frames(detector: &Detector, camera: &CameraModel, frames: &[image::GrayImage], follow: bool) -> (u64, u64) {
    let mut tracker = Tracker::new(TrackParams { follow, ..TrackParams::default() });
    for (k, f) in frames[..WARM].iter().enumerate() {
        let _ = tracker.detect_grey(detector, f, Some(camera), time(k));
    }
    let steady = &frames[WARM..];
    let mut kept = 0;
    let counts = per_call(steady.len(), |k| {
        let tracked = tracker.detect_grey(detector, &steady[k], Some(camera), time(WARM + k));
        let so = match tracked.searched {
            Searched::Followed(_) => follow,
            Searched::Window(_) => !follow,
            Searched::FullFrame { .. } => false,
        };
        kept += usize::from(tracked.report.detection.is_some() && so);
    });
    assert_eq!(kept, steady.len(), "every frame's outlet is tracked (follow {follow})");
    counts
}

#[test]
fn a_frame_in_the_steady_state_allocates_only_its_report() {
    let _profiler = dhat::Profiler::builder().testing().build();
    let detector = common::detector();

    let vga = CameraModel::new(640, 480, [525.0, 525.0, 319.5, 239.5], [0.0; 5]).expect("camera");
    let frames = approach(&vga, 12);
    let [(blocks, bytes), kept] = full_frames(&detector, &vga, &frames);
    // Measured 2 blocks, 1.1 kB: the report's candidates and the detection's
    // holes (before session 20: 67 blocks, 14 kB).
    assert!(blocks <= 4 && bytes <= 4_000, "640x480 full frame: {blocks} allocations, {bytes} bytes per frame");
    assert_eq!(kept, (0, 0), "640x480 full frames into a kept report: allocations, bytes");
    let (blocks, bytes) = tracked_frames(&detector, &vga, &frames, true);
    // Measured 1 block, 0.4 kB: the detection's holes (before: 24 blocks, 4 kB).
    assert!(blocks <= 2 && bytes <= 2_000, "640x480 tracked: {blocks} allocations, {bytes} bytes per frame");

    // Coarse first: the half-resolution image and its level's report are kept.
    let hd = CameraModel::new(1280, 960, [1050.0, 1050.0, 639.5, 479.5], [0.0; 5]).expect("camera");
    let frames = approach(&hd, 8);
    let [(blocks, bytes), kept] = full_frames(&detector, &hd, &frames);
    // Measured 2 blocks, 1.0 kB (before: 6 blocks, 309 kB, the half image most of it).
    assert!(blocks <= 3 && bytes <= 3_000, "1280x960 full frame: {blocks} allocations, {bytes} bytes per frame");
    assert_eq!(kept, (0, 0), "1280x960 full frames into a kept report: allocations, bytes");
    // The window's crop is kept too: measured 2 blocks, 1.3 kB, the report's
    // candidates and holes (before: 7 blocks, 62 kB).
    let (blocks, bytes) = tracked_frames(&detector, &hd, &frames, false);
    assert!(blocks <= 3 && bytes <= 3_000, "1280x960 window search: {blocks} allocations, {bytes} bytes per frame");
}
