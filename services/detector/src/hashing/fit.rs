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

/// Pinhole intrinsics of the undistorted pixels the candidates are given in:
/// focal lengths and principal point (pixels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Least-squares template-to-image homography of a rigid planar template seen
/// by a calibrated camera (at least 4 pairs): K [r1 r2 t], six unknowns (the
/// pose) where an affine map has six and a homography eight. Unlike the affine
/// map it holds the perspective of an outlet seen close up and obliquely (at
/// 10 cm and 35 degrees one receptacle is a third larger than the other); unlike
/// a homography through 4-5 points it cannot bend to fit a stray point. Scaled
/// so that w = 1 at `centre`. `None` where the points do not fix a pose in
/// front of the camera.
pub(super) fn fit_planar_pose(
    src: &[Point2<f64>],
    dst: &[Point2<f64>],
    k: &Intrinsics,
    centre: Point2<f64>,
) -> Option<Matrix3<f64>> {
    use nalgebra::{Matrix2x3, Matrix6, Rotation3, Vector3, Vector6};
    if src.len() < 4 || src.len() != dst.len() || !(k.fx > 0.0 && k.fy > 0.0) {
        return None;
    }
    let mut rays = [Point2::origin(); super::MAX_TEMPLATE_HOLES];
    let n = src.len().min(rays.len());
    for (r, d) in rays.iter_mut().zip(dst) {
        *r = Point2::new((d.x - k.cx) / k.fx, (d.y - k.cy) / k.fy);
    }
    let (src, rays) = (&src[..n], &rays[..n]);
    // First guess: the homography to the normalised rays is lambda [r1 r2 t].
    let h = fit_homography(src, rays, centre)?;
    let (h1, h2, h3) = (h.column(0).into_owned(), h.column(1).into_owned(), h.column(2).into_owned());
    let lambda = (h1.norm() + h2.norm()) / 2.0;
    if lambda.is_nan() || lambda <= 0.0 {
        return None;
    }
    let (r1, r2) = (h1 / lambda, h2 / lambda);
    let columns = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = columns.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut rotation = u * v_t;
    if rotation.determinant() < 0.0 {
        return None;
    }
    let mut t = h3 / lambda;
    // Gauss-Newton on the pose, residuals in pixels.
    let scale = Vector3::new(k.fx, k.fy, 1.0);
    for _ in 0..10 {
        let (mut jtj, mut jtr) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        for (s, r) in src.iter().zip(rays) {
            let rx = rotation * Vector3::new(s.x, s.y, 0.0);
            let p = rx + t;
            let in_front = p.z > 1e-9;
            if !in_front {
                return None;
            }
            let residual = nalgebra::Vector2::new((p.x / p.z - r.x) * k.fx, (p.y / p.z - r.y) * k.fy);
            let dpi = Matrix2x3::new(
                scale.x / p.z,
                0.0,
                -scale.x * p.x / (p.z * p.z),
                0.0,
                scale.y / p.z,
                -scale.y * p.y / (p.z * p.z),
            );
            // d p / d omega (rotation applied on the left) = -[R X]x; d p / d t = I.
            let skew = Matrix3::new(0.0, rx.z, -rx.y, -rx.z, 0.0, rx.x, rx.y, -rx.x, 0.0);
            let mut jac = nalgebra::Matrix2x6::<f64>::zeros();
            jac.fixed_view_mut::<2, 3>(0, 0).copy_from(&(dpi * skew));
            jac.fixed_view_mut::<2, 3>(0, 3).copy_from(&dpi);
            jtj += jac.transpose() * jac;
            jtr += jac.transpose() * residual;
        }
        let step = (jtj + Matrix6::identity() * 1e-12).cholesky()?.solve(&(-jtr));
        let omega = Vector3::new(step[0], step[1], step[2]);
        rotation = Rotation3::new(omega).matrix() * rotation;
        t += Vector3::new(step[3], step[4], step[5]);
        if step.norm() < 1e-10 * (1.0 + t.norm()) {
            break;
        }
    }
    let kmat = Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
    let pose = Matrix3::from_columns(&[rotation.column(0).into_owned(), rotation.column(1).into_owned(), t]);
    let homography = kmat * pose;
    let w = homography[(2, 0)] * centre.x + homography[(2, 1)] * centre.y + homography[(2, 2)];
    let in_front = w > 1e-12;
    if !in_front {
        return None;
    }
    let homography = homography / w;
    if homography.iter().all(|x| x.is_finite()) { Some(homography) } else { None }
}
