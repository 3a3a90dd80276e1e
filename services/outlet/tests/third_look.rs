//! The detector's third look (issue 13): where the first two found nothing,
//! candidates still background are classified again a ladder step either side
//! of the scale their size implies. A far 2x1 whose holes the descriptor misses
//! at that scale is then found, hole for hole on the truth; what the first two
//! looks find is unchanged, and a frame without an outlet stays empty.

use nalgebra::Point2;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::CameraModel;
use outlet_sim::{render, sample_scene, truth::ground_truth};

fn detector_for(name: &str, third_look_spread: u32) -> Detector {
    let template = outlet::templates::builtin(name).expect("built-in template");
    // The last look (classes swapped) off: it finds some of the same outlets.
    Detector::new(template, DetectorParams { third_look_spread, swap_look_margin: 0.0, ..DetectorParams::default() })
}

/// Full resolution alone: the half-resolution look comes after the third, so
/// without the third look it may find what the third look finds at full
/// resolution (a little differently).
fn full_resolution_detector(third_look_spread: u32) -> Detector {
    let template = outlet::templates::builtin("2x1").expect("built-in template");
    let params = DetectorParams { third_look_spread, pyramid_min_px: 0, swap_look_margin: 0.0, ..Default::default() };
    Detector::new(template, params)
}

fn detector(third_look_spread: u32) -> Detector {
    detector_for("2x1", third_look_spread)
}

#[test]
fn a_far_outlet_missed_at_its_implied_scales_is_found_a_step_away() {
    let camera = CameraModel::default_vga();
    // Rendered orange 2x1, view 56 of seed 4242: 45 cm away, its holes classed
    // background at the scales their blobs imply.
    let scene = sample_scene("orange2x1", 4242, 56, &camera).expect("scene");
    let image = render(&scene).image;
    let truth: Vec<Point2<f64>> =
        ground_truth(&scene, "x").holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
    assert!(detector(0).detect(&image, Some(&camera)).detection.is_none(), "found without the third look");
    let found = detector(1).detect(&image, Some(&camera)).detection.expect("found with it");
    assert_eq!(found.holes.len(), truth.len());
    for (k, (h, t)) in found.holes.iter().zip(&truth).enumerate() {
        assert!((h.pixel - t).norm() < 1.0, "hole {k}: {:.2} px off", (h.pixel - t).norm());
    }
}

#[test]
fn the_third_look_changes_no_first_look_find_and_adds_no_false_alarm() {
    let camera = CameraModel::default_vga();
    let (with, without) = (full_resolution_detector(1), full_resolution_detector(0));
    let quad = detector_for("2x2", 1);
    for index in 0..12 {
        let scene = sample_scene("fw_2x1white", 3200, index, &camera).expect("scene");
        let image = render(&scene).image;
        let a = without.detect(&image, Some(&camera)).detection;
        let b = with.detect(&image, Some(&camera)).detection;
        if let Some(a) = a {
            let b = b.expect("a first-look find stays found");
            let same = a.holes.iter().zip(&b.holes).all(|(p, q)| p.pixel == q.pixel);
            assert!(same, "fw_2x1white #{index}: a find moved");
        }
        // A negative holds no outlet of its search's kind (a 2x2 search's may
        // hold a duplex).
        let negative = sample_scene("negative", 3200, index, &camera).expect("scene");
        let search = if negative.search_template == "2x2" { &quad } else { &with };
        let blank = render(&negative).image;
        assert!(search.detect(&blank, Some(&camera)).detection.is_none(), "negative #{index}: an outlet reported");
    }
}
