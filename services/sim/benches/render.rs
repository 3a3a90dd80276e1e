//! Render time of one frame per scenario (640x480 unless said), one core.

use criterion::{Criterion, criterion_group, criterion_main};
use outlet_protocol::CameraModel;
use outlet_sim::{SCENARIOS, render, sample_scene, stereo_cloud};
use std::hint::black_box;

fn bench_render(c: &mut Criterion) {
    let vga = CameraModel::default_vga();
    let mut group = c.benchmark_group("render_640x480");
    for scenario in SCENARIOS {
        // A few scenes per scenario so that one lucky scene does not decide.
        let scenes: Vec<_> = (0..8).filter_map(|i| sample_scene(scenario, 42, i, &vga).ok()).collect();
        let mut k = 0;
        group.bench_function(scenario, |b| {
            b.iter(|| {
                k = (k + 1) % scenes.len();
                black_box(render(&scenes[k]))
            })
        });
    }
    group.finish();
    let scene = sample_scene("white2x2", 42, 0, &vga).expect("scene");
    c.bench_function("stereo_cloud_640x480_step2", |b| b.iter(|| black_box(stereo_cloud(&scene))));
    let hd = CameraModel { width: 1920, height: 1080, fx: 1575.0, fy: 1575.0, cx: 959.5, cy: 539.5, ..vga };
    let scene = sample_scene("white2x2", 42, 0, &hd).expect("scene");
    c.bench_function("render_1920x1080_white2x2", |b| b.iter(|| black_box(render(&scene))));
}

criterion_group!(benches, bench_render);
criterion_main!(benches);
