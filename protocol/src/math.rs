//! Small geometry shared by the detector and the pose: a basis of a plane and
//! the homography between two planes.

use nalgebra::{Matrix3, Point2, Vector2, Vector3};

/// Two unit vectors completing `n` to a right-handed basis `(e1, e2, n)`:
/// `e1 = normalize(n × x)` (`n × y` when `n` is close to the x axis), `e2 = n × e1`.
/// Plane covariances (`δa`, `δb` of a normal) are expressed in this basis.
pub fn tangent_basis(n: &Vector3<f64>) -> [Vector3<f64>; 2] {
    let helper = if n.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    [e1, e2]
}

/// Applies a homography; `None` at or beyond the horizon.
pub fn apply_homography(h: &Matrix3<f64>, p: &Point2<f64>) -> Option<Point2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    (q.z.abs() > 1e-12 && q.x.is_finite() && q.y.is_finite()).then(|| Point2::new(q.x / q.z, q.y / q.z))
}

/// Least-squares homography taking the first point of each pair to the second
/// (normalised DLT, Hartley): `None` for fewer than 4 pairs or degenerate ones.
pub fn fit_homography(pairs: &[(Point2<f64>, Point2<f64>)]) -> Option<Matrix3<f64>> {
    if pairs.len() < 4 {
        return None;
    }
    // Centroid at the origin, mean distance sqrt(2): conditions the system.
    // (Two passes over the pairs, no copy: this runs many times per frame.)
    type Pick = fn(&(Point2<f64>, Point2<f64>)) -> Point2<f64>;
    let normaliser = |point: Pick| {
        let n = pairs.len() as f64;
        let c = pairs.iter().fold(Vector2::zeros(), |s, p| s + point(p).coords) / n;
        let d = pairs.iter().map(|p| (point(p).coords - c).norm()).sum::<f64>() / n;
        if !(d > 1e-12 && d.is_finite()) {
            return None;
        }
        let s = std::f64::consts::SQRT_2 / d;
        Some(Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0))
    };
    let ta = normaliser(|p| p.0)?;
    let tb = normaliser(|p| p.1)?;
    // AᵀA accumulated directly: its null vector is the homography.
    let mut ata = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    for (p, q) in pairs {
        let p = ta * Vector3::new(p.x, p.y, 1.0);
        let q = tb * Vector3::new(q.x, q.y, 1.0);
        let (x, y, u, v) = (p.x, p.y, q.x, q.y);
        let r1 = nalgebra::SVector::<f64, 9>::from([-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u]);
        let r2 = nalgebra::SVector::<f64, 9>::from([0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
        ata += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let eig = ata.symmetric_eigen();
    let h = eig.eigenvectors.column(eig.eigenvalues.imin());
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let h = tb.try_inverse()? * hn * ta;
    (h[(2, 2)].abs() > 1e-15 && h.iter().all(|v| v.is_finite())).then(|| h / h[(2, 2)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_homography_is_recovered_from_its_points() {
        let h = Matrix3::new(1.2, 0.1, 5.0, -0.05, 0.9, -3.0, 0.001, -0.002, 1.0);
        let pts = [(0.0, 0.0), (10.0, 0.0), (0.0, 12.0), (9.0, 11.0), (4.0, 5.0), (-3.0, 7.0)];
        let pairs: Vec<_> = pts
            .iter()
            .map(|&(x, y)| {
                let p = Point2::new(x, y);
                (p, apply_homography(&h, &p).expect("finite"))
            })
            .collect();
        let fitted = fit_homography(&pairs).expect("fit");
        assert!((fitted - h).abs().max() < 1e-9, "{fitted}");
        assert!(fit_homography(&pairs[..3]).is_none());
        let [e1, e2] = tangent_basis(&Vector3::new(0.1, -0.3, 0.9).normalize());
        assert!((e1.cross(&e2) - Vector3::new(0.1, -0.3, 0.9).normalize()).norm() < 1e-12);
    }
}
