//! A receptacle in a specular highlight (issue 13, Table I's specular2x2): its face
//! clipped at 255, one slot shows only 6 grey levels below it (relative 0.024) and is
//! found neither by its candidate nor by the faint second look at half the faint
//! contrast (0.025). On a clipped face there is no noise to mistake for an opening,
//! so the share asked there is 0.4: the outlet is found, every hole on the truth.

use nalgebra::Point2;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_detector::refine::RefineParams;
use outlet_protocol::CameraModel;
use outlet_sim::{render, sample_scene, truth::ground_truth};

fn detector(clipped_contrast_share: f64) -> Detector {
    let template = outlet::templates::builtin("2x2").expect("built-in template");
    let defaults = DetectorParams::default();
    let refine = RefineParams { clipped_contrast_share, ..defaults.refine };
    Detector::new(template, DetectorParams { refine, ..defaults })
}

#[test]
fn a_slot_washed_out_by_glare_on_a_clipped_face_is_seen() {
    let camera = CameraModel::default_vga();
    // Table I's specular2x2 view 1 of seed 1000: 46 cm, the upper right receptacle
    // in the highlight.
    let scene = sample_scene("specular2x2", 1000, 1, &camera).expect("scene");
    let image = render(&scene).image;
    let truth: Vec<Point2<f64>> =
        ground_truth(&scene, "x").holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
    let shipped = DetectorParams::default().refine.clipped_contrast_share;
    let found = detector(shipped).detect(&image, Some(&camera)).detection.expect("found with the shipped share");
    assert_eq!(found.holes.len(), truth.len());
    for (k, (h, t)) in found.holes.iter().zip(&truth).enumerate() {
        assert!((h.pixel - t).norm() < 1.0, "hole {k}: {:.2} px off", (h.pixel - t).norm());
    }
    let report = detector(0.5).detect(&image, Some(&camera));
    assert!(report.detection.is_none(), "found with half the faint contrast asked on the clipped face too");
}
