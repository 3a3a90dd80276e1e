//! The camera around the scene: the lens's distortion inverted on a grid, and
//! the sensor's blur, exposure, noise and gamma.

use super::UNDISTORT_GRID_PX;
use crate::rng::SimRng;
use crate::scene::Scene;
use nalgebra::Point2;

/// Normalised undistorted coordinates of pixel corners, exact on a coarse grid and
/// bilinear between (the distortion map is smooth: the error is ~1e-3 px).
pub(crate) struct UndistortGrid {
    cols: usize,
    rows: usize,
    xy: Vec<[f64; 2]>,
}

impl UndistortGrid {
    pub(crate) fn new(camera: &outlet_protocol::CameraModel) -> Self {
        let g = UNDISTORT_GRID_PX;
        let cols = (camera.width as usize).div_ceil(g) + 2;
        let rows = (camera.height as usize).div_ceil(g) + 2;
        let mut xy = Vec::with_capacity(cols * rows);
        for j in 0..rows {
            for i in 0..cols {
                let n = camera.undistort_pixel(Point2::new((i * g) as f64 - 0.5, (j * g) as f64 - 0.5));
                xy.push([n.x, n.y]);
            }
        }
        Self { cols, rows, xy }
    }

    /// At the pixel coordinates `(u, v)` (with u = -0.5 the left image edge).
    #[inline]
    pub(crate) fn at(&self, u: f64, v: f64) -> [f64; 2] {
        let (j, tv) = self.cell(v, self.rows);
        let (i, tu) = self.cell(u, self.cols);
        let a = self.xy[j * self.cols + i];
        let b = self.xy[j * self.cols + i + 1];
        let c = self.xy[(j + 1) * self.cols + i];
        let d = self.xy[(j + 1) * self.cols + i + 1];
        let mut out = [0.0; 2];
        for k in 0..2 {
            out[k] = (a[k] * (1.0 - tu) + b[k] * tu) * (1.0 - tv) + (c[k] * (1.0 - tu) + d[k] * tu) * tv;
        }
        out
    }

    #[inline]
    fn cell(&self, x: f64, n: usize) -> (usize, f64) {
        let g = ((x + 0.5) / UNDISTORT_GRID_PX as f64).max(0.0);
        let i = (g as usize).min(n - 2);
        (i, g - i as f64)
    }

    /// Every value along the row `v`, at `u = u0 + k` for k in 0..n.
    pub(crate) fn row(&self, v: f64, u0: f64, n: usize) -> Vec<[f64; 2]> {
        let (j, tv) = self.cell(v, self.rows);
        let coarse: Vec<[f64; 2]> = (0..self.cols)
            .map(|i| {
                let (a, c) = (self.xy[j * self.cols + i], self.xy[(j + 1) * self.cols + i]);
                [a[0] + (c[0] - a[0]) * tv, a[1] + (c[1] - a[1]) * tv]
            })
            .collect();
        (0..n)
            .map(|k| {
                let (i, tu) = self.cell(u0 + k as f64, self.cols);
                let (a, b) = (coarse[i], coarse[i + 1]);
                [a[0] + (b[0] - a[0]) * tu, a[1] + (b[1] - a[1]) * tu]
            })
            .collect()
    }
}

/// Separable Gaussian blur of interleaved RGB, in place (edges clamped). The
/// loops run over whole padded rows so that they vectorise.
pub(super) fn blur(buf: &mut [f32], w: usize, h: usize, sigma: f32) {
    let radius = (3.0 * sigma).ceil() as usize;
    let mut kernel: Vec<f32> = (0..=2 * radius)
        .map(|i| {
            let d = i as f32 - radius as f32;
            (-(d * d) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let total: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= total);
    let stride = w * 3;
    let mut padded = vec![0.0f32; (w + 2 * radius) * 3];
    for y in 0..h {
        let row = &mut buf[y * stride..(y + 1) * stride];
        for k in 0..radius {
            padded[k * 3..k * 3 + 3].copy_from_slice(&row[..3]);
            let tail = (radius + w + k) * 3;
            padded[tail..tail + 3].copy_from_slice(&row[stride - 3..]);
        }
        padded[radius * 3..(radius + w) * 3].copy_from_slice(row);
        row.iter_mut().for_each(|v| *v = 0.0);
        for (j, &kj) in kernel.iter().enumerate() {
            for (o, &i) in row.iter_mut().zip(&padded[j * 3..j * 3 + stride]) {
                *o += kj * i;
            }
        }
    }
    let source = buf.to_vec();
    for y in 0..h {
        let row = &mut buf[y * stride..(y + 1) * stride];
        row.iter_mut().for_each(|v| *v = 0.0);
        for (j, &kj) in kernel.iter().enumerate() {
            let sy = (y + j).saturating_sub(radius).min(h - 1);
            for (o, &i) in row.iter_mut().zip(&source[sy * stride..(sy + 1) * stride]) {
                *o += kj * i;
            }
        }
    }
}

/// Exposure, sensor noise, clipping and gamma: radiance to 8-bit pixels.
pub(super) fn expose(radiance: &[f32], scene: &Scene) -> Vec<u8> {
    const LUT_SIZE: usize = 4096;
    let sensor = &scene.sensor;
    let lut: Vec<u8> = (0..LUT_SIZE)
        .map(|i| ((i as f32 / (LUT_SIZE - 1) as f32).powf(1.0 / sensor.gamma) * 255.0 + 0.5) as u8)
        .collect();
    let mut rng = SimRng::new(scene.noise_seed);
    let sqrt3 = 3.0f32.sqrt();
    // Noise per channel; its sigma from the pixel's mean level (one square root
    // per pixel, not per channel).
    let mut out = Vec::with_capacity(radiance.len());
    for px in radiance.chunks_exact(3) {
        let v = [px[0] * sensor.exposure, px[1] * sensor.exposure, px[2] * sensor.exposure];
        let level = ((v[0] + v[1] + v[2]) * (1.0 / 3.0)).max(0.0);
        let sigma = (sensor.read_noise * sensor.read_noise + sensor.shot_noise * level).sqrt();
        for c in v {
            // Sum of four 16-bit uniforms: close to a Gaussian and four times cheaper.
            let bits = rng.next_u64();
            let sum = (bits & 0xFFFF) + ((bits >> 16) & 0xFFFF) + ((bits >> 32) & 0xFFFF) + (bits >> 48);
            let gauss = (sum as f32 / 65536.0 - 2.0) * sqrt3;
            let v = (c + sigma * gauss).clamp(0.0, 1.0);
            out.push(lut[(v * (LUT_SIZE - 1) as f32) as usize]);
        }
    }
    out
}
