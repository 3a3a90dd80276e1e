//! Far holes: a slot 5-8 px long (a VGA camera 60-75 cm away) is the blur of a
//! few pixels. A template trained with far samples (half its poses taken at
//! half resolution) must find more of them than the paper's training alone,
//! and never a wrong outlet.

mod common;

use outlet_detector::detect::{Detector, DetectorParams};
use outlet_detector::grey_of;
use outlet_sim::render_frame;

#[test]
fn far_samples_find_more_far_outlets_and_none_wrong() {
    let camera = common::camera();
    let with = Detector::new(common::template_with_far_samples().clone(), DetectorParams::default());
    let without = Detector::new(common::template().clone(), DetectorParams::default());
    let (mut found_with, mut found_without) = (0, 0);
    let views = 24;
    for k in 0..views {
        let distance = 0.60 + 0.15 * (k % 5) as f64 / 4.0;
        let off_axis = (k * 7 % 30) as f64;
        let scene = common::plain_scene(500 + k as u64, distance, off_axis, (k * 45) as f64, (k * 29 % 360) as f64);
        let frame = render_frame(&scene, "far");
        let grey = grey_of(&frame.frame.image);
        let truth = common::truth_pixels(&frame);
        for (detector, found) in [(&with, &mut found_with), (&without, &mut found_without)] {
            if let Some(d) = detector.detect_grey(&grey, Some(&camera)).detection {
                let worst = common::worst_error(&d, &truth);
                assert!(worst < 3.0, "view {k} at {distance:.2} m: a hole {worst:.1} px from its place");
                *found += 1;
            }
        }
    }
    println!("far 2x1s found: {found_with} of {views} with far samples, {found_without} without");
    assert!(found_with > found_without, "far samples found {found_with}, without {found_without}");
    assert!(found_with * 4 >= views * 3, "far samples found only {found_with} of {views}");
}
