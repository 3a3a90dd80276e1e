//! Heap allocations per detected frame in the steady state (issue 15, item 4):
//! dhat's counting global allocator, over the frames of an
//! approach at 640x480 (the tracking bench's), full frame and tracked. Prints
//! the count and bytes per frame; `cargo bench -p outlet-detector --bench
//! allocations`. A measurement, not a limit: BENCHMARKS.md holds the figures.

use nalgebra::Vector3;
use outlet_detector::grey_of;
use outlet_detector::track::{TrackParams, Tracker};
use outlet_protocol::CameraModel;
use outlet_sim::render_frame;
// dhat's allocator counts every allocation (no unsafe of ours).
#[global_allocator]
static ALLOC: dhat::Alloc = dhat::Alloc;

#[path = "../tests/common/mod.rs"]
mod common;

fn counted<T>(f: impl FnOnce() -> T) -> (T, u64, u64) {
    let before = dhat::HeapStats::get();
    let out = f();
    let after = dhat::HeapStats::get();
    (out, after.total_blocks - before.total_blocks, after.total_bytes - before.total_bytes)
}

fn main() {
    // Counting only (testing mode: no profile file written).
    let _profiler = dhat::Profiler::builder().testing().build();
    let detector = common::detector();
    let camera = CameraModel::new(640, 480, [525.0, 525.0, 319.5, 239.5], [0.0; 5]).expect("camera");
    let frames: Vec<image::GrayImage> = (0..20)
        .map(|k| {
            let k = k as f64;
            let mut scene =
                common::plain_scene_seen_by(&camera, 7, 0.40 - 0.005 * k, 12.0 + 0.5 * k, 40.0, 5.0 - 0.4 * k);
            scene.pose.translation.vector += Vector3::new(0.001 * k, -0.0005 * k, 0.0);
            grey_of(&render_frame(&scene, "x").frame.image)
        })
        .collect();
    // Warm up: the first calls size whatever is kept between frames.
    for f in frames.iter().take(3) {
        let _ = detector.detect_grey(f, Some(&camera));
    }
    let (mut n, mut bytes, mut found) = (0, 0, 0);
    for f in &frames {
        let (report, a, b) = counted(|| detector.detect_grey(f, Some(&camera)));
        n += a;
        bytes += b;
        found += usize::from(report.detection.is_some());
    }
    let per = frames.len() as u64;
    println!(
        "640x480 full frame: {} allocations, {} bytes allocated per frame ({found} of {} found)",
        n / per,
        bytes / per,
        frames.len()
    );
    let mut tracker = Tracker::new(TrackParams::default());
    for (k, f) in frames.iter().enumerate().take(3) {
        let _ = tracker.detect_grey(&detector, f, Some(&camera), k as f64 / 30.0);
    }
    let (mut n, mut bytes) = (0, 0);
    for (k, f) in frames.iter().enumerate().skip(3) {
        let (_, a, b) = counted(|| tracker.detect_grey(&detector, f, Some(&camera), k as f64 / 30.0));
        n += a;
        bytes += b;
    }
    let per = (frames.len() - 3) as u64;
    println!("640x480 tracked: {} allocations, {} bytes allocated per frame", n / per, bytes / per);
}
