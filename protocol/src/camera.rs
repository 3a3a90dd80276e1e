//! Pinhole camera with ROS's `plumb_bob` distortion (OpenCV's five-coefficient model).

use nalgebra::{Point2, Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Why a camera model was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    #[error("camera size {width}x{height} is empty")]
    EmptyImage { width: u32, height: u32 },
    #[error("camera focal length fx={fx}, fy={fy} must be between 1 and 1e7 pixels")]
    BadFocalLength { fx: f64, fy: f64 },
    #[error("camera principal point ({cx}, {cy}) must be finite and within ten image sizes of the image")]
    BadPrincipalPoint { cx: f64, cy: f64 },
    #[error("distortion coefficient {index} ({value}) must be finite and within ±10000")]
    BadDistortion { index: usize, value: f64 },
}

/// Intrinsics and plumb_bob distortion `[k1, k2, p1, p2, k3]` of one camera.
///
/// Pixels are in the image as captured (distorted), OpenCV convention.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// plumb_bob: `[k1, k2, p1, p2, k3]`.
    pub distortion: [f64; 5],
}

impl CameraModel {
    /// A checked camera: non-empty size, positive focal lengths, finite values.
    pub fn new(width: u32, height: u32, [fx, fy, cx, cy]: [f64; 4], distortion: [f64; 5]) -> Result<Self, CameraError> {
        if width == 0 || height == 0 {
            return Err(CameraError::EmptyImage { width, height });
        }
        // A focal length under one pixel is a field of view past 180 degrees, and
        // one of 1e-37 (a fuzzed CameraInfo) makes every ray infinite.
        let focal_ok = |f: f64| (1.0..=1e7).contains(&f);
        if !(focal_ok(fx) && focal_ok(fy)) {
            return Err(CameraError::BadFocalLength { fx, fy });
        }
        let near = |c: f64, size: u32| (-10.0 * size as f64..=11.0 * size as f64).contains(&c);
        if !(near(cx, width) && near(cy, height)) {
            return Err(CameraError::BadPrincipalPoint { cx, cy });
        }
        // Calibrated lenses stay far inside ±1e4; 1e306 (a fuzzed CameraInfo) overflows every ray.
        if let Some((index, &value)) = distortion.iter().enumerate().find(|(_, v)| !(-1e4..=1e4).contains(*v)) {
            return Err(CameraError::BadDistortion { index, value });
        }
        Ok(Self { width, height, fx, fy, cx, cy, distortion })
    }

    /// The simulated camera's default: 640x480, f = 525 px, mild barrel distortion.
    pub fn default_vga() -> Self {
        Self {
            width: 640,
            height: 480,
            fx: 525.0,
            fy: 525.0,
            cx: 319.5,
            cy: 239.5,
            distortion: [-0.06, 0.03, 0.0, 0.0, 0.0],
        }
    }

    /// True when every distortion coefficient is zero.
    pub fn is_rectified(&self) -> bool {
        self.distortion.iter().all(|&k| k == 0.0)
    }

    /// Applies plumb_bob to normalised undistorted coordinates `(x/z, y/z)`.
    pub fn distort_normalized(&self, p: Vector2<f64>) -> Vector2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        Vector2::new(
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Normalised undistorted coordinates of a distorted pixel, by Newton
    /// iterations on the distortion map (exact to ~1e-12 inside the image).
    pub fn undistort_pixel(&self, pixel: Point2<f64>) -> Vector2<f64> {
        let target = Vector2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        if self.is_rectified() {
            return target;
        }
        let mut p = target;
        for _ in 0..20 {
            let f = self.distort_normalized(p) - target;
            if f.norm_squared() < 1e-26 {
                break;
            }
            let j = self.distortion_jacobian(p);
            match j.try_inverse() {
                Some(inv) => p -= inv * f,
                None => break,
            }
        }
        p
    }

    /// d(distorted)/d(undistorted) of the normalised coordinates.
    pub fn distortion_jacobian(&self, p: Vector2<f64>) -> nalgebra::Matrix2<f64> {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2); // d radial / d r2
        nalgebra::Matrix2::new(
            radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x,
            2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
            2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x,
        )
    }

    /// Pixel (distorted, as captured) of a camera-frame point; `None` behind the camera.
    pub fn project(&self, point_cam: &Point3<f64>) -> Option<Point2<f64>> {
        if point_cam.z.is_nan() || point_cam.z <= 0.0 {
            return None;
        }
        let d = self.distort_normalized(Vector2::new(point_cam.x / point_cam.z, point_cam.y / point_cam.z));
        Some(Point2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy))
    }

    /// The camera-frame ray `(x, y, 1)` through a distorted pixel (z = 1, not unit).
    pub fn ray(&self, pixel: Point2<f64>) -> Vector3<f64> {
        let n = self.undistort_pixel(pixel);
        Vector3::new(n.x, n.y, 1.0)
    }

    /// True when a pixel lies inside the image with a margin in pixels.
    pub fn contains(&self, pixel: Point2<f64>, margin: f64) -> bool {
        pixel.x >= margin - 0.5
            && pixel.y >= margin - 0.5
            && pixel.x <= self.width as f64 - 0.5 - margin
            && pixel.y <= self.height as f64 - 0.5 - margin
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intrinsics_no_camera_could_have_are_refused_naming_them() {
        let ok = CameraModel::new(640, 480, [525.0, 525.0, 319.5, 239.5], [0.0; 5]);
        assert!(ok.is_ok());
        for (f, c) in [(4e-37, 319.5), (0.5, 319.5), (2e7, 319.5), (f64::NAN, 319.5), (525.0, 1e9), (525.0, -7000.0)] {
            let err = CameraModel::new(640, 480, [f, 525.0, c, 239.5], [0.0; 5]).expect_err("refused");
            let named = if f == 525.0 { "principal point" } else { "focal length" };
            assert!(err.to_string().contains(named), "fx {f}, cx {c}: {err}");
        }
        for k in [-3.6e306, 1.1e4, f64::INFINITY, f64::NAN] {
            let err = CameraModel::new(640, 480, [525.0, 525.0, 319.5, 239.5], [0.01, k, 0.0, 0.0, 0.0])
                .expect_err("refused");
            assert!(err.to_string().contains("distortion coefficient 1"), "k2 {k}: {err}");
        }
    }

    #[test]
    fn undistort_inverts_distort_across_the_image() {
        let cam = CameraModel { distortion: [-0.3966, 0.21, -0.0028, -0.0051, 0.0], ..CameraModel::default_vga() };
        for &(u, v) in &[(0.0, 0.0), (639.0, 479.0), (320.0, 10.0), (100.0, 400.0), (319.5, 239.5)] {
            let ray = cam.ray(Point2::new(u, v));
            let back = cam.project(&Point3::from(ray * 0.4)).expect("in front");
            assert!((back.x - u).abs() < 1e-9 && (back.y - v).abs() < 1e-9, "({u},{v}) -> {back}");
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let cam = CameraModel { distortion: [-0.2, 0.1, 0.003, -0.002, 0.01], ..CameraModel::default_vga() };
        let p = Vector2::new(0.31, -0.22);
        let j = cam.distortion_jacobian(p);
        let h = 1e-7;
        for c in 0..2 {
            let mut dp = Vector2::zeros();
            dp[c] = h;
            let fd = (cam.distort_normalized(p + dp) - cam.distort_normalized(p - dp)) / (2.0 * h);
            assert!((fd - j.column(c)).norm() < 1e-6);
        }
    }

    #[test]
    fn rejects_bad_intrinsics() {
        assert!(matches!(
            CameraModel::new(0, 480, [525.0, 525.0, 320.0, 240.0], [0.0; 5]),
            Err(CameraError::EmptyImage { .. })
        ));
        assert!(CameraModel::new(640, 480, [f64::NAN, 525.0, 320.0, 240.0], [0.0; 5]).is_err());
        assert!(CameraModel::new(640, 480, [525.0, 525.0, 320.0, 240.0], [0.0, f64::INFINITY, 0.0, 0.0, 0.0]).is_err());
        assert!(CameraModel::new(640, 480, [525.0, 525.0, 320.0, 240.0], [0.0; 5]).is_ok());
    }

    #[test]
    fn points_behind_the_camera_do_not_project() {
        assert!(CameraModel::default_vga().project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }
}
