//! Sub-pixel hole centres on rendered images, started from a guess a pixel off.

mod common;

use common::each_rendered_hole;
use nalgebra::Vector2;
use outlet_detector::refine::{RefineParams, refine_hole};

/// How far off the guesses start (pixels, each axis).
const JITTER: f64 = 1.0;

#[test]
fn refined_centres_are_within_a_fifth_of_a_pixel() {
    let mut errors = Vec::new();
    let mut failed = 0;
    let mut rng = outlet_sim::rng::SimRng::new(3);
    for scenario in
        ["fw_2x1white", "orange2x1", "whitehall2x1", "cracked2x2", "fw_2x2orange", "white2x2", "specular2x2"]
    {
        each_rendered_hole(scenario, 21, 6, |grey, truth, j, outline| {
            let guess = truth + Vector2::new(rng.range(-1.0, 1.0) * JITTER, rng.range(-1.0, 1.0) * JITTER);
            match refine_hole(grey, guess, j, outline, &RefineParams::default()) {
                Some(r) => errors.push((r.centre - truth).norm()),
                None => failed += 1,
            }
        });
    }
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    let p95 = errors[errors.len() * 95 / 100];
    println!(
        "refined {} holes, {failed} refused: median {median:.3} px, p95 {p95:.3} px, max {:.3}",
        errors.len(),
        errors[errors.len() - 1]
    );
    assert!(median <= 0.2, "median error {median:.3} px");
    assert!(failed * 20 <= errors.len(), "{failed} refused");
}

/// The outline fit's optimum depends on where it starts: on this plain frontal
/// outlet the upper neutral slot, fitted from its candidate's centre, lands
/// 0.9 px along its length from the truth with a 0.13 px sigma. Fitted again
/// from where the plane through all the holes puts it, it lands within 0.3 px.
#[test]
fn a_hole_fitted_again_from_the_plane_lands_nearer_the_truth() {
    let scene = common::plain_scene(1, 0.32, 10.0, 30.0, 0.0);
    let frame = outlet_sim::render_frame(&scene, "x");
    let truth = common::truth_pixels(&frame);
    let found = |refit_from_plane| {
        let params = outlet_detector::detect::DetectorParams { refit_from_plane, ..Default::default() };
        outlet_detector::detect::Detector::new(common::template().clone(), params)
            .detect(&frame.frame.image, Some(&scene.camera))
            .detection
            .expect("a plain frontal outlet is found")
    };
    let once = common::worst_error(&found(false), &truth);
    let again = common::worst_error(&found(true), &truth);
    assert!(once > 0.6, "the first fit's worst hole is {once:.2} px off: the test no longer covers a bad start");
    assert!(again < 0.3, "fitted again, the worst hole is {again:.2} px off");
}
