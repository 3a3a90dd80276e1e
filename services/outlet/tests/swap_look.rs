//! The detector's last look (issue 21): where the first three find nothing, a
//! candidate the descriptor could barely tell between the hole classes also
//! counts as the other class (far away, a ground hole is a round blur much like
//! a slot's). A glossy 2x2 whose hole classes the descriptor confused is then
//! found, hole for hole on the truth; frames without an outlet stay empty.

use nalgebra::Point2;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::CameraModel;
use outlet_sim::{render, sample_scene, truth::ground_truth};

fn detector(name: &str, swap_look_margin: f32) -> Detector {
    let template = outlet::templates::builtin(name).expect("built-in template");
    Detector::new(template, DetectorParams { swap_look_margin, ..DetectorParams::default() })
}

#[test]
fn an_outlet_with_its_hole_classes_confused_is_found_by_the_last_look() {
    let camera = CameraModel::default_vga();
    // Rendered specular 2x2, view 61 of seed 4242.
    let scene = sample_scene("specular2x2", 4242, 61, &camera).expect("scene");
    let image = render(&scene).image;
    let truth: Vec<Point2<f64>> =
        ground_truth(&scene, "x").holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
    assert!(detector("2x2", 0.0).detect(&image, Some(&camera)).detection.is_none(), "found without the last look");
    let shipped = DetectorParams::default().swap_look_margin;
    assert!(shipped > 0.0, "the last look is off by default");
    let found = detector("2x2", shipped).detect(&image, Some(&camera)).detection.expect("found with it");
    assert_eq!(found.holes.len(), truth.len());
    for (k, (h, t)) in found.holes.iter().zip(&truth).enumerate() {
        assert!((h.pixel - t).norm() < 1.5, "hole {k}: {:.2} px off", (h.pixel - t).norm());
    }
}

#[test]
fn the_last_look_adds_no_false_alarm() {
    let camera = CameraModel::default_vga();
    let margin = DetectorParams::default().swap_look_margin;
    let (duplex, quad) = (detector("2x1", margin), detector("2x2", margin));
    for index in 0..16 {
        // A negative holds no outlet of its search's kind (a 2x2 search's may
        // hold a duplex).
        let negative = sample_scene("negative", 3300, index, &camera).expect("scene");
        let search = if negative.search_template == "2x2" { &quad } else { &duplex };
        let blank = render(&negative).image;
        assert!(search.detect(&blank, Some(&camera)).detection.is_none(), "negative #{index}: an outlet reported");
    }
}
