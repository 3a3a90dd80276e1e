//! Heap allocations per detected frame in the steady state (issue 15, item 4):
//! dhat's counting global allocator, over the frames of an approach (the
//! tracking bench's) at 640x480, 1280x960 and 1920x1080: full frame, tracked
//! (the last outlet followed) and searched in the window around it (the follow
//! off), and full frames into a report kept by the caller. Prints the count and bytes per frame; `cargo bench -p outlet-detector
//! --bench allocations`. A measurement, not a limit: BENCHMARKS.md holds the
//! figures.

use nalgebra::Vector3;
use outlet_detector::detect::DetectReport;
use outlet_detector::grey_of;
use outlet_detector::track::{Searched, TrackParams, Tracker};
use outlet_protocol::CameraModel;
use outlet_sim::render_frame;
// dhat's allocator counts every allocation (no unsafe of ours).
#[global_allocator]
static ALLOC: dhat::Alloc = dhat::Alloc;

#[path = "../tests/common/mod.rs"]
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

fn main() {
    // Counting only (testing mode: no profile file written).
    let _profiler = dhat::Profiler::builder().testing().build();
    let detector = common::detector();
    // VGA, and the HD cameras of issue 21 (the tracking bench's).
    let cameras = [(640, 480, 525.0), (1280, 960, 1050.0), (1920, 1080, 1181.0)].map(|(w, h, f)| {
        let centre = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
        CameraModel::new(w, h, [f, f, centre[0], centre[1]], [0.0; 5]).expect("camera")
    });
    let warm = 3;
    for camera in cameras {
        let size = format!("{}x{}", camera.width, camera.height);
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
        for f in &frames[..warm] {
            let _ = detector.detect_grey(f, Some(&camera));
        }
        let mut found = 0;
        let (n, bytes) = per_call(frames.len(), |k| {
            found += usize::from(detector.detect_grey(&frames[k], Some(&camera)).detection.is_some());
        });
        println!(
            "{size} full frame: {n} allocations, {bytes} bytes allocated per frame ({found} of {} found)",
            frames.len()
        );
        // A report kept by the caller: its vectors grow to the most candidates
        // of these frames in a first pass; counted over the whole second one.
        let mut report = DetectReport::default();
        for f in &frames {
            detector.detect_grey_into(f, Some(&camera), &mut report);
        }
        let (n, bytes) = per_call(1, |_| {
            for f in &frames {
                detector.detect_grey_into(f, Some(&camera), &mut report);
            }
        });
        println!(
            "{size} full frame into a kept report: {n} allocations, {bytes} bytes allocated in {} frames",
            frames.len()
        );
        for (name, follow) in [("tracked", true), ("window search", false)] {
            let mut tracker = Tracker::new(TrackParams { follow, ..TrackParams::default() });
            let time = |k: usize| k as f64 / 30.0;
            for (k, f) in frames[..warm].iter().enumerate() {
                let _ = tracker.detect_grey(&detector, f, Some(&camera), time(k));
            }
            let steady = &frames[warm..];
            let mut kept = 0;
            let (n, bytes) = per_call(steady.len(), |k| {
                let t = tracker.detect_grey(&detector, &steady[k], Some(&camera), time(warm + k));
                let wanted = if follow {
                    matches!(t.searched, Searched::Followed(_))
                } else {
                    matches!(t.searched, Searched::Window(_))
                };
                kept += usize::from(t.report.detection.is_some() && wanted);
            });
            println!(
                "{size} {name}: {n} allocations, {bytes} bytes allocated per frame ({kept} of {} so)",
                steady.len()
            );
        }
    }
}
