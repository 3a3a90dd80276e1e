//! Levenberg-Marquardt over a pose: the reprojection error of the holes, whitened
//! by their pixel covariance, plus an optional prior on the holes' plane.

use crate::Rays;
use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, Rotation3, SMatrix, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// A Gaussian prior on the holes' plane `n · X = d` (camera frame).
pub(crate) struct Prior {
    pub normal: Vector3<f64>,
    pub distance_m: f64,
    pub tangent: [Vector3<f64>; 2],
    /// Inverse Cholesky factor of the covariance of (δa, δb, δd).
    pub whiten: Matrix3<f64>,
    /// Whether the distance is part of the prior (else only the normal).
    pub with_distance: bool,
}

/// A refined pose and the covariance of its parameters (rotation vector applied
/// on the left, translation).
#[derive(Clone)]
pub(crate) struct Fit {
    pub pose: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

type Row = SMatrix<f64, 1, 6>;

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Residuals and their Jacobian rows at a pose.
fn linearise(rays: &Rays, pose: &Isometry3<f64>, prior: Option<&Prior>) -> Option<(Vec<f64>, Vec<Row>)> {
    let r = pose.rotation.to_rotation_matrix();
    let mut res = Vec::with_capacity(2 * rays.model.len() + 3);
    let mut jac = Vec::with_capacity(2 * rays.model.len() + 3);
    for ((p, obs), w) in rays.model.iter().zip(&rays.xy).zip(&rays.whiten) {
        let rp = r * p.coords;
        let x = rp + pose.translation.vector;
        if x.z.is_nan() || x.z <= 1e-9 {
            return None;
        }
        let (u, v) = (x.x / x.z, x.y / x.z);
        let dpi = nalgebra::Matrix2x3::new(1.0 / x.z, 0.0, -u / x.z, 0.0, 1.0 / x.z, -v / x.z);
        let mut dx = SMatrix::<f64, 3, 6>::zeros();
        dx.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&rp)));
        dx.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
        let e = w * nalgebra::Vector2::new(u - obs.x, v - obs.y);
        let j = w * dpi * dx;
        for k in 0..2 {
            res.push(e[k]);
            jac.push(j.row(k).into_owned());
        }
    }
    if let Some(prior) = prior {
        let (e, j) = prior_rows(prior, pose);
        for k in 0..3 {
            res.push(e[k]);
            jac.push(j.row(k).into_owned());
        }
    }
    Some((res, jac))
}

/// The prior's whitened residual and its Jacobian at a pose (three rows).
fn prior_rows(prior: &Prior, pose: &Isometry3<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
    let n = pose.rotation.to_rotation_matrix() * Vector3::z();
    let t = pose.translation.vector;
    let dn = n - prior.normal;
    let raw = Vector3::new(prior.tangent[0].dot(&dn), prior.tangent[1].dot(&dn), n.dot(&t) - prior.distance_m);
    let mut raw_j = SMatrix::<f64, 3, 6>::zeros();
    for k in 0..2 {
        let g = n.cross(&prior.tangent[k]);
        raw_j.fixed_view_mut::<1, 3>(k, 0).copy_from(&g.transpose());
    }
    if prior.with_distance {
        raw_j.fixed_view_mut::<1, 3>(2, 0).copy_from(&n.cross(&t).transpose());
        raw_j.fixed_view_mut::<1, 3>(2, 3).copy_from(&n.transpose());
    }
    let raw = if prior.with_distance { raw } else { Vector3::new(raw.x, raw.y, 0.0) };
    (prior.whiten * raw, prior.whiten * raw_j)
}

fn normal_equations(res: &[f64], jac: &[Row]) -> (Matrix6<f64>, Vector6<f64>, f64) {
    let mut jtj = Matrix6::zeros();
    let mut jtr = Vector6::zeros();
    let mut cost = 0.0;
    for (r, j) in res.iter().zip(jac) {
        jtj += j.transpose() * j;
        jtr += j.transpose() * *r;
        cost += r * r;
    }
    (jtj, jtr, cost)
}

fn step(pose: &Isometry3<f64>, delta: &Vector6<f64>) -> Isometry3<f64> {
    let w = Vector3::new(delta[0], delta[1], delta[2]);
    let rot = Rotation3::new(w) * pose.rotation.to_rotation_matrix();
    let t = pose.translation.vector + Vector3::new(delta[3], delta[4], delta[5]);
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_rotation_matrix(&rot))
}

/// Levenberg-Marquardt from `start`; the covariance is (Jᵀ J)⁻¹ at the optimum.
pub(crate) fn refine(rays: &Rays, start: Isometry3<f64>, prior: Option<&Prior>) -> Option<Fit> {
    let mut pose = start;
    let (res, jac) = linearise(rays, &pose, prior)?;
    let (mut jtj, mut jtr, mut cost) = normal_equations(&res, &jac);
    let mut lambda = 1e-3;
    for _ in 0..50 {
        let mut a = jtj;
        for k in 0..6 {
            a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
        }
        let Some(delta) = a.cholesky().map(|c| c.solve(&(-jtr))) else {
            lambda *= 10.0;
            continue;
        };
        let candidate = step(&pose, &delta);
        match linearise(rays, &candidate, prior) {
            Some((res, jac)) => {
                let (njtj, njtr, ncost) = normal_equations(&res, &jac);
                if ncost <= cost {
                    let converged = cost - ncost < 1e-12 * (1.0 + cost) && delta.norm() < 1e-12;
                    (pose, jtj, jtr, cost) = (candidate, njtj, njtr, ncost);
                    lambda = (lambda * 0.3).max(1e-9);
                    if converged || delta.norm() < 1e-13 {
                        break;
                    }
                } else {
                    lambda *= 10.0;
                }
            }
            None => lambda *= 10.0,
        }
        if lambda > 1e9 {
            break;
        }
    }
    let covariance = jtj.try_inverse()?;
    Some(Fit { pose, covariance })
}

/// The covariance at a given pose, without moving it (for Cramér-Rao bounds).
pub(crate) fn at(rays: &Rays, pose: Isometry3<f64>, prior: Option<&Prior>) -> Option<Fit> {
    let (res, jac) = linearise(rays, &pose, prior)?;
    let (jtj, _, _) = normal_equations(&res, &jac);
    Some(Fit { pose, covariance: jtj.try_inverse()? })
}

/// The cost (sum of squared whitened residuals) at a pose.
pub(crate) fn cost(rays: &Rays, pose: &Isometry3<f64>, prior: Option<&Prior>) -> f64 {
    linearise(rays, pose, prior).map_or(f64::INFINITY, |(r, _)| r.iter().map(|v| v * v).sum())
}

/// The fit's covariance with the holes' own noise at `rays.share` of their
/// sigma, the estimate weighed by the whole sigma as it is: `A⁻¹ (k² H + P)
/// A⁻¹` for A = H + P (H from the pixels, P from the prior), which is `k² A⁻¹`
/// without a prior.
pub(crate) fn with_own_noise(fit: Fit, rays: &Rays, prior: Option<&Prior>) -> Fit {
    let k2 = rays.share.powi(2);
    let c = fit.covariance;
    // The prior's information alone (the pixels' need not be linearised again).
    let from_prior = prior.map(|prior| {
        let (_, j) = prior_rows(prior, &fit.pose);
        j.transpose() * j
    });
    let covariance = match from_prior {
        Some(p) => c * k2 + c * p * c * (1.0 - k2),
        None => c * k2,
    };
    Fit { covariance: (covariance + covariance.transpose()) * 0.5, ..fit }
}

/// Each hole's position covariance from the pose parameters' covariance.
pub(crate) fn hole_covariances(fit: &Fit, model: &[Point3<f64>]) -> Vec<Matrix3<f64>> {
    let r = fit.pose.rotation.to_rotation_matrix();
    model
        .iter()
        .map(|p| {
            let mut a = SMatrix::<f64, 3, 6>::zeros();
            a.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&(r * p.coords))));
            a.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
            let c = a * fit.covariance * a.transpose();
            (c + c.transpose()) * 0.5
        })
        .collect()
}

/// Each hole's squared whitened reprojection residual at a pose (2 degrees of
/// freedom each when the pixel noise is as assumed); infinite behind the camera.
pub(crate) fn hole_costs(rays: &Rays, pose: &Isometry3<f64>) -> Vec<f64> {
    rays.model
        .iter()
        .zip(&rays.xy)
        .zip(&rays.whiten)
        .map(|((p, obs), w)| {
            let x = pose * p;
            if x.z.is_nan() || x.z <= 1e-9 {
                return f64::INFINITY;
            }
            (w * nalgebra::Vector2::new(x.x / x.z - obs.x, x.y / x.z - obs.y)).norm_squared()
        })
        .collect()
}

/// The covariance (pose parameters) that errors common to every hole add to a
/// fit. Each mode is one unit draw of such an error: the move of each hole's
/// normalised coordinates (a common pixel shift, a common scale). The estimate
/// moves by `(Jᵀ J)⁻¹ Jᵀ W δxy` for observations moved by `δxy`.
pub(crate) fn common_covariance(
    rays: &Rays,
    pose: &Isometry3<f64>,
    prior: Option<&Prior>,
    modes: &[Vec<nalgebra::Vector2<f64>>],
) -> Option<Matrix6<f64>> {
    let (res, jac) = linearise(rays, pose, prior)?;
    let (jtj, _, _) = normal_equations(&res, &jac);
    let inv = jtj.try_inverse()?;
    let mut total = Matrix6::zeros();
    for mode in modes {
        let mut g = Vector6::zeros();
        for (k, (w, d)) in rays.whiten.iter().zip(mode).enumerate() {
            let moved = w * d;
            for axis in 0..2 {
                g += jac.get(2 * k + axis)?.transpose() * moved[axis];
            }
        }
        let g = inv * g;
        total += g * g.transpose();
    }
    Some(total)
}
