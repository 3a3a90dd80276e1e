//! The receptacle face as the stereo cloud sees it: how far it stands ahead of
//! a fitted plane, measured from the points around the holes.
//!
//! The pose puts the holes on the wall moved towards the camera by the face's
//! offset. A real receptacle's face stands 3-7 mm proud of the wall, and close
//! up (an arm's camera at 10-12 cm) the plane the cloud holds most points of is
//! the wall plate, not the wall. Either way, the points on the face between the
//! holes say where the holes' plane is relative to the fitted one. A calibration
//! bias of the stereo pair moves the face and the plane alike, so their
//! difference is free of it.

use crate::WallPlane;
use nalgebra::{Isometry3, Point2, Point3};

/// Where on the face points are taken, and how many are needed.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceParams {
    /// Points are taken between these distances (mm, on the face) from a hole's
    /// centre: clear of the opening (a slot is 8.7 mm long, a ground hole 5 mm
    /// across; depth there is the hole's inside) and inside a receptacle's face
    /// (a slot's centre lies 10-12 mm from the face's edge).
    pub inner_radius_mm: f64,
    pub outer_radius_mm: f64,
    /// Fewest points that make a measurement.
    pub min_points: usize,
    /// Neighbouring stereo points share their matching window, so their errors
    /// are not independent: the mean's variance counts this many points as one.
    pub points_per_independent: f64,
    /// Offsets (mm, towards the camera) outside this range are no receptacle
    /// face: nothing is measured.
    pub offset_range_mm: (f64, f64),
}

impl Default for FaceParams {
    fn default() -> Self {
        Self {
            inner_radius_mm: 5.5,
            outer_radius_mm: 8.5,
            min_points: 12,
            points_per_independent: 4.0,
            offset_range_mm: (-5.0, 25.0),
        }
    }
}

/// The face's offset ahead of a fitted plane, as measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceOffset {
    /// How far the face stands ahead of the plane, towards the camera (metres).
    pub offset_m: f64,
    /// Its standard deviation (metres).
    pub sigma_m: f64,
    /// Points that measured it (after outliers).
    pub points: usize,
}

/// The face's offset ahead of `plane`, from the points of `cloud` (camera frame,
/// metres; NaN ignored) that lie around the holes `holes_mm` (outlet frame,
/// z = 0 on the face) of an outlet at `outlet_to_camera`. The pose need only be
/// right to a millimetre or two across the face: it picks the points, their
/// depth is the plane's. None when too few points are there (a real stereo pair
/// finds few on a smooth face) or they do not agree on one face.
pub fn measure_face(
    cloud: &[[f32; 3]],
    plane: &WallPlane,
    outlet_to_camera: &Isometry3<f64>,
    holes_mm: &[Point2<f64>],
    params: &FaceParams,
) -> Option<FaceOffset> {
    let ring = params.inner_radius_mm >= 0.0 && params.inner_radius_mm < params.outer_radius_mm;
    if holes_mm.is_empty() || !ring {
        return None;
    }
    let to_outlet = outlet_to_camera.inverse();
    let (r_in, r_out) = ((params.inner_radius_mm / 1e3).powi(2), (params.outer_radius_mm / 1e3).powi(2));
    let holes: Vec<Point2<f64>> = holes_mm.iter().map(|h| Point2::new(h.x / 1e3, h.y / 1e3)).collect();
    // The outlet's reach on the face: a cheap test before the holes'.
    let reach = holes.iter().map(|h| h.coords.norm()).fold(0.0, f64::max) + params.outer_radius_mm / 1e3;
    // A sphere about the outlet's centre holding that reach (a little wider for
    // the face's depth and f32 rounding): most of a cloud is wall far from it,
    // rejected here in a few operations per point (NaN fails the test too).
    let centre = outlet_to_camera.translation.vector.map(|v| v as f32);
    let radius = (reach + 0.01) as f32;
    let r2 = radius * radius;
    let mut offsets: Vec<f64> = cloud
        .iter()
        .filter(|p| {
            let (dx, dy, dz) = (p[0] - centre.x, p[1] - centre.y, p[2] - centre.z);
            dx * dx + dy * dy + dz * dz <= r2
        })
        .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .filter_map(|p| {
            let q = to_outlet * p;
            let xy = Point2::new(q.x, q.y);
            if xy.coords.norm() > reach {
                return None;
            }
            let nearest = holes.iter().map(|h| (h - xy).norm_squared()).fold(f64::INFINITY, f64::min);
            (nearest >= r_in && nearest <= r_out).then(|| -plane.signed_distance(&p))
        })
        .collect();
    if offsets.len() < params.min_points {
        return None;
    }
    let median = median_of(&mut offsets)?;
    let mut spread: Vec<f64> = offsets.iter().map(|o| (o - median).abs()).collect();
    // The median absolute deviation as a sigma; a floor keeps an exact cloud usable.
    let sigma = (1.4826 * median_of(&mut spread)?).max(1e-5);
    let kept: Vec<f64> = offsets.iter().copied().filter(|o| (o - median).abs() <= 3.0 * sigma).collect();
    if kept.len() < params.min_points {
        return None;
    }
    let n = kept.len() as f64;
    let mean = kept.iter().sum::<f64>() / n;
    let std = (kept.iter().map(|o| (o - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt().max(1e-5);
    let independent = (n / params.points_per_independent.max(1.0)).max(1.0);
    let (lo, hi) = params.offset_range_mm;
    (mean * 1e3 >= lo && mean * 1e3 <= hi).then_some(FaceOffset {
        offset_m: mean,
        sigma_m: std / independent.sqrt(),
        points: kept.len(),
    })
}

fn median_of(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tangent_basis;
    use nalgebra::{Matrix3, Unit, Vector3};

    /// A wall 40 cm ahead, seen head-on, with a face `offset_mm` proud of it over
    /// 60 mm around the outlet's centre, on a ray grid of 0.5 mm.
    fn scene(offset_mm: f64) -> (Vec<[f32; 3]>, WallPlane, Isometry3<f64>) {
        let z = 0.4;
        let mut cloud = Vec::new();
        for i in -200..=200 {
            for j in -200..=200 {
                let (x, y) = (i as f64 * 5e-4, j as f64 * 5e-4);
                let depth = if x.abs() < 0.03 && y.abs() < 0.03 { z - offset_mm / 1e3 } else { z };
                cloud.push([x as f32, y as f32, depth as f32]);
            }
        }
        let normal = Unit::new_normalize(Vector3::z());
        let wall = WallPlane {
            normal,
            distance_m: z,
            covariance: Matrix3::identity() * 1e-8,
            tangent: tangent_basis(&normal),
            inliers: cloud.len(),
            rms_m: 0.0,
        };
        let outlet = Isometry3::translation(0.0, 0.0, z - offset_mm / 1e3);
        (cloud, wall, outlet)
    }

    fn holes() -> Vec<Point2<f64>> {
        vec![Point2::new(-6.35, -5.0), Point2::new(6.35, -5.0), Point2::new(0.0, 6.9)]
    }

    #[test]
    fn a_face_proud_of_the_wall_is_measured_from_the_points_around_the_holes() {
        let (cloud, wall, outlet) = scene(4.2);
        let face = measure_face(&cloud, &wall, &outlet, &holes(), &FaceParams::default()).expect("measured");
        assert!((face.offset_m - 4.2e-3).abs() < 1e-6, "{face:?}");
        assert!(face.points > 100, "{face:?}");
    }

    #[test]
    fn noisy_points_and_mismatches_give_the_face_with_an_honest_sigma() {
        let (mut cloud, wall, outlet) = scene(6.0);
        // Depth noise of 2 mm and one point in ten a mismatch 30 mm off.
        let mut state = 12345u64;
        let mut uniform = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64) / ((1u64 << 53) as f64)
        };
        for p in &mut cloud {
            let gauss = (-2.0 * uniform().max(1e-12).ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos();
            p[2] += (2e-3 * gauss) as f32;
            if uniform() < 0.1 {
                p[2] -= 0.03;
            }
        }
        let face = measure_face(&cloud, &wall, &outlet, &holes(), &FaceParams::default()).expect("measured");
        let error = face.offset_m - 6.0e-3;
        assert!(error.abs() < 3.0 * face.sigma_m, "{face:?}");
        assert!(face.sigma_m < 0.5e-3, "{face:?}");
    }

    #[test]
    fn too_few_points_or_none_measure_nothing() {
        let (cloud, wall, outlet) = scene(5.0);
        assert_eq!(measure_face(&[], &wall, &outlet, &holes(), &FaceParams::default()), None);
        let sparse: Vec<[f32; 3]> = cloud.iter().step_by(4000).copied().collect();
        assert_eq!(measure_face(&sparse, &wall, &outlet, &holes(), &FaceParams::default()), None);
        let nan = vec![[f32::NAN; 3]; 1000];
        assert_eq!(measure_face(&nan, &wall, &outlet, &holes(), &FaceParams::default()), None);
        assert_eq!(measure_face(&cloud, &wall, &outlet, &[], &FaceParams::default()), None);
    }
}
