//! The wall-plane fit on any cloud (as a stereo camera might publish it) and any
//! region of interest: a plane or an error, never a panic, never a non-finite value.
#![no_main]

use arbitrary::{Arbitrary, Unstructured};
use libfuzzer_sys::fuzz_target;
use nalgebra::Point3;
use outlet_normal::{PlaneParams, fit_wall_plane};

fuzz_target!(|data: &[u8]| {
    let mut u = Unstructured::new(data);
    let mut run = || -> arbitrary::Result<()> {
        let mut params = PlaneParams { sample_size: u.int_in_range(4..=256usize)?, ..PlaneParams::default() };
        if bool::arbitrary(&mut u)? {
            let c: [f32; 4] = Arbitrary::arbitrary(&mut u)?;
            params = params.with_roi(Point3::new(c[0] as f64, c[1] as f64, c[2] as f64), c[3] as f64);
        }
        let dense = bool::arbitrary(&mut u)?;
        let mut cloud = Vec::new();
        while !u.is_empty() && cloud.len() < 4096 {
            let p = if dense {
                // Points near a wall 40 cm away: the paths of a real fit.
                let q: [i16; 3] = Arbitrary::arbitrary(&mut u)?;
                [q[0] as f32 * 1e-5, q[1] as f32 * 1e-5, 0.4 + q[2] as f32 * 1e-7 + (q[0] as f32) * 1e-6]
            } else {
                Arbitrary::arbitrary(&mut u)?
            };
            cloud.push(p);
        }
        if let Ok(wall) = fit_wall_plane(&cloud, &params) {
            assert!(wall.normal.iter().all(|v| v.is_finite()) && wall.distance_m.is_finite(), "{wall:?}");
            assert!(wall.covariance.iter().all(|v| v.is_finite()) && wall.rms_m.is_finite(), "{wall:?}");
            assert!(wall.distance_m >= 0.0, "{wall:?}");
        }
        Ok(())
    };
    let _ = run();
});
