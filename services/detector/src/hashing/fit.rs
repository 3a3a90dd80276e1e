//! Least-squares fits of template-to-image transforms (affine, normalised DLT
//! homography) and their application to points.

use nalgebra::{Matrix3, Point2, SMatrix, SVector, Vector2};

/// `t` applied to a point (homogeneous division).
pub(super) fn apply(t: &Matrix3<f64>, p: Point2<f64>) -> Point2<f64> {
    let w = t[(2, 0)] * p.x + t[(2, 1)] * p.y + t[(2, 2)];
    Point2::new(
        (t[(0, 0)] * p.x + t[(0, 1)] * p.y + t[(0, 2)]) / w,
        (t[(1, 0)] * p.x + t[(1, 1)] * p.y + t[(1, 2)]) / w,
    )
}

/// Similarity that moves `points` to their centroid and scales their mean
/// distance from it to sqrt(2) (Hartley), as (centroid, scale).
pub(super) fn normaliser(points: &[Point2<f64>]) -> Option<(Vector2<f64>, f64)> {
    let n = points.len() as f64;
    let c = points.iter().map(|p| p.coords).sum::<Vector2<f64>>() / n;
    let mean = points.iter().map(|p| (p.coords - c).norm()).sum::<f64>() / n;
    if mean > 0.0 && mean.is_finite() { Some((c, std::f64::consts::SQRT_2 / mean)) } else { None }
}

/// Least-squares affine transform taking `src` to `dst` (at least 3 pairs).
pub(super) fn fit_affine(src: &[Point2<f64>], dst: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    if src.len() < 3 {
        return None;
    }
    let (cs, ss) = normaliser(src)?;
    let (cd, sd) = normaliser(dst)?;
    let mut ata = SMatrix::<f64, 3, 3>::zeros();
    let mut atu = SVector::<f64, 3>::zeros();
    let mut atv = SVector::<f64, 3>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let x = (s.coords - cs) * ss;
        let y = (d.coords - cd) * sd;
        let row = SVector::<f64, 3>::new(x.x, x.y, 1.0);
        ata += row * row.transpose();
        atu += row * y.x;
        atv += row * y.y;
    }
    let chol = ata.cholesky()?;
    let (u, v) = (chol.solve(&atu), chol.solve(&atv));
    let normalised = Matrix3::new(u[0], u[1], u[2], v[0], v[1], v[2], 0.0, 0.0, 1.0);
    let t = denormalise(&normalised, cs, ss, cd, sd);
    if t.iter().all(|x| x.is_finite()) { Some(t) } else { None }
}

/// Normalised DLT homography taking `src` to `dst` (at least 4 pairs), scaled so
/// that w = 1 at `centre` (a point of the template).
pub(super) fn fit_homography(src: &[Point2<f64>], dst: &[Point2<f64>], centre: Point2<f64>) -> Option<Matrix3<f64>> {
    if src.len() < 4 {
        return None;
    }
    let (cs, ss) = normaliser(src)?;
    let (cd, sd) = normaliser(dst)?;
    // h33 = 1 in normalised coordinates: the template's centroid, at the origin
    // there, maps to a finite image point.
    let mut ata = SMatrix::<f64, 8, 8>::zeros();
    let mut atb = SVector::<f64, 8>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let x = (s.coords - cs) * ss;
        let y = (d.coords - cd) * sd;
        let ru = SVector::<f64, 8>::from([x.x, x.y, 1.0, 0.0, 0.0, 0.0, -y.x * x.x, -y.x * x.y]);
        let rv = SVector::<f64, 8>::from([0.0, 0.0, 0.0, x.x, x.y, 1.0, -y.y * x.x, -y.y * x.y]);
        ata += ru * ru.transpose() + rv * rv.transpose();
        atb += ru * y.x + rv * y.y;
    }
    let h = ata.cholesky()?.solve(&atb);
    let normalised = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    let t = denormalise(&normalised, cs, ss, cd, sd);
    let w = t[(2, 0)] * centre.x + t[(2, 1)] * centre.y + t[(2, 2)];
    let finite_centre = w.abs() > 1e-12;
    if !finite_centre {
        return None;
    }
    let t = t / w;
    if t.iter().all(|x| x.is_finite()) { Some(t) } else { None }
}

/// T_dst^-1 * normalised * T_src.
pub(super) fn denormalise(
    normalised: &Matrix3<f64>,
    cs: Vector2<f64>,
    ss: f64,
    cd: Vector2<f64>,
    sd: f64,
) -> Matrix3<f64> {
    let t_src = Matrix3::new(ss, 0.0, -ss * cs.x, 0.0, ss, -ss * cs.y, 0.0, 0.0, 1.0);
    let t_dst_inv = Matrix3::new(1.0 / sd, 0.0, cd.x, 0.0, 1.0 / sd, cd.y, 0.0, 0.0, 1.0);
    t_dst_inv * normalised * t_src
}
