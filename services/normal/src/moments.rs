//! The sums a pass over the cloud collects: weighted moments of the centred
//! points, from which every normal equation, Newton step and covariance of the
//! plane follows. The pass over every point is the fit's hot loop: it works in
//! blocks whose per-point weights are computed first and summed second, in
//! independent lanes that the compiler turns into vector instructions.

use nalgebra::{Matrix4, Vector3, Vector4};

/// Symmetric 4x4 moments `Σ w [X; 1] [X; 1]ᵀ` of centred points.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct Moments {
    xx: f64,
    xy: f64,
    xz: f64,
    yy: f64,
    yz: f64,
    zz: f64,
    x: f64,
    y: f64,
    z: f64,
    one: f64,
}

impl Moments {
    #[inline(always)]
    fn add(&mut self, w: f64, x: f64, y: f64, z: f64) {
        let (wx, wy, wz) = (w * x, w * y, w * z);
        self.xx += wx * x;
        self.xy += wx * y;
        self.xz += wx * z;
        self.yy += wy * y;
        self.yz += wy * z;
        self.zz += wz * z;
        self.x += wx;
        self.y += wy;
        self.z += wz;
        self.one += w;
    }

    fn from_lanes(second: &[[f64; LANES]; 6], first: &[[f64; LANES]; 4]) -> Self {
        let [xx, xy, xz, yy, yz, zz] = second.map(|l| l.iter().sum::<f64>());
        let [x, y, z, one] = first.map(|l| l.iter().sum::<f64>());
        Self { xx, xy, xz, yy, yz, zz, x, y, z, one }
    }

    pub(crate) fn matrix(&self) -> Matrix4<f64> {
        Matrix4::new(
            self.xx, self.xy, self.xz, self.x, //
            self.xy, self.yy, self.yz, self.y, //
            self.xz, self.yz, self.zz, self.z, //
            self.x, self.y, self.z, self.one,
        )
    }
}

/// The plane and noise of a pass, in the centred coordinates `X - origin`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Weighting {
    pub origin: Vector3<f64>,
    /// Unit normal.
    pub n: Vector3<f64>,
    /// `d - n · origin`: the plane is `n · (X - origin) = dc`.
    pub dc: f64,
    /// Residual sigma of a point at depth `z` is `kappa · z` (metres).
    pub kappa: f64,
    /// Tukey's constant, in sigmas.
    pub c: f64,
}

/// Tukey-reweighted moments `Σ (1 - u²/c²)² / sigma² [X; 1] [X; 1]ᵀ` over the
/// points within the band, and their number. Plain scalar code, for the sample.
pub(crate) fn reweighted_moments(points: &[[f32; 3]], wt: &Weighting) -> (Moments, usize) {
    let (kappa2, inv_c2) = (wt.kappa * wt.kappa, 1.0 / (wt.c * wt.c));
    let band2 = wt.c * wt.c * kappa2;
    let (mut moments, mut inliers) = (Moments::default(), 0);
    for p in points {
        let z = p[2] as f64;
        let (x, y, zc) = (p[0] as f64 - wt.origin.x, p[1] as f64 - wt.origin.y, z - wt.origin.z);
        let r = wt.n.x * x + wt.n.y * y + wt.n.z * zc - wt.dc;
        let (r2, z2) = (r * r, z * z);
        if z > 0.0 && r2 < band2 * z2 {
            let inv_sigma2 = 1.0 / (kappa2 * z2);
            let t = 1.0 - r2 * inv_sigma2 * inv_c2;
            moments.add(t * t * inv_sigma2, x, y, zc);
            inliers += 1;
        }
    }
    (moments, inliers)
}

/// What a Newton step and the sandwich covariance of the M-estimate need, with
/// `u = r / sigma`, `ψ(u) = u (1 - u²/c²)²` inside the band and 0 outside.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct NewtonSums {
    /// Moments with weights `ψ'(u) / sigma²` (the Hessian).
    pub a: Moments,
    /// Moments with weights `ψ(u)² / sigma²` (the meat of the sandwich).
    pub b: Moments,
    /// `Σ ψ(u) / sigma [X; 1]` (the gradient).
    pub gradient: Vector4<f64>,
    pub inliers: usize,
    /// Sum of squared residuals of the inliers (m²).
    pub r2: f64,
}

/// [`NewtonSums`] over every point; points that are not finite or lie at
/// `z <= 0` get no weight. Without `sandwich`, `b` is left zero (a third less
/// work, for a pass whose covariance is not needed).
pub(crate) fn newton_sums(points: &[[f32; 3]], wt: &Weighting, sandwich: bool) -> NewtonSums {
    if sandwich { newton_kernel::<true>(points, wt) } else { newton_kernel::<false>(points, wt) }
}

/// Points per block: the block's weights and coordinates stay in L1.
const BLOCK: usize = 256;
/// Independent partial sums per quantity.
const LANES: usize = 4;

/// Per-point values of one block.
struct Block {
    x: [f64; BLOCK],
    y: [f64; BLOCK],
    z: [f64; BLOCK],
    /// `ψ'(u) / sigma²`, `ψ(u)² / sigma²`, `ψ(u) / sigma`.
    a: [f64; BLOCK],
    b: [f64; BLOCK],
    g: [f64; BLOCK],
    r2: [f64; BLOCK],
    inside: [f64; BLOCK],
}

#[inline(always)]
fn newton_kernel<const SANDWICH: bool>(points: &[[f32; 3]], wt: &Weighting) -> NewtonSums {
    let (n, dc, o) = (wt.n, wt.dc, wt.origin);
    let kappa2 = wt.kappa * wt.kappa;
    let band2 = wt.c * wt.c * kappa2;
    let inv_c2 = 1.0 / (wt.c * wt.c);
    let mut block = Block {
        x: [0.0; BLOCK],
        y: [0.0; BLOCK],
        z: [0.0; BLOCK],
        a: [0.0; BLOCK],
        b: [0.0; BLOCK],
        g: [0.0; BLOCK],
        r2: [0.0; BLOCK],
        inside: [0.0; BLOCK],
    };
    let zero2 = [[0.0; LANES]; 6];
    let zero1 = [[0.0; LANES]; 4];
    let (mut a2, mut a1, mut b2, mut b1) = (zero2, zero1, zero2, zero1);
    let mut g = [[0.0; LANES]; 6];
    for chunk in points.chunks(BLOCK) {
        for (i, p) in chunk.iter().enumerate() {
            let z = p[2] as f64;
            let (x, y, zc) = (p[0] as f64 - o.x, p[1] as f64 - o.y, z - o.z);
            let r = n.x * x + n.y * y + n.z * zc - dc;
            let (r2, z2) = (r * r, z * z);
            // False for NaN and infinite points as well as outliers.
            let inside = z > 0.0 && r2 < band2 * z2;
            // Zeros, not NaN or infinities, for every point outside.
            let inv_sigma2 = if inside { 1.0 / (kappa2 * z2) } else { 0.0 };
            let (x, y, zc, r, r2) = if inside { (x, y, zc, r, r2) } else { (0.0, 0.0, 0.0, 0.0, 0.0) };
            let u2 = r2 * inv_sigma2;
            let t = 1.0 - u2 * inv_c2;
            block.x[i] = x;
            block.y[i] = y;
            block.z[i] = zc;
            block.a[i] = t * (1.0 - 5.0 * u2 * inv_c2) * inv_sigma2;
            block.b[i] = u2 * (t * t) * (t * t) * inv_sigma2;
            block.g[i] = t * t * r * inv_sigma2;
            block.r2[i] = r2;
            block.inside[i] = if inside { 1.0 } else { 0.0 };
        }
        let m = chunk.len().next_multiple_of(LANES);
        for i in chunk.len()..m {
            (block.a[i], block.b[i], block.g[i], block.r2[i], block.inside[i]) = (0.0, 0.0, 0.0, 0.0, 0.0);
        }
        a2 = second_moments(a2, &block, &block.a, m);
        a1 = first_moments(a1, &block, &block.a, m);
        if SANDWICH {
            b2 = second_moments(b2, &block, &block.b, m);
            b1 = first_moments(b1, &block, &block.b, m);
        }
        g = gradient_sums(g, &block, m);
    }
    let g = g.map(|l| l.iter().sum::<f64>());
    NewtonSums {
        a: Moments::from_lanes(&a2, &a1),
        b: Moments::from_lanes(&b2, &b1),
        gradient: Vector4::new(g[0], g[1], g[2], g[3]),
        r2: g[4],
        inliers: g[5] as usize,
    }
}

/// Four lanes of partial sums; element-wise arithmetic that the compiler turns
/// into one vector instruction each.
#[derive(Debug, Default, Clone, Copy)]
struct F4([f64; LANES]);

impl F4 {
    #[inline(always)]
    fn load(v: &[f64; BLOCK], i: usize) -> Self {
        Self([v[i], v[i + 1], v[i + 2], v[i + 3]])
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Self([self.0[0] * o.0[0], self.0[1] * o.0[1], self.0[2] * o.0[2], self.0[3] * o.0[3]])
    }
    /// `self + a * b`.
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        Self([
            self.0[0] + a.0[0] * b.0[0],
            self.0[1] + a.0[1] * b.0[1],
            self.0[2] + a.0[2] * b.0[2],
            self.0[3] + a.0[3] * b.0[3],
        ])
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Self([self.0[0] + o.0[0], self.0[1] + o.0[1], self.0[2] + o.0[2], self.0[3] + o.0[3]])
    }
}

/// Adds `Σ w (xx, xy, xz, yy, yz, zz)` over the first `m` points of a block.
#[inline(always)]
fn second_moments(s: [[f64; LANES]; 6], block: &Block, w: &[f64; BLOCK], m: usize) -> [[f64; LANES]; 6] {
    let [mut xx, mut xy, mut xz, mut yy, mut yz, mut zz] = s.map(F4);
    for i in (0..m).step_by(LANES) {
        let (x, y, z, w) = (F4::load(&block.x, i), F4::load(&block.y, i), F4::load(&block.z, i), F4::load(w, i));
        let (wx, wy, wz) = (w.mul(x), w.mul(y), w.mul(z));
        xx = xx.mul_add(wx, x);
        xy = xy.mul_add(wx, y);
        xz = xz.mul_add(wx, z);
        yy = yy.mul_add(wy, y);
        yz = yz.mul_add(wy, z);
        zz = zz.mul_add(wz, z);
    }
    [xx.0, xy.0, xz.0, yy.0, yz.0, zz.0]
}

/// Adds `Σ w (x, y, z, 1)` over the first `m` points of a block.
#[inline(always)]
fn first_moments(s: [[f64; LANES]; 4], block: &Block, w: &[f64; BLOCK], m: usize) -> [[f64; LANES]; 4] {
    let [mut sx, mut sy, mut sz, mut s1] = s.map(F4);
    for i in (0..m).step_by(LANES) {
        let w = F4::load(w, i);
        sx = sx.mul_add(w, F4::load(&block.x, i));
        sy = sy.mul_add(w, F4::load(&block.y, i));
        sz = sz.mul_add(w, F4::load(&block.z, i));
        s1 = s1.add(w);
    }
    [sx.0, sy.0, sz.0, s1.0]
}

/// Adds `Σ g (x, y, z, 1)`, `Σ r²` and the inliers over the first `m` points.
#[inline(always)]
fn gradient_sums(s: [[f64; LANES]; 6], block: &Block, m: usize) -> [[f64; LANES]; 6] {
    let [mut gx, mut gy, mut gz, mut g1, mut r2, mut inside] = s.map(F4);
    for i in (0..m).step_by(LANES) {
        let g = F4::load(&block.g, i);
        gx = gx.mul_add(g, F4::load(&block.x, i));
        gy = gy.mul_add(g, F4::load(&block.y, i));
        gz = gz.mul_add(g, F4::load(&block.z, i));
        g1 = g1.add(g);
        r2 = r2.add(F4::load(&block.r2, i));
        inside = inside.add(F4::load(&block.inside, i));
    }
    [gx.0, gy.0, gz.0, g1.0, r2.0, inside.0]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition, point by point, without blocks, lanes or masks.
    fn reference(points: &[[f32; 3]], wt: &Weighting) -> NewtonSums {
        let mut sums = NewtonSums::default();
        let (kappa2, c2) = (wt.kappa * wt.kappa, wt.c * wt.c);
        for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite()) && p[2] > 0.0) {
            let x = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) - wt.origin;
            let r = wt.n.dot(&x) - wt.dc;
            let sigma2 = kappa2 * (p[2] as f64).powi(2);
            let u2 = r * r / sigma2;
            if u2 >= c2 {
                continue;
            }
            let t = 1.0 - u2 / c2;
            sums.a.add(t * (1.0 - 5.0 * u2 / c2) / sigma2, x.x, x.y, x.z);
            sums.b.add(u2 * t.powi(4) / sigma2, x.x, x.y, x.z);
            sums.gradient += Vector4::new(x.x, x.y, x.z, 1.0) * (t * t * r / sigma2);
            sums.inliers += 1;
            sums.r2 += r * r;
        }
        sums
    }

    fn close(a: &Matrix4<f64>, b: &Matrix4<f64>) -> bool {
        (a - b).norm() <= 1e-12 * b.norm()
    }

    #[test]
    fn the_vector_kernel_sums_what_the_definition_sums_on_both_code_paths() {
        let mut state = 99u64;
        let mut unit = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        // 1001 points: whole blocks, a partial block and a partial lane group.
        let points: Vec<[f32; 3]> = (0..1001)
            .map(|i| match i % 97 {
                0 => [f32::NAN, 0.0, 0.3],
                1 => [0.0, 0.0, -0.3],
                2 => [0.0, f32::INFINITY, 0.3],
                _ => [(unit() - 0.5) as f32 * 0.4, (unit() - 0.5) as f32 * 0.3, (0.3 + (unit() - 0.5) * 0.004) as f32],
            })
            .collect();
        let wt =
            Weighting { origin: Vector3::new(0.01, -0.02, 0.29), n: Vector3::z(), dc: 0.01, kappa: 0.3 * 3e-3, c: 2.5 };
        let expected = reference(&points, &wt);
        assert!(expected.inliers > 300 && expected.inliers < 990, "{}", expected.inliers);
        let generic = newton_kernel::<true>(&points, &wt);
        let dispatched = newton_sums(&points, &wt, true);
        for got in [generic, dispatched] {
            assert_eq!(got.inliers, expected.inliers);
            assert!(close(&got.a.matrix(), &expected.a.matrix()) && close(&got.b.matrix(), &expected.b.matrix()));
            assert!((got.gradient - expected.gradient).norm() <= 1e-12 * expected.gradient.norm());
            assert!((got.r2 - expected.r2).abs() <= 1e-12 * expected.r2);
        }
        // Both paths add in the same order without fused multiply-adds: same bits.
        assert_eq!(generic.a.matrix(), dispatched.a.matrix());
        assert_eq!(generic.gradient, dispatched.gradient);
        let without_b = newton_sums(&points, &wt, false);
        assert_eq!(without_b.a.matrix(), dispatched.a.matrix());
        assert_eq!(without_b.b.matrix(), Matrix4::zeros());
    }
}
