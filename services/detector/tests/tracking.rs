//! Tracking: a window around the last outlet first, the whole frame when that
//! fails. It must follow a moving outlet with the accuracy of full-frame
//! detection, and never give a wrong outlet when the outlet leaves the view, the
//! camera jumps or a second outlet comes in.

use image::RgbImage;
use nalgebra::{Point2, Vector3};
use outlet_detector::detect::Detection;
use outlet_detector::grey_of;
use outlet_detector::track::{Searched, TrackParams, Tracker};
use outlet_sim::render_frame;
use outlet_sim::scenario::pose_looking;

mod common;
use common::{detector, plain_scene, truth_pixels, worst_error};

const FRAME_S: f64 = 1.0 / 30.0;

/// Holes within this of the truth are the outlet's (pixels); a wrong outlet has
/// a hole further than this from every true hole.
const RIGHT_PX: f64 = 1.5;

fn every_hole_near(d: &Detection, truth: &[Point2<f64>]) -> bool {
    worst_error(d, truth) < RIGHT_PX
}

#[test]
fn an_approaching_outlet_is_tracked_in_windows_with_full_frame_accuracy() {
    let detector = detector();
    // Followed (the default), the strictest case: the holes' fits start at
    // their predicted places instead of candidates' centres.
    let mut tracker = Tracker::new(TrackParams::default());
    let mut windows = 0;
    // Squared hole errors (px^2) after the first frame: tracked, full frame.
    let mut squared = [0.0f64; 2];
    let mut followed = 0;
    for k in 0..16 {
        // 40 cm to 28 cm in half a second, turning and sliding a little.
        let mut scene = plain_scene(7, 0.40 - 0.0075 * k as f64, 12.0 + 0.5 * k as f64, 40.0, 5.0 - 0.4 * k as f64);
        scene.pose.translation.vector += Vector3::new(0.002 * k as f64, -0.001 * k as f64, 0.0);
        let frame = render_frame(&scene, "x");
        let grey = grey_of(&frame.frame.image);
        let truth = truth_pixels(&frame);
        let tracked = tracker.detect_grey(&detector, &grey, Some(&scene.camera), k as f64 * FRAME_S);
        let full = detector.detect_grey(&grey, Some(&scene.camera));
        let (Some(t), Some(f)) = (&tracked.report.detection, &full.detection) else {
            panic!("frame {k}: tracked {:?}, full frame {:?}", tracked.report.rejected, full.rejected);
        };
        assert!(every_hole_near(t, &truth), "frame {k}: tracked holes {:.2} px off", worst_error(t, &truth));
        // The holes of a full-frame search, or as near the truth: a followed
        // hole's fit starts from where the last frame's motion puts it instead
        // of a candidate's centre.
        for ((a, b), p) in t.holes.iter().zip(&f.holes).zip(&truth) {
            assert_eq!(a.kind, b.kind);
            if k > 0 {
                squared[0] += (a.pixel - p).norm_squared();
                squared[1] += (b.pixel - p).norm_squared();
            }
        }
        if let Searched::Window(w) | Searched::Followed(w) = tracked.searched {
            windows += 1;
            followed += usize::from(matches!(tracked.searched, Searched::Followed(_)));
            assert!(w[2] * w[3] < grey.width() * grey.height() / 3, "frame {k}: window {w:?}");
        }
    }
    assert!(windows >= 13, "only {windows} of 15 frames after the first were tracked in a window");
    // From the third frame on the motion is known: the outlet is followed.
    assert!(followed >= 12, "only {followed} of 15 frames followed");
    // The same accuracy: the tracked holes' RMS error within 10% of the full frame's.
    let [tracked, full] = squared.map(|s| s.sqrt());
    println!("hole error, root of summed squares: tracked {tracked:.4} px, full frame {full:.4} px");
    assert!(tracked <= 1.1 * full, "tracked {tracked:.4} against full frame {full:.4}");
}

#[test]
fn an_outlet_leaving_the_view_is_never_reported_with_holes_in_wrong_places() {
    let detector = detector();
    let mut tracker = Tracker::new(TrackParams::default());
    let (mut found, mut gone) = (0, 0);
    for k in 0..14 {
        // Slides right, 2.5 cm per frame, out of the image after half the frames.
        let mut scene = plain_scene(8, 0.33, 5.0, 0.0, 0.0);
        scene.pose.translation.vector += Vector3::new(0.025 * k as f64, 0.0, 0.0);
        let frame = render_frame(&scene, "x");
        let truth = truth_pixels(&frame);
        let inside = truth.iter().all(|p| p.x > 4.0 && p.x < 636.0);
        let tracked = tracker.detect_grey(&detector, &grey_of(&frame.frame.image), None, k as f64 * FRAME_S);
        match &tracked.report.detection {
            Some(d) => {
                assert!(inside, "frame {k}: an outlet reported with holes out of the image");
                assert!(every_hole_near(d, &truth), "frame {k}: holes {:.2} px off", worst_error(d, &truth));
                found += 1;
            }
            None if !inside => gone += 1,
            None => {}
        }
    }
    assert!(found >= 4 && gone >= 3, "found in {found} frames, rightly none in {gone}");
}

#[test]
fn a_camera_jump_gives_the_new_outlet_or_none() {
    let detector = detector();
    let mut tracker = Tracker::new(TrackParams::default());
    let near = plain_scene(9, 0.32, 10.0, 0.0, 0.0);
    let first = render_frame(&near, "a");
    let d = tracker.detect_grey(&detector, &grey_of(&first.frame.image), None, 0.0);
    assert!(d.report.detection.is_some(), "the first view is found");
    // One frame later the head has turned: the outlet is elsewhere, smaller,
    // turned in the image.
    let mut far = plain_scene(10, 0.45, 20.0, 120.0, 35.0);
    far.pose.translation.vector += Vector3::new(-0.08, 0.05, 0.0);
    let second = render_frame(&far, "b");
    let truth = truth_pixels(&second);
    let tracked = tracker.detect_grey(&detector, &grey_of(&second.frame.image), None, FRAME_S);
    assert_eq!(tracked.searched, Searched::FullFrame { after_window: true });
    let d = tracked.report.detection.expect("the outlet's new place is found by the whole-frame search");
    assert!(every_hole_near(&d, &truth), "holes {:.2} px off", worst_error(&d, &truth));
    // And a jump to a wall without an outlet gives none.
    let mut blank = plain_scene(11, 0.32, 0.0, 0.0, 0.0);
    blank.plates.clear();
    let empty = render_frame(&blank, "c");
    let tracked = tracker.detect_grey(&detector, &grey_of(&empty.frame.image), None, 2.0 * FRAME_S);
    assert!(tracked.report.detection.is_none(), "an outlet reported on a bare wall");
}

/// Copies the rectangle around `holes` (grown by `pad`) of `from` into `to`,
/// moved by `(dx, dy)`.
fn paste(to: &mut RgbImage, from: &RgbImage, holes: &[Point2<f64>], pad: f64, dx: i64, dy: i64) {
    let x0 = holes.iter().map(|p| p.x).fold(f64::INFINITY, f64::min) - pad;
    let x1 = holes.iter().map(|p| p.x).fold(f64::NEG_INFINITY, f64::max) + pad;
    let y0 = holes.iter().map(|p| p.y).fold(f64::INFINITY, f64::min) - pad;
    let y1 = holes.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max) + pad;
    for y in y0.max(0.0) as i64..y1.min(from.height() as f64) as i64 {
        for x in x0.max(0.0) as i64..x1.min(from.width() as f64) as i64 {
            let (u, v) = (x + dx, y + dy);
            if u >= 0 && v >= 0 && (u as u32) < to.width() && (v as u32) < to.height() {
                to.put_pixel(u as u32, v as u32, *from.get_pixel(x as u32, y as u32));
            }
        }
    }
}

#[test]
fn a_second_outlet_coming_in_never_gives_a_mixed_or_wrong_outlet() {
    let detector = detector();
    let mut tracker = Tracker::new(TrackParams::default());
    let mut scene = plain_scene(12, 0.40, 0.0, 0.0, 0.0);
    scene.pose = pose_looking(Vector3::z(), 0.40, 0.0, 0.0, 0.0);
    scene.pose.translation.vector += Vector3::new(-0.06, 0.0, 0.0);
    let frame = render_frame(&scene, "x");
    let truth = truth_pixels(&frame);
    let mut reported = 0;
    // A copy of the outlet comes in from the right edge towards the first one.
    for (k, dx) in [400i64, 330, 260, 200, 150, 120, 100].into_iter().enumerate() {
        let mut image = frame.frame.image.clone();
        paste(&mut image, &frame.frame.image, &truth, 28.0, dx, 0);
        let copy: Vec<Point2<f64>> = truth.iter().map(|p| Point2::new(p.x + dx as f64, p.y)).collect();
        let tracked = tracker.detect_grey(&detector, &grey_of(&image), None, k as f64 * FRAME_S);
        if let Some(d) = &tracked.report.detection {
            reported += 1;
            assert!(
                every_hole_near(d, &truth) || every_hole_near(d, &copy),
                "frame {k} (copy {dx} px right): holes neither the outlet's ({:.1} px) nor the copy's ({:.1} px)",
                worst_error(d, &truth),
                worst_error(d, &copy)
            );
        }
    }
    assert!(reported >= 2, "the outlet was reported in only {reported} frames");
}

#[test]
fn tracking_follows_an_outlet_growing_four_times_in_a_second() {
    let detector = detector();
    let mut tracker = Tracker::new(TrackParams::default());
    let (mut found, mut windows, mut full) = (0, 0, 0);
    let frames = 30;
    for k in 0..frames {
        // 40 cm to 10 cm in one second at 30 Hz: the holes grow four times.
        let distance = 0.40 * (0.25f64).powf(k as f64 / (frames - 1) as f64);
        let scene = plain_scene(13, distance, 8.0, 60.0, 3.0);
        let frame = render_frame(&scene, "x");
        let truth = truth_pixels(&frame);
        let grey = grey_of(&frame.frame.image);
        let tracked = tracker.detect_grey(&detector, &grey, Some(&scene.camera), k as f64 * FRAME_S);
        if let Some(d) = &tracked.report.detection {
            assert!(every_hole_near(d, &truth), "{distance:.3} m: holes {:.2} px off", worst_error(d, &truth));
            found += 1;
            match tracked.searched {
                Searched::Window(_) | Searched::Followed(_) => windows += 1,
                Searched::FullFrame { .. } => full += 1,
            }
        }
    }
    println!("found {found} of {frames}: {windows} in a window, {full} in the whole frame");
    assert!(found >= frames - 2, "found in {found} of {frames} frames");
    assert!(windows >= found - 4, "only {windows} of {found} found in a window");
}

#[test]
fn a_window_off_the_image_finds_nothing_and_one_over_it_all_finds_what_the_frame_does() {
    let detector = detector();
    let scene = plain_scene(14, 0.33, 10.0, 20.0, 0.0);
    let frame = render_frame(&scene, "x");
    let grey = grey_of(&frame.frame.image);
    for window in [[700, 0, 100, 100], [0, 500, 100, 100], [10, 10, 0, 50]] {
        let report = detector.detect_window(&grey, Some(&scene.camera), window);
        assert!(report.detection.is_none() && report.candidates.is_empty(), "{window:?}");
        assert!(report.rejected.is_some_and(|why| why.contains("empty")), "{window:?}");
    }
    let whole = detector.detect_window(&grey, Some(&scene.camera), [0, 0, u32::MAX, u32::MAX]);
    let frame_wide = detector.detect_grey(&grey, Some(&scene.camera));
    let (Some(a), Some(b)) = (whole.detection, frame_wide.detection) else { panic!("the outlet is found") };
    assert_eq!(a, b);
}

#[test]
fn a_followed_outlet_is_verified_where_it_is_and_refused_a_hole_pitch_away() {
    let detector = detector();
    let scene = plain_scene(14, 0.33, 10.0, 20.0, 0.0);
    let frame = render_frame(&scene, "x");
    let grey = grey_of(&frame.frame.image);
    let truth = truth_pixels(&frame);
    let found = detector.detect_grey(&grey, Some(&scene.camera)).detection.expect("the outlet is found");
    let last: Vec<Point2<f64>> = found.holes.iter().map(|h| h.pixel).collect();
    let verify = |h: &nalgebra::Matrix3<f64>, guesses: &[Point2<f64>], max_move: f64| {
        detector.verify_at(&grey, [0, 0], Some(&scene.camera), h, guesses, found.score, max_move)
    };
    // Where it was: the same outlet, verified.
    let again = verify(&found.homography, &last, 10.0).detection.expect("verified where it is");
    assert!(every_hole_near(&again, &truth), "{:.2} px off", worst_error(&again, &truth));
    // A hole that had to move further than allowed refuses it.
    let moved: Vec<Point2<f64>> = last.iter().map(|p| p + nalgebra::Vector2::new(2.0, 0.0)).collect();
    let report = verify(&found.homography, &moved, 1.0);
    assert!(report.detection.is_none(), "a 2 px move was taken with 1 px allowed");
    assert!(report.rejected.is_some_and(|why| why.contains("moved")));
    // The outlet a slot pitch (12.7 mm) to the side, or half a duplex pitch
    // (19.05 mm) down: holes on the bare plate, never an outlet.
    let geometry = &detector.template().geometry;
    for shift in [
        nalgebra::Matrix3::new(1.0, 0.0, 12.7, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 19.05, 0.0, 0.0, 1.0),
    ] {
        let h = found.homography * shift;
        let guesses: Vec<Point2<f64>> = geometry
            .holes
            .iter()
            .map(|t| outlet_protocol::math::apply_homography(&h, &t.position()).expect("in front"))
            .collect();
        let report = verify(&h, &guesses, f64::INFINITY);
        assert!(report.detection.is_none(), "an outlet beside the real one: {:?}", report.detection);
    }
    // Guesses that do not match the template are named, not used.
    let report = verify(&found.homography, &last[..3], 10.0);
    assert!(report.rejected.is_some_and(|why| why.contains("hole guesses")));
}
