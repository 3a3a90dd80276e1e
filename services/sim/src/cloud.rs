//! The stereo point cloud of the scene as a stereo camera sees it: depth noise
//! growing with distance squared, outliers, blobs without stereo (NaN), and the
//! plate and faces standing proud of the wall. A realistic model
//! ([`crate::scene::StereoModel::realistic`]) adds what real pairs do: sparse
//! points, noise proportional to range, few points on the plate, none over the
//! outlet, and a calibration bias.

use crate::render::{Prepared, Ray, UndistortGrid};
use crate::rng::SimRng;
use crate::scene::{Insert, Scene};
use crate::shapes::{Opening, box_sd, face_sd};
use nalgebra::Point3;

impl Prepared<'_> {
    /// Depth (outlet z, mm) of the first surface along a ray; `None` inside an
    /// opening, where stereo finds no texture to match.
    pub(crate) fn depth(&self, scene: &Scene, ray: &Ray) -> Option<f64> {
        for plate in &scene.plates {
            let c = plate.centre;
            let local = |z: f64| {
                let p = ray.at(z);
                [p[0] - c[0], p[1] - c[1]]
            };
            let zt = plate.top_z(scene.wall_z_mm);
            if let Insert::Receptacles(faces) = &plate.insert {
                let (q0, qt) = (local(0.0), local(zt));
                for face in faces {
                    let (x0, y0) = (q0[0] - face.centre[0], q0[1] - face.centre[1]);
                    if face_sd(x0, y0, &face.shape) < 0.0 {
                        if Opening::ALL.iter().any(|o| o.sd(x0, y0, face.shape.t_slot) < 0.0) {
                            return None;
                        }
                        return Some(0.0);
                    }
                    if face_sd(qt[0] - face.centre[0], qt[1] - face.centre[1], &face.shape) < 0.0 {
                        return Some(zt * 0.5);
                    }
                }
            }
            let (thx, thy) = (plate.size[0] / 2.0 - plate.bevel, plate.size[1] / 2.0 - plate.bevel);
            let q = local(zt);
            if q[0].abs() <= thx && q[1].abs() <= thy {
                return Some(zt);
            }
            let qw = local(scene.wall_z_mm);
            if qw[0].abs() <= plate.size[0] / 2.0 && qw[1].abs() <= plate.size[1] / 2.0 {
                // On the bevel: height falls linearly from the top's edge to the wall.
                let (mut lo, mut hi) = (zt, scene.wall_z_mm);
                for _ in 0..8 {
                    let mid = 0.5 * (lo + hi);
                    let p = local(mid);
                    let out = box_sd(p[0], p[1], thx, thy).max(0.0);
                    let surface = zt + plate.proud * (out / plate.bevel.max(0.1)).min(1.0);
                    if mid < surface { lo = mid } else { hi = mid }
                }
                return Some(0.5 * (lo + hi));
            }
        }
        Some(scene.wall_z_mm)
    }
}

/// The cloud in the camera frame (metres), one point per `step` pixels, row-major;
/// points without stereo are NaN.
pub fn stereo_cloud(scene: &Scene) -> Vec<[f32; 3]> {
    let prepared = Prepared::new(scene);
    let grid = UndistortGrid::new(&scene.camera);
    stereo_cloud_with(scene, &prepared, &grid)
}

pub(crate) fn stereo_cloud_with(scene: &Scene, prepared: &Prepared, grid: &UndistortGrid) -> Vec<[f32; 3]> {
    let model = &scene.stereo;
    let step = model.step.max(1) as usize;
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let mut rng = SimRng::new(scene.noise_seed ^ 0xC10D);
    // Blobs where the matcher fails: random ellipses covering about the fraction asked.
    let mut blobs = Vec::new();
    let mut covered = 0.0;
    let area = (w * h) as f64;
    while covered < model.dropout_fraction * area && blobs.len() < 64 {
        let (a, b) = (rng.range(0.02, 0.12) * w as f64, rng.range(0.02, 0.12) * h as f64);
        blobs.push((rng.range(0.0, w as f64), rng.range(0.0, h as f64), a, b));
        covered += std::f64::consts::PI * a * b;
    }
    // Draws of the realistic model come from a stream of their own, so that the
    // default model's cloud stays the same to the byte.
    let mut real = SimRng::new(scene.noise_seed ^ 0x5EED_C10D);
    let focal = scene.camera.fx;
    let noise_scale = model.disparity_sigma_px / (focal * model.baseline_m);
    let mut points = Vec::with_capacity(w.div_ceil(step) * h.div_ceil(step));
    for y in (step / 2..h).step_by(step) {
        for x in (step / 2..w).step_by(step) {
            let nan = [f32::NAN; 3];
            let in_blob = blobs.iter().any(|&(bx, by, a, b)| {
                let (dx, dy) = ((x as f64 - bx) / a, (y as f64 - by) / b);
                dx * dx + dy * dy < 1.0
            });
            let dropout = rng.chance(0.01);
            let outlier = rng.unit();
            let noise = rng.normal();
            let n = grid.at(x as f64, y as f64);
            let Some(ray) = prepared.ray(n[0], n[1]) else {
                points.push(nan);
                continue;
            };
            if in_blob || dropout {
                points.push(nan);
                continue;
            }
            let Some(z_mm) = prepared.depth(scene, &ray) else {
                points.push(nan);
                continue;
            };
            let p = ray.at(z_mm);
            let raised = z_mm < scene.wall_z_mm - 0.5;
            if (raised && model.raised_keep < 1.0 && real.unit() > model.raised_keep)
                || model.outlet_dropout_mm.is_some_and(|r| p[0].hypot(p[1]) < r)
            {
                points.push(nan);
                continue;
            }
            let cam = scene.pose * Point3::new(p[0] / 1000.0, p[1] / 1000.0, z_mm / 1000.0);
            let z = cam.z;
            let mut scale = if outlier < model.outlier_fraction {
                0.5 + outlier / model.outlier_fraction
            } else {
                1.0 + noise * noise_scale * z
            };
            if model.range_sigma_fraction > 0.0 {
                scale *= 1.0 + model.range_sigma_fraction * real.normal();
            }
            let q = model.bias * Point3::from(cam.coords * scale);
            points.push([q.x as f32, q.y as f32, q.z as f32]);
        }
    }
    if let Some(keep) = model.max_points {
        thin_out(&mut points, keep, &mut real);
    }
    points
}

/// Keeps `keep` of the valid points, each subset equally likely (selection
/// sampling), and makes the others NaN.
fn thin_out(points: &mut [[f32; 3]], keep: usize, rng: &mut SimRng) {
    let valid = points.iter().filter(|p| p[0].is_finite()).count();
    let (mut seen, mut kept) = (0usize, 0usize);
    for p in points.iter_mut().filter(|p| p[0].is_finite()) {
        let wanted = keep.saturating_sub(kept) as f64;
        if rng.unit() * ((valid - seen) as f64) < wanted {
            kept += 1;
        } else {
            *p = [f32::NAN; 3];
        }
        seen += 1;
    }
}
