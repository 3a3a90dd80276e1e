//! The pose solvers on any detection: hole pixels, model points, camera, wall
//! normal and plane as they arrive from the detector and the normal estimator.
//! A pose or an error, never a panic; what is returned is finite.
#![no_main]

use arbitrary::{Arbitrary, Unstructured};
use libfuzzer_sys::fuzz_target;
use nalgebra::{Matrix3, Point2, Unit, Vector3};
use outlet_pose::{Observations, OutletPose, PlaneMeasurement, solve_mono, solve_normal, solve_plane};
use outlet_protocol::CameraModel;

fn finite(pose: &OutletPose) -> bool {
    pose.holes_cam_m.iter().all(|h| h.coords.iter().all(|v| v.is_finite()))
        && pose.holes_cam_m.iter().all(|h| h.z > 0.0)
        && pose.pose.translation.vector.iter().all(|v| v.is_finite())
}

/// A value that is often near what a real detection holds and sometimes anything.
fn number(u: &mut Unstructured, centre: f64, spread: f64) -> arbitrary::Result<f64> {
    Ok(match u.int_in_range(0..=7u8)? {
        0 => f64::arbitrary(u)?,
        _ => centre + spread * (i16::arbitrary(u)? as f64 / i16::MAX as f64),
    })
}

fuzz_target!(|data: &[u8]| {
    let mut u = Unstructured::new(data);
    let mut run = || -> arbitrary::Result<()> {
        let camera = if bool::arbitrary(&mut u)? {
            CameraModel::default_vga()
        } else {
            let intrinsics = [
                number(&mut u, 525.0, 500.0)?,
                number(&mut u, 525.0, 500.0)?,
                number(&mut u, 320.0, 320.0)?,
                number(&mut u, 240.0, 240.0)?,
            ];
            let mut distortion = [0.0; 5];
            for k in &mut distortion {
                *k = number(&mut u, 0.0, 0.5)?;
            }
            match CameraModel::new(640, 480, intrinsics, distortion) {
                Ok(c) => c,
                Err(_) => return Ok(()),
            }
        };
        let n = u.int_in_range(0..=12usize)?;
        let mut model = Vec::with_capacity(n);
        let mut pixels = Vec::with_capacity(n);
        for _ in 0..n {
            model.push(Point2::new(number(&mut u, 0.0, 30.0)?, number(&mut u, 0.0, 30.0)?));
            pixels.push(Point2::new(number(&mut u, 320.0, 400.0)?, number(&mut u, 240.0, 300.0)?));
        }
        let pixel_sigma = number(&mut u, 0.3, 0.3)?;
        let obs = Observations { model_mm: &model, pixels: &pixels, camera: &camera, pixel_sigma, pixel_sigmas: None };
        let normal = Vector3::new(number(&mut u, 0.0, 1.0)?, number(&mut u, 0.0, 1.0)?, number(&mut u, 1.0, 1.0)?);
        if let Ok(p) = solve_normal(&obs, &normal, number(&mut u, 0.01, 0.01)?) {
            assert!(finite(&p), "{p:?}");
        }
        if let Ok(p) = solve_mono(&obs) {
            assert!(finite(&p), "{p:?}");
        }
        let mut plane = PlaneMeasurement::new(
            normal,
            number(&mut u, 0.4, 0.4)?,
            number(&mut u, 0.01, 0.01)?,
            number(&mut u, 0.001, 0.001)?,
            number(&mut u, 0.005, 0.005)?,
        );
        if bool::arbitrary(&mut u)? {
            let c: [f64; 9] = Arbitrary::arbitrary(&mut u)?;
            plane.covariance = Matrix3::from_row_slice(&c);
            plane.normal = Unit::new_unchecked(normal);
        }
        if let Ok(p) = solve_plane(&obs, &plane) {
            assert!(finite(&p), "{p:?}");
        }
        Ok(())
    };
    let _ = run();
});
