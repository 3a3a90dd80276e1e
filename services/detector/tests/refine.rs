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
