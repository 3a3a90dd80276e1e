//! The paper's closed form (section V): with the wall normal known, the cost in
//! the object plane, `f = Σ |p_i - r_i|²` with `r_i = k_i d / (k_i · n)`, has one
//! minimum: translation from the rays (eq. 11), distance from eq. (15), in-plane
//! angle from eq. (17), the root with positive depth.

use crate::Rays;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector2, Vector3};

/// In-plane angle, distance and centroids of the closed form.
struct Parts {
    /// Rays scaled to meet the plane `n · X = 1` (the paper's k_i / (k_i · n)).
    w_mean: Vector3<f64>,
    /// The in-plane basis a^p, b^p of equation (16).
    ap: Vector3<f64>,
    bp: Vector3<f64>,
    phi: f64,
    /// Equation (15): the distance that minimises f for the angle phi.
    d: f64,
    /// Centroid of the model points (outlet frame, m).
    centroid: Vector2<f64>,
}

fn parts(model: &[Point3<f64>], xy: &[Vector2<f64>], n: &Unit<Vector3<f64>>) -> Option<Parts> {
    let m = model.len();
    if m < 2 || m != xy.len() {
        return None;
    }
    let w: Vec<Vector3<f64>> = xy
        .iter()
        .map(|p| {
            let k = Vector3::new(p.x, p.y, 1.0);
            k / k.dot(n)
        })
        .collect();
    let w_mean = w.iter().fold(Vector3::zeros(), |s, v| s + v) / m as f64;
    let centroid = model.iter().fold(Vector2::zeros(), |s, p| s + Vector2::new(p.x, p.y)) / m as f64;
    // a^p = n × x0 (x0 the image's x axis), b^p = n × a^p: then a^p × b^p = n.
    let x0 = if n.x.abs() < 0.95 { Vector3::x() } else { Vector3::y() };
    let ap = n.cross(&x0).normalize();
    let bp = n.cross(&ap);
    let (mut c, mut s, mut q2) = (0.0, 0.0, 0.0);
    for (p, wi) in model.iter().zip(&w) {
        let q = wi - w_mean;
        let (alpha, beta) = (p.x - centroid.x, p.y - centroid.y);
        let (qa, qb) = (q.dot(&ap), q.dot(&bp));
        c += alpha * qa + beta * qb;
        s += beta * qa - alpha * qb;
        q2 += q.norm_squared();
    }
    // dS/dphi = 0 (eq. 17) has two roots a half turn apart; this one gives d > 0.
    let phi = s.atan2(c);
    let d = (c * c + s * s).sqrt() / q2;
    (q2 > 1e-18 && d.is_finite() && d > 0.0).then_some(Parts { w_mean, ap, bp, phi, d, centroid })
}

fn assemble(parts: &Parts, n: &Unit<Vector3<f64>>, d: f64) -> Isometry3<f64> {
    let (sin, cos) = parts.phi.sin_cos();
    let a = parts.ap * cos - parts.bp * sin;
    let b = parts.ap * sin + parts.bp * cos;
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[a, b, n.into_inner()]));
    // Eq. (11): the holes' centroid is the mean of the rays met at distance d.
    let centroid_cam = parts.w_mean * d;
    let origin = centroid_cam - rotation * Vector3::new(parts.centroid.x, parts.centroid.y, 0.0);
    Isometry3::from_parts(Translation3::from(origin), UnitQuaternion::from_rotation_matrix(&rotation))
}

/// The pose that minimises the paper's object-plane cost for a normal `n` pointing
/// away from the camera. Model points in metres on z = 0; `xy` the normalised
/// undistorted image coordinates. `None` when the rays do not determine it.
pub fn closed_form_normal(
    model: &[Point3<f64>],
    xy: &[Vector2<f64>],
    n: &Unit<Vector3<f64>>,
) -> Option<Isometry3<f64>> {
    let p = parts(model, xy, n)?;
    Some(assemble(&p, n, p.d))
}

/// The same with the plane's distance known (the holes' plane `n · X = d`).
pub(crate) fn with_distance(
    model: &[Point3<f64>],
    xy: &[Vector2<f64>],
    n: &Unit<Vector3<f64>>,
    d: f64,
) -> Option<Isometry3<f64>> {
    let p = parts(model, xy, n)?;
    Some(assemble(&p, n, d))
}

/// Covariance of each hole of the closed form, by first-order propagation of the
/// rays' covariance and the normal's (`sigma_rad` per tangent direction).
pub(crate) fn covariances(rays: &Rays, n: &Unit<Vector3<f64>>, sigma_rad: f64) -> Vec<Matrix3<f64>> {
    let m = rays.model.len();
    let holes = |xy: &[Vector2<f64>], n: &Unit<Vector3<f64>>| -> Option<Vec<Vector3<f64>>> {
        let pose = closed_form_normal(&rays.model, xy, n)?;
        Some(rays.model.iter().map(|p| (pose * p).coords).collect())
    };
    let [e1, e2] = crate::tangent_basis(n);
    let h = 1e-7;
    let mut xy = rays.xy.clone();
    // Rays: their 2x2 covariances are full, so propagate per ray with J_k Σ_k J_kᵀ.
    let mut total = vec![Matrix3::zeros(); m];
    for k in 0..m {
        let mut jk = vec![nalgebra::Matrix3x2::zeros(); m];
        for axis in 0..2 {
            let base = xy[k][axis];
            xy[k][axis] = base + h;
            let plus = holes(&xy, n);
            xy[k][axis] = base - h;
            let minus = holes(&xy, n);
            xy[k][axis] = base;
            if let (Some(p), Some(q)) = (plus, minus) {
                for i in 0..m {
                    jk[i].set_column(axis, &((p[i] - q[i]) / (2.0 * h)));
                }
            }
        }
        for i in 0..m {
            total[i] += jk[i] * rays.covariance[k] * jk[i].transpose() * rays.share.powi(2);
        }
    }
    if sigma_rad > 0.0 {
        for e in [e1, e2] {
            let tilt = |s: f64| Unit::new_normalize(n.into_inner() + e * s);
            let (p, q) = (holes(&rays.xy, &tilt(1e-6)), holes(&rays.xy, &tilt(-1e-6)));
            if let (Some(p), Some(q)) = (p, q) {
                for i in 0..m {
                    let c = (p[i] - q[i]) / 2e-6;
                    total[i] += c * c.transpose() * sigma_rad * sigma_rad;
                }
            }
        }
    }
    total
}

/// Adds to each hole's covariance what errors common to every hole do to the
/// closed form: each mode is one unit draw, the move of each hole's normalised
/// coordinates (see [`crate::robust::common_modes`]).
pub(crate) fn add_common_modes(
    total: &mut [Matrix3<f64>],
    rays: &Rays,
    n: &Unit<Vector3<f64>>,
    modes: &[Vec<Vector2<f64>>],
) {
    let holes = |xy: &[Vector2<f64>]| -> Option<Vec<Vector3<f64>>> {
        let pose = closed_form_normal(&rays.model, xy, n)?;
        Some(rays.model.iter().map(|p| (pose * p).coords).collect())
    };
    for mode in modes {
        // The closed form is differentiated numerically, by moves of the same
        // size whatever the draw's (1e-6 of the normalised image, a thousandth
        // of a pixel at f = 1000 px): the result is then exactly quadratic in
        // the draw's sigma.
        let size = mode.iter().map(|d| d.norm()).fold(0.0, f64::max);
        if !(size > 0.0 && size.is_finite()) {
            continue;
        }
        let h = 1e-6 / size;
        let moved =
            |sign: f64| -> Vec<Vector2<f64>> { rays.xy.iter().zip(mode).map(|(xy, d)| xy + d * (h * sign)).collect() };
        if let (Some(p), Some(q)) = (holes(&moved(1.0)), holes(&moved(-1.0))) {
            for (t, (a, b)) in total.iter_mut().zip(p.iter().zip(&q)) {
                let c = (a - b) / (2.0 * h);
                *t += c * c.transpose();
            }
        }
    }
}
