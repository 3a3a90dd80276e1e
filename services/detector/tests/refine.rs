//! Sub-pixel hole centres on rendered images, started from a guess a pixel off.

use nalgebra::{Matrix2, Point2, Point3};
use outlet_detector::grey_of;
use outlet_detector::refine::{HoleShape, RefineParams, refine_hole};
use outlet_protocol::CameraModel;
use outlet_sim::{render_frame, sample_scene};

/// How far off the guesses start (pixels, each axis).
const JITTER: f64 = 1.0;

/// The outlet-plane mm to image px Jacobian at a hole, from the true pose.
fn jacobian(scene: &outlet_sim::Scene, hole_mm: [f64; 2]) -> Matrix2<f64> {
    let project = |x: f64, y: f64| {
        scene.camera.project(&(scene.pose * Point3::new(x / 1000.0, y / 1000.0, 0.0))).expect("in front")
    };
    let c = project(hole_mm[0], hole_mm[1]);
    let dx = project(hole_mm[0] + 0.5, hole_mm[1]) - c;
    let dy = project(hole_mm[0], hole_mm[1] + 0.5) - c;
    Matrix2::new(dx.x, dy.x, dx.y, dy.y) * 2.0
}

#[test]
fn refined_centres_are_within_a_fifth_of_a_pixel() {
    let camera = CameraModel::default_vga();
    let mut errors = Vec::new();
    let mut failed = 0;
    let mut rng = outlet_sim::rng::SimRng::new(3);
    for scenario in
        ["fw_2x1white", "orange2x1", "whitehall2x1", "cracked2x2", "fw_2x2orange", "white2x2", "specular2x2"]
    {
        for index in 0..6 {
            let scene = sample_scene(scenario, 21, index, &camera).expect("scene");
            let frame = render_frame(&scene, "x");
            let grey = grey_of(&frame.frame.image);
            let geometry = scene.geometry().expect("outlet");
            let outlines = HoleShape::us_outlines(&geometry);
            for ((hole, truth), outline) in geometry.holes.iter().zip(&frame.truth.holes).zip(outlines) {
                let j = jacobian(&scene, hole.position_mm);
                let guess = Point2::new(
                    truth.pixel[0] + rng.range(-1.0, 1.0) * JITTER,
                    truth.pixel[1] + rng.range(-1.0, 1.0) * JITTER,
                );
                match refine_hole(&grey, guess, &j, outline, &RefineParams::default()) {
                    Some(r) => errors
                        .push(((r.centre.x - truth.pixel[0]).powi(2) + (r.centre.y - truth.pixel[1]).powi(2)).sqrt()),
                    None => failed += 1,
                }
            }
        }
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
