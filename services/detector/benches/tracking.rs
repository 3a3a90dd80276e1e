//! Tracking against full-frame detection on the frames of an approach (one
//! core), at 640x480, 1280x960 and 1920x1080: a 2x1 outlet from 40 to 30 cm in
//! 20 frames at 30 Hz and back. Each tracked frame is searched in the window
//! around the previous frame's outlet.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Vector3;
use outlet_detector::detect::StageTimes;
use outlet_detector::grey_of;
use outlet_detector::track::{Searched, TrackParams, Tracker};
use outlet_protocol::CameraModel;
use outlet_sim::render_frame;
use std::hint::black_box;

#[path = "../tests/common/mod.rs"]
mod common;

fn frames(camera: &CameraModel) -> Vec<image::GrayImage> {
    (0..20)
        .map(|k| {
            let k = k as f64;
            let mut scene =
                common::plain_scene_seen_by(camera, 7, 0.40 - 0.005 * k, 12.0 + 0.5 * k, 40.0, 5.0 - 0.4 * k);
            scene.pose.translation.vector += Vector3::new(0.001 * k, -0.0005 * k, 0.0);
            grey_of(&render_frame(&scene, "x").frame.image)
        })
        .collect()
}

fn bench_tracking(c: &mut Criterion) {
    let detector = common::detector();
    // VGA, and the HD cameras of issue 21 (the 1080p one with its f = 1181 px).
    let cameras = [(640, 480, 525.0), (1280, 960, 1050.0), (1920, 1080, 1181.0)].map(|(w, h, f)| {
        let centre = [(w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0];
        CameraModel::new(w, h, [f, f, centre[0], centre[1]], [0.0; 5]).expect("camera")
    });
    for camera in cameras {
        let frames = frames(&camera);
        // Where the time of a tracked frame goes, once.
        let mut tracker = Tracker::new(TrackParams::default());
        let (mut stages, mut windows) = (StageTimes::default(), 0);
        for (k, f) in frames.iter().enumerate() {
            let t = tracker.detect_grey(&detector, f, Some(&camera), k as f64 / 30.0);
            if matches!(t.searched, Searched::Window(_) | Searched::Followed(_)) {
                stages += t.report.times;
                windows += 1;
            }
        }
        let n = windows.max(1) as f64;
        println!(
            "{}x{}: {windows} of {} frames tracked (followed or in a window); per tracked frame (ms): candidates {:.3}, classify {:.3}, hash {:.3}, refine {:.3}",
            camera.width,
            camera.height,
            frames.len(),
            stages.candidates / n,
            stages.classify / n,
            stages.hash / n,
            stages.refine / n
        );
        let mut group = c.benchmark_group(format!("approach_{}x{}", camera.width, camera.height));
        let mut k = 0;
        group.bench_function("full_frame", |b| {
            b.iter(|| {
                k = (k + 1) % frames.len();
                black_box(detector.detect_grey(&frames[k], Some(&camera)))
            })
        });
        // A stream: the frames forth and back (the outlet approaches, then
        // recedes), each tracked from the one before, with the whole-frame
        // search every 30 frames that tracking keeps doing.
        let order: Vec<usize> = (0..frames.len()).chain((0..frames.len()).rev()).collect();
        // As shipped (following the last outlet first, `TrackParams::follow`),
        // and searching the window around it at once.
        for (name, follow) in [("tracking", true), ("tracking_window", false)] {
            let mut tracker = Tracker::new(TrackParams { follow, ..TrackParams::default() });
            let (mut i, mut time) = (0, 0.0);
            group.bench_function(name, |b| {
                b.iter(|| {
                    i = (i + 1) % order.len();
                    time += 1.0 / 30.0;
                    black_box(tracker.detect_grey(&detector, &frames[order[i]], Some(&camera), time))
                })
            });
        }
        group.finish();
    }
}

criterion_group!(benches, bench_tracking);
criterion_main!(benches);
