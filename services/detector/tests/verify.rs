//! A reported outlet is a verified outlet: every hole seen where the outlet's
//! homography puts it, and the hole outlines deciding which way round it is.

use image::RgbImage;
use nalgebra::Point2;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_sim::render_frame;

mod common;
use common::{detector, plain_scene, template, truth_pixels, worst_error};

/// Views from 30 to 40 cm, up to 25 degrees off-axis, any azimuth and roll.
fn views() -> Vec<(f64, f64, f64, f64)> {
    (0..8)
        .map(|k| (0.30 + 0.015 * k as f64, 25.0 * (k % 3) as f64 / 2.0, 45.0 * k as f64, 20.0 * k as f64 - 70.0))
        .collect()
}

#[test]
fn a_found_outlet_reports_every_hole_seen_with_its_score_and_sigma() {
    let scene = plain_scene(1, 0.32, 10.0, 30.0, 0.0);
    let frame = render_frame(&scene, "x");
    let report = detector().detect(&frame.frame.image, Some(&scene.camera));
    let found = report.detection.expect("a plain frontal outlet is found");
    assert!(report.rejected.is_none());
    assert!(worst_error(&found, &truth_pixels(&frame)) < 1.0);
    for (i, hole) in found.holes.iter().enumerate() {
        assert!(hole.refined, "hole {i} reported without being seen");
        assert!(hole.score > 0.3 && hole.score <= 1.0, "hole {i}: score {}", hole.score);
        assert!(hole.sigma_px > 0.0 && hole.sigma_px < 0.5, "hole {i}: sigma {} px", hole.sigma_px);
    }
}

#[test]
fn a_hole_moved_onto_the_bare_plate_is_refused() {
    let scene = plain_scene(2, 0.33, 0.0, 0.0, 0.0);
    let frame = render_frame(&scene, "x");
    let truth = truth_pixels(&frame);
    assert!(detector().detect(&frame.frame.image, None).detection.is_some(), "the untouched outlet is found");
    // The upper hot slot (hole 1) cut out, the face painted over it, and the
    // opening pasted 14 px to its right, onto the bare face.
    let mut image = frame.frame.image.clone();
    let (u, v) = (truth[1].x.round() as i64, truth[1].y.round() as i64);
    let face = *frame.frame.image.get_pixel((u - 6) as u32, (v - 12) as u32);
    for dy in -10..=10 {
        for dx in -4..=4 {
            let (x, y) = ((u + dx) as u32, (v + dy) as u32);
            image.put_pixel((u + dx + 14) as u32, y, *frame.frame.image.get_pixel(x, y));
            image.put_pixel(x, y, face);
        }
    }
    let report = detector().detect(&image, None);
    assert!(report.detection.is_none(), "an outlet with a hole on the bare face was reported: {:?}", report.detection);
}

/// A camera never sees a mirror image of an outlet, but a flipped image must
/// not give one with its slots swapped (neutral for hot) or holes elsewhere.
#[test]
fn a_mirrored_outlet_is_never_reported_with_holes_in_wrong_places() {
    let mut found_upright = 0;
    // The same detector without the outlines' identity check: what it guards.
    let mut unchecked = DetectorParams::default();
    unchecked.verify.min_identity_gain = f64::NEG_INFINITY;
    unchecked.verify.max_identity_contradiction = f64::INFINITY;
    let unchecked = Detector::new(template().clone(), unchecked);
    let mut swapped_without_check = 0;
    for (k, &(d, a, z, roll)) in views().iter().enumerate() {
        let scene = plain_scene(10 + k as u64, d, a, z, roll);
        let frame = render_frame(&scene, "x");
        let truth = truth_pixels(&frame);
        if detector().detect(&frame.frame.image, None).detection.is_some_and(|f| worst_error(&f, &truth) < 2.0) {
            found_upright += 1;
        }
        let mirrored = image::imageops::flip_horizontal(&frame.frame.image);
        let w = mirrored.width() as f64;
        let truth_mirrored: Vec<Point2<f64>> = truth.iter().map(|p| Point2::new(w - 1.0 - p.x, p.y)).collect();
        let mirrored = RgbImage::from(mirrored);
        if unchecked.detect(&mirrored, None).detection.is_some_and(|f| worst_error(&f, &truth_mirrored) > 2.0) {
            swapped_without_check += 1;
        }
        let report = detector().detect(&mirrored, None);
        if let Some(found) = report.detection {
            // Only the physical outlet, each hole on its own physical hole, would do.
            let e = worst_error(&found, &truth_mirrored);
            assert!(e < 2.0, "view {k}: a mirrored outlet reported with a hole {e:.1} px from its place");
        }
    }
    assert!(found_upright >= 6, "only {found_upright} of 8 upright views found");
    assert!(swapped_without_check >= 4, "without the identity check {swapped_without_check} of 8 read swapped");
}

#[test]
fn a_ground_up_outlet_is_read_the_right_way_round() {
    let mut found = 0;
    for (k, &(d, a, z, roll)) in views().iter().enumerate() {
        // Turned by half a turn from the upright views.
        let scene = plain_scene(30 + k as u64, d, a, z, roll + 180.0);
        let frame = render_frame(&scene, "x");
        let truth = truth_pixels(&frame);
        if let Some(d) = detector().detect(&frame.frame.image, Some(&scene.camera)).detection {
            let e = worst_error(&d, &truth);
            assert!(e < 2.0, "view {k}: ground-up outlet read with a hole {e:.1} px off (half turn?)");
            found += 1;
        }
    }
    assert!(found >= 6, "only {found} of 8 ground-up views found");
}
