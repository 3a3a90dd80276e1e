//! The renderer: every pixel's ray is cast onto the planes of the wall, the plates
//! and the receptacle faces (exact perspective, distortion included), shaded with a
//! point light, then blurred, exposed, given sensor noise and gamma.
//!
//! Anti-aliasing is adaptive: a pixel is shaded once where its four corners and its
//! centre see the same surface and no thin feature (crack, screw slot, spot) is
//! near, else with 3x3 samples. That keeps a 640x480 frame in a few milliseconds.
//!
//! Here the frame's loop over pixels; in `surfaces`, what a ray hits and how it
//! is shaded; in `sensor`, the lens's distortion grid and the sensor's blur and
//! exposure.

mod sensor;
mod surfaces;

pub(crate) use sensor::UndistortGrid;
use sensor::{blur, expose};
pub(crate) use surfaces::Prepared;
use surfaces::{Hit, Lit, scale};

use crate::scene::Scene;
use image::RgbImage;

/// Spacing of the coarse grid on which distortion is inverted exactly (pixels).
const UNDISTORT_GRID_PX: usize = 4;
/// Supersamples per side where a pixel straddles an edge.
const SUPERSAMPLE: usize = 3;

/// A rendered camera frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The picture as a camera delivers it (after JPEG if the sensor compresses).
    pub image: RgbImage,
    /// The JPEG bytes when the sensor compresses: what `outlet render` writes.
    pub jpeg: Option<Vec<u8>>,
}

/// A ray through the outlet frame: its point on the face plane z = 0 and its
/// lateral shift per mm of depth, so that the point at depth z is `p0 + z * slope`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ray {
    p0: [f64; 2],
    slope: [f64; 2],
}

impl Ray {
    #[inline]
    pub(crate) fn at(&self, z: f64) -> [f64; 2] {
        [self.p0[0] + z * self.slope[0], self.p0[1] + z * self.slope[1]]
    }
}

struct PixelLight {
    dir: [f32; 3],
    irradiance: f32,
    diffuse_flat: f32,
    /// Cosine between the surface normal and the half vector (Blinn-Phong).
    nh: f32,
    occlusion: f32,
}

/// Pixel columns between exact light evaluations along a row: light varies slowly
/// across the wall, so it is interpolated between them.
const LIGHT_STEP_PX: usize = 4;

impl PixelLight {
    fn lerp(a: &PixelLight, b: &PixelLight, t: f32) -> PixelLight {
        let m = |x: f32, y: f32| x + (y - x) * t;
        PixelLight {
            dir: [m(a.dir[0], b.dir[0]), m(a.dir[1], b.dir[1]), m(a.dir[2], b.dir[2])],
            irradiance: m(a.irradiance, b.irradiance),
            diffuse_flat: m(a.diffuse_flat, b.diffuse_flat),
            nh: m(a.nh, b.nh),
            occlusion: m(a.occlusion, b.occlusion),
        }
    }
}

/// Linear radiance of every pixel, RGB interleaved, before the sensor.
pub(crate) fn render_radiance(scene: &Scene, prepared: &Prepared, grid: &UndistortGrid) -> Vec<f32> {
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let mut out = vec![0.0f32; w * h * 3];
    let background = Hit { id: u32::MAX, albedo: [0.05; 3], lit: Lit::Inside, gloss: 0.0, shininess: 1.0 };
    let ray_at = |u: f64, v: f64| {
        let n = grid.at(u, v);
        prepared.ray(n[0], n[1])
    };
    let corner_row = |v: f64| -> Vec<(Option<Ray>, Hit)> {
        grid.row(v, -0.5, w + 1)
            .into_iter()
            .map(|n| {
                let r = prepared.ray(n[0], n[1]);
                (r, r.as_ref().map_or(background, |r| prepared.hit(r)))
            })
            .collect()
    };
    let mut top = corner_row(-0.5);
    let mut thin_row = vec![false; w];
    let mut lights: Vec<Option<PixelLight>> = Vec::new();
    for y in 0..h {
        let bottom = corner_row(y as f64 + 0.5);
        thin_row.iter_mut().for_each(|t| *t = false);
        for b in &prepared.thin_boxes {
            if (y as f64) < b[1] || (y as f64) > b[3] {
                continue;
            }
            let (x0, x1) = (b[0].max(0.0) as usize, (b[2].max(0.0) as usize).min(w.saturating_sub(1)));
            for t in thin_row.iter_mut().take(x1 + 1).skip(x0) {
                *t = true;
            }
        }
        lights.clear();
        lights.extend(
            (0..w.div_ceil(LIGHT_STEP_PX) + 1)
                .map(|k| ray_at((k * LIGHT_STEP_PX) as f64, y as f64).map(|r| prepared.pixel_light(&r))),
        );
        for x in 0..w {
            let corners = [&top[x], &top[x + 1], &bottom[x], &bottom[x + 1]];
            let (k, t) = (x / LIGHT_STEP_PX, (x % LIGHT_STEP_PX) as f32 / LIGHT_STEP_PX as f32);
            let centre = match (corners[0].0, corners[1].0, corners[2].0, corners[3].0) {
                (Some(a), Some(b), Some(c), Some(d)) => Some(Ray {
                    p0: [(a.p0[0] + b.p0[0] + c.p0[0] + d.p0[0]) / 4.0, (a.p0[1] + b.p0[1] + c.p0[1] + d.p0[1]) / 4.0],
                    slope: [
                        (a.slope[0] + b.slope[0] + c.slope[0] + d.slope[0]) / 4.0,
                        (a.slope[1] + b.slope[1] + c.slope[1] + d.slope[1]) / 4.0,
                    ],
                }),
                _ => ray_at(x as f64, y as f64),
            };
            let (Some(centre), Some(l0), Some(l1)) = (centre, &lights[k], &lights[k + 1]) else {
                out[(y * w + x) * 3..][..3].copy_from_slice(&background.albedo);
                continue;
            };
            let light = PixelLight::lerp(l0, l1, t);
            let id = corners[0].1.id;
            let uniform = !thin_row[x] && corners.iter().all(|c| c.1.id == id);
            let (mut wall_shadow, mut plate_shadow) = (None, None);
            let px = if uniform {
                // One shading with the corners' mean reflectance.
                let mut hit = corners[0].1;
                for c in &corners[1..] {
                    for (a, b) in hit.albedo.iter_mut().zip(c.1.albedo) {
                        *a += b;
                    }
                }
                hit.albedo = scale(hit.albedo, 0.25);
                prepared.shade(&hit, &light, &centre, &mut wall_shadow, &mut plate_shadow)
            } else {
                let mut sum = [0.0f32; 3];
                let n = SUPERSAMPLE as f64;
                for sj in 0..SUPERSAMPLE {
                    for si in 0..SUPERSAMPLE {
                        let u = x as f64 - 0.5 + (si as f64 + 0.5) / n;
                        let v = y as f64 - 0.5 + (sj as f64 + 0.5) / n;
                        let c = match ray_at(u, v) {
                            Some(ray) => {
                                let hit = prepared.hit(&ray);
                                prepared.shade(&hit, &light, &ray, &mut wall_shadow, &mut plate_shadow)
                            }
                            None => background.albedo,
                        };
                        sum = [sum[0] + c[0], sum[1] + c[1], sum[2] + c[2]];
                    }
                }
                scale(sum, 1.0 / (SUPERSAMPLE * SUPERSAMPLE) as f32)
            };
            out[(y * w + x) * 3..][..3].copy_from_slice(&px);
        }
        top = bottom;
    }
    out
}

/// Renders the camera image of a scene.
pub fn render(scene: &Scene) -> Frame {
    let prepared = Prepared::new(scene);
    let grid = UndistortGrid::new(&scene.camera);
    render_with(scene, &prepared, &grid)
}

pub(crate) fn render_with(scene: &Scene, prepared: &Prepared, grid: &UndistortGrid) -> Frame {
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let mut radiance = render_radiance(scene, prepared, grid);
    if scene.sensor.blur_sigma >= 0.3 {
        blur(&mut radiance, w, h, scene.sensor.blur_sigma);
    }
    let bytes = expose(&radiance, scene);
    let image = RgbImage::from_raw(scene.camera.width, scene.camera.height, bytes)
        .unwrap_or_else(|| RgbImage::new(scene.camera.width, scene.camera.height));
    match scene.sensor.jpeg_quality {
        Some(q) => {
            let mut jpeg = Vec::new();
            let encoded = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, q).encode_image(&image);
            let decoded = encoded
                .ok()
                .and_then(|_| image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg).ok())
                .map(|d| d.to_rgb8());
            match decoded {
                Some(decoded) => Frame { image: decoded, jpeg: Some(jpeg) },
                None => Frame { image, jpeg: None },
            }
        }
        None => Frame { image, jpeg: None },
    }
}

/// Milliseconds spent in each stage of one frame: undistortion grid, ray casting,
/// blur, exposure, JPEG. For profiling; `render` is what to call.
pub fn phase_times(scene: &Scene) -> [(&'static str, f64); 5] {
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let t = std::time::Instant::now();
    let prepared = Prepared::new(scene);
    let grid = UndistortGrid::new(&scene.camera);
    let t_grid = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    let mut radiance = render_radiance(scene, &prepared, &grid);
    let t_cast = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    blur(&mut radiance, w, h, scene.sensor.blur_sigma.max(0.8));
    let t_blur = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    let bytes = expose(&radiance, scene);
    let t_expose = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    let image = RgbImage::from_raw(scene.camera.width, scene.camera.height, bytes).unwrap_or_default();
    let mut jpeg = Vec::new();
    let _ = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 80).encode_image(&image);
    let _ = image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg);
    let t_jpeg = t.elapsed().as_secs_f64() * 1e3;
    [("grid", t_grid), ("cast", t_cast), ("blur", t_blur), ("expose", t_expose), ("jpeg", t_jpeg)]
}
