//! Hole candidates (stage 1) on rendered frames, one core.

use criterion::{Criterion, criterion_group, criterion_main};
use outlet_detector::candidates::{CandidateParams, find_candidates};
use outlet_detector::grey_of;
use outlet_protocol::CameraModel;
use outlet_sim::{render, sample_scene};
use std::hint::black_box;

/// Grey frames of a few scenarios, so that one easy frame does not decide.
fn frames(width: u32, height: u32) -> Vec<image::GrayImage> {
    let f = 525.0 * width as f64 / 640.0;
    let centre = [(width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0];
    let camera =
        CameraModel::new(width, height, [f, f, centre[0], centre[1]], [-0.06, 0.03, 0.0, 0.0, 0.0]).expect("camera");
    ["white2x2", "orange2x1", "specular2x2", "cracked2x2"]
        .iter()
        .flat_map(|scenario| (0..2).map(move |i| (scenario, i)))
        .map(|(scenario, i)| grey_of(&render(&sample_scene(scenario, 42, i, &camera).expect("scene")).image))
        .collect()
}

fn bench_candidates(c: &mut Criterion) {
    for (width, height) in [(640, 480), (1280, 960)] {
        let frames = frames(width, height);
        let mut group = c.benchmark_group(format!("candidates_{width}x{height}"));
        for (name, params) in [("high_recall", CandidateParams::high_recall()), ("paper", CandidateParams::default())] {
            let mut k = 0;
            group.bench_function(name, |b| {
                b.iter(|| {
                    k = (k + 1) % frames.len();
                    black_box(find_candidates(&frames[k], &params))
                })
            });
        }
        group.finish();
    }
}

criterion_group!(benches, bench_candidates);
criterion_main!(benches);
