//! Training samples: the affine poses that simulate viewpoint changes, and one
//! feature's intensity-normalised sample through a pose.

use super::{DescriptorParams, Normalisation, TrainingFeature};
use image::GrayImage;
use nalgebra::{Matrix2, Vector2};
use rand_xoshiro::SplitMix64;
use rand_xoshiro::rand_core::{Rng as _, SeedableRng};

/// Deterministic generator for poses and perturbations: SplitMix64
/// (`rand_xoshiro`'s). A template's training samples follow from its seed, so
/// the stream is pinned by `the_stream_of_a_seed_never_changes`.
pub(super) struct Rng(SplitMix64);

impl Rng {
    pub(super) fn new(seed: u64) -> Self {
        Self(SplitMix64::seed_from_u64(seed))
    }

    pub(super) fn next(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in [a, b).
    pub(super) fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// An affine pose R(phi) diag(l1, l2) R(theta - phi), angles in radians.
#[derive(Debug, Clone, Copy)]
pub(super) struct Pose {
    theta: f64,
    phi: f64,
    l1: f64,
    l2: f64,
}

pub(super) fn rotation(a: f64) -> Matrix2<f64> {
    let (s, c) = a.sin_cos();
    Matrix2::new(c, -s, s, c)
}

impl Pose {
    /// The inverse pose: from the simulated view's patch to the training patch.
    pub(super) fn inverse(&self) -> Matrix2<f64> {
        rotation(self.phi - self.theta) * Matrix2::new(1.0 / self.l1, 0.0, 0.0, 1.0 / self.l2) * rotation(-self.phi)
    }
}

/// The poses shared by every feature: the identity first.
pub(super) fn draw_poses(params: &DescriptorParams) -> Vec<Pose> {
    let mut rng = Rng::new(params.seed);
    let max_theta = params.max_rotation_deg.to_radians();
    let mut poses: Vec<Pose> = (0..params.poses_per_feature)
        .map(|i| {
            if i == 0 {
                return Pose { theta: 0.0, phi: 0.0, l1: 1.0, l2: 1.0 };
            }
            Pose {
                theta: rng.range(-max_theta, max_theta),
                phi: rng.range(0.0, std::f64::consts::TAU),
                l1: rng.range(params.stretch[0], params.stretch[1]),
                l2: rng.range(params.stretch[0], params.stretch[1]),
            }
        })
        .collect();
    if params.half_turn {
        let turned: Vec<Pose> = poses.iter().map(|p| Pose { theta: p.theta + std::f64::consts::PI, ..*p }).collect();
        poses.extend(turned);
    }
    poses
}

/// Bilinear grey value at (u, v), coordinates clamped to the (non-empty) image.
#[inline]
pub(super) fn bilinear(grey: &GrayImage, u: f64, v: f64) -> f32 {
    let (w, h) = grey.dimensions();
    let u = if u.is_finite() { u.clamp(0.0, (w - 1) as f64) } else { 0.0 };
    let v = if v.is_finite() { v.clamp(0.0, (h - 1) as f64) } else { 0.0 };
    let (x0, y0) = (u as u32, v as u32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (tx, ty) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
    let raw = grey.as_raw();
    let at = |x: u32, y: u32| raw[(y * w + x) as usize] as f32;
    let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * tx;
    let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * tx;
    top + (bottom - top) * ty
}

/// Normalises a sample in place; a flat sample becomes all zeros.
pub(super) fn normalise(sample: &mut [f32], how: Normalisation) {
    let mean = sample.iter().sum::<f32>() / sample.len() as f32;
    match how {
        Normalisation::ZeroMeanUnitNorm => {
            sample.iter_mut().for_each(|x| *x -= mean);
            let norm = sample.iter().map(|x| x * x).sum::<f32>().sqrt();
            let k = if norm > 1e-3 { 1.0 / norm } else { 0.0 };
            sample.iter_mut().for_each(|x| *x *= k);
        }
        Normalisation::UnitMean => {
            let k = if mean > 1e-3 { 1.0 / mean } else { 0.0 };
            sample.iter_mut().for_each(|x| *x = if k > 0.0 { *x * k - 1.0 } else { 0.0 });
        }
    }
}

/// Offsets of the crop's pixel centres from the patch centre (patch pixels).
pub(super) fn crop_offsets(crop: usize) -> impl Iterator<Item = f64> + Clone {
    let half = (crop as f64 - 1.0) / 2.0;
    (0..crop).map(move |i| i as f64 - half)
}

/// The sample of one pose of a feature: the mean of `noisy_copies` perturbed warps
/// (the first one unperturbed), normalised.
pub(super) fn pose_sample(
    grey: &GrayImage,
    feature: &TrainingFeature,
    pose: &Pose,
    params: &DescriptorParams,
    rng: &mut Rng,
    out: &mut [f32],
) {
    out.iter_mut().for_each(|x| *x = 0.0);
    let (dr, ds, dp) = (params.noise_rotation_deg.to_radians(), params.noise_stretch, params.noise_shift_px);
    for copy in 0..params.noisy_copies {
        let (perturbed, shift) = if copy == 0 {
            (*pose, Vector2::zeros())
        } else {
            let p = Pose {
                theta: pose.theta + rng.range(-dr, dr),
                phi: pose.phi + rng.range(-dr, dr),
                l1: pose.l1 * (1.0 + rng.range(-ds, ds)),
                l2: pose.l2 * (1.0 + rng.range(-ds, ds)),
            };
            (p, Vector2::new(rng.range(-dp, dp), rng.range(-dp, dp)))
        };
        let to_image = feature.view * perturbed.inverse() * feature.scale;
        let offsets = crop_offsets(params.crop_size);
        let mut k = 0;
        for y in offsets.clone() {
            for x in offsets.clone() {
                let p = feature.centre + to_image * (Vector2::new(x, y) + shift);
                out[k] += bilinear(grey, p.x, p.y);
                k += 1;
            }
        }
    }
    normalise(out, params.normalisation);
}

#[cfg(test)]
mod rng_tests {
    use super::Rng;

    #[test]
    fn the_stream_of_a_seed_never_changes() {
        // The first outputs of the hand-written SplitMix64 this replaced.
        let first = |seed| {
            let mut r = Rng::new(seed);
            [r.next(), r.next(), r.next()]
        };
        assert_eq!(first(0), [0xe220a8397b1dcdaf, 0x6e789e6aa1b965f4, 0x06c45d188009454f]);
        assert_eq!(first(7), [0x63cbe1e459320dd7, 0x044c3cd7f43c661c, 0xe6984080bab12a02]);
    }
}
