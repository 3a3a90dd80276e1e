//! Planar PnP from pixels alone: the homography of the holes' plane, decomposed
//! into a pose; its mirror (the plane tilted the other way about the line of
//! sight, which explains the pixels almost as well when the outlet is small or
//! far) is refined too. Both are returned with their costs: the caller decides
//! whether the pixels tell them apart.

use crate::Rays;
use crate::lm::{self, Fit};
use nalgebra::{Isometry3, Matrix3, Point2, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};

/// Homography from model (x, y) in metres to normalised image coordinates.
fn homography(rays: &Rays) -> Option<Matrix3<f64>> {
    let pairs: Vec<_> =
        rays.model.iter().zip(&rays.xy).map(|(p, q)| (Point2::new(p.x, p.y), Point2::new(q.x, q.y))).collect();
    outlet_protocol::math::fit_homography(&pairs)
}

/// H ∝ [r1 r2 t]: the pose, rotation made orthonormal, in front of the camera.
fn decompose(h: &Matrix3<f64>) -> Option<Isometry3<f64>> {
    let (h1, h2, h3) = (h.column(0).into_owned(), h.column(1).into_owned(), h.column(2).into_owned());
    let mut lambda = 2.0 / (h1.norm() + h2.norm());
    if !lambda.is_finite() {
        return None;
    }
    if (h3 * lambda).z < 0.0 {
        lambda = -lambda;
    }
    let (r1, r2, t) = (h1 * lambda, h2 * lambda, h3 * lambda);
    let m = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut u = u;
        u.column_mut(2).neg_mut();
        r = u * vt;
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}

/// The pose whose plane is mirrored about the line of sight to the holes.
fn mirrored(pose: &Isometry3<f64>, rays: &Rays) -> Option<Isometry3<f64>> {
    let centre = rays.model.iter().fold(Vector3::zeros(), |s, p| s + (pose * p).coords) / rays.model.len() as f64;
    let v = centre.try_normalize(1e-12)?;
    let n = pose.rotation * Vector3::z();
    let n2 = v * 2.0 * v.dot(&n) - n;
    let axis = Unit::try_new(n.cross(&n2), 1e-12)?;
    let angle = n.dot(&n2).clamp(-1.0, 1.0).acos();
    let q = UnitQuaternion::from_axis_angle(&axis, angle);
    // Turn about the holes' centroid so that it stays where the pixels put it.
    let rotation = q * pose.rotation;
    let model_centre = rays.model.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / rays.model.len() as f64;
    let t = centre - rotation * model_centre;
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}

/// A refined pose and its cost (sum of squared whitened residuals).
pub(crate) struct Solution {
    pub fit: Fit,
    pub cost: f64,
}

/// The better of the two mirror solutions, and the other when it converged.
pub(crate) fn solve(rays: &Rays) -> Option<(Solution, Option<Solution>)> {
    let start = decompose(&homography(rays)?)?;
    let first = lm::refine(rays, start, None)?;
    let first = Solution { cost: lm::cost(rays, &first.pose, None), fit: first };
    let second = mirrored(&first.fit.pose, rays)
        .and_then(|m| lm::refine(rays, m, None))
        .map(|fit| Solution { cost: lm::cost(rays, &fit.pose, None), fit });
    Some(match second {
        Some(s) if s.cost < first.cost => (s, Some(first)),
        other => (first, other),
    })
}
