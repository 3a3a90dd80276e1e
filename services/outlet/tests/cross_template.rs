//! An outlet of one kind shown to the other kind's search (issue 13): a 2x2
//! search never reports a 2x2 in a duplex (its six missing holes would be
//! predicted onto the bare plate), and a 2x1 search in a 2x2 reports one of its
//! two duplexes, each hole on a real hole of that column, or nothing.

use nalgebra::Point2;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::CameraModel;
use outlet_sim::{render, sample_scene, truth::ground_truth};

fn detector(name: &str) -> Detector {
    Detector::new(outlet::templates::builtin(name).expect("built-in template"), DetectorParams::default())
}

#[test]
fn a_2x2_search_finds_no_2x2_in_a_duplex() {
    let camera = CameraModel::default_vga();
    let quad = detector("2x2");
    let duplex = detector("2x1");
    let (mut shown, mut found_by_own) = (0, 0);
    for scenario in ["fw_2x1white", "orange2x1", "whitehall2x1"] {
        for index in 0..8 {
            let scene = sample_scene(scenario, 3100, index, &camera).expect("scene");
            let image = render(&scene).image;
            shown += 1;
            let report = quad.detect(&image, Some(&camera));
            assert!(
                report.detection.is_none(),
                "{scenario} #{index}: a 2x2 reported in a duplex: {:?}",
                report.detection.map(|d| d.holes.iter().map(|h| h.pixel).collect::<Vec<_>>())
            );
            // The same images are no blank test: their own search finds them.
            found_by_own += usize::from(duplex.detect(&image, Some(&camera)).detection.is_some());
        }
    }
    assert!(found_by_own * 10 >= shown * 8, "the 2x1 search found only {found_by_own} of {shown} duplexes");
}

#[test]
fn a_2x1_search_in_a_2x2_finds_one_of_its_columns_hole_for_hole() {
    let camera = CameraModel::default_vga();
    let duplex = detector("2x1");
    let (mut shown, mut found) = (0, 0);
    for scenario in ["white2x2", "cracked2x2", "specular2x2"] {
        for index in 0..8 {
            let mut scene = sample_scene(scenario, 3100, index, &camera).expect("scene");
            // No neighbouring plate: a duplex beside the 2x2 would be a right
            // answer this test has no truth for.
            scene.plates.truncate(1);
            let image = render(&scene).image;
            let truth: Vec<Point2<f64>> =
                ground_truth(&scene, "x").holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
            assert_eq!(truth.len(), 12);
            shown += 1;
            let Some(d) = duplex.detect(&image, Some(&camera)).detection else { continue };
            found += 1;
            // Template order: each column of the 2x2 is a 2x1 in the 2x1's order.
            let worst = |column: &[Point2<f64>]| {
                d.holes.iter().zip(column).map(|(h, t)| (h.pixel - t).norm()).fold(0.0, f64::max)
            };
            let best = worst(&truth[..6]).min(worst(&truth[6..]));
            assert!(best <= 5.0, "{scenario} #{index}: the 2x1 found is {best:.1} px from either column's holes");
        }
    }
    assert!(found * 2 >= shown, "the 2x1 search found a column in only {found} of {shown} 2x2s");
}
