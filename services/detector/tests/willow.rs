//! The paper's use of its one real image: train a template on the Willow orange
//! 2x2 photograph and find the outlet in it again (lens distortion k1 = -0.40).

use nalgebra::Point2;
use outlet_detector::candidates::{CandidateParams, find_candidates};
use outlet_detector::descriptor::DescriptorParams;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_detector::grey_of;
use outlet_detector::template::{Template, TrainingImage, train_template};
use outlet_protocol::{CameraModel, HoleKind, OutletGeometry};

/// `V000.labels.json`, shifted into the crop (x - 560, y - 330), template order.
const LABELS: [(HoleKind, [f64; 2]); 12] = [
    (HoleKind::Power, [370.67, 252.12]),
    (HoleKind::Power, [337.27, 253.04]),
    (HoleKind::Ground, [354.08, 237.14]),
    (HoleKind::Power, [372.31, 198.40]),
    (HoleKind::Power, [336.37, 199.03]),
    (HoleKind::Ground, [354.31, 180.82]),
    (HoleKind::Power, [249.32, 250.48]),
    (HoleKind::Power, [215.71, 251.02]),
    (HoleKind::Ground, [231.48, 235.17]),
    (HoleKind::Power, [245.71, 194.81]),
    (HoleKind::Power, [210.67, 194.81]),
    (HoleKind::Ground, [227.44, 177.96]),
];

/// `camera.yaml` of the photograph, its principal point moved with the crop.
fn camera() -> CameraModel {
    CameraModel::new(
        580,
        440,
        [1474.9071860700753, 1483.676600963029, 823.7045939542494 - 560.0, 682.4225889903155 - 330.0],
        [-0.3966072841182623, 0.2100337319203109, -0.002809223122968944, -0.005147669775217029, 0.0],
    )
    .expect("camera")
}

#[test]
fn a_template_trained_on_the_willow_photo_finds_its_outlet() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/willow-2x2/V000_crop.png");
    let image = image::open(path).expect("fixture").to_rgb8();
    let grey = grey_of(&image);
    let candidates = find_candidates(&grey, &CandidateParams::default());
    let holes: Vec<Point2<f64>> = LABELS.iter().map(|(_, p)| Point2::new(p[0], p[1])).collect();
    let geometry = OutletGeometry::us_2x2();
    assert!(geometry.holes.iter().zip(&LABELS).all(|(h, (k, _))| h.kind == *k));
    let template = train_template(
        "willow",
        geometry,
        &[TrainingImage { grey: &grey, holes: holes.clone(), candidates }],
        &[],
        &DescriptorParams::default(),
        true,
    )
    .expect("training");
    // Through the file format, as `outlet train` and `outlet detect` would.
    let template = Template::from_bytes(&template.to_bytes().expect("encode"), "willow.tpl").expect("round trip");
    let detector = Detector::new(template, DetectorParams::default());
    let report = detector.detect(&image, Some(&camera()));
    let found = report.detection.expect("the outlet is found");
    for (k, (hole, label)) in found.holes.iter().zip(&holes).enumerate() {
        let e = (hole.pixel - label).norm();
        // The labels are hand-placed on a blurred photo: 3 px is their own spread.
        assert!(e < 3.0, "hole {k}: {e:.2} px from its label");
    }
}
