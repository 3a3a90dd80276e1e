//! Stage 2, classification (paper section III.B): the one-way descriptor.
//!
//! Every labelled training feature (a power hole, a ground hole or a background
//! spot) is warped by a fixed set of affine poses that simulate viewpoint changes;
//! each pose gives one sample, the mean of a few slightly perturbed warps. Samples
//! are intensity-normalised, reduced by PCA, and a test candidate takes the class of
//! its exact nearest neighbour (L2) among all samples in PCA space.
//!
//! Scale convention: a patch is sampled on a grid of patch pixels, and `scale` is
//! the number of image pixels per patch pixel. The built-in convention (used by
//! [`DescriptorParams::scale_for_slot_pitch`], [`background_features`] and
//! [`OneWayDescriptor::classify_candidate`]) is that the pitch between a
//! receptacle's two blade slots (12.7 mm) spans
//! [`DescriptorParams::slot_pitch_patch_px`] patch pixels, by default 12.7: one
//! patch pixel per millimetre of the outlet face, so the kept 12x12 centre covers
//! a hole and the face right around it but none of its neighbours.

use crate::{Candidate, Class};
use image::GrayImage;
use nalgebra::{DMatrix, Matrix2, Point2, Vector2};
use serde::{Deserialize, Serialize};

/// How a sample is made invariant to linear intensity changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Normalisation {
    /// Subtract the mean, divide by the L2 norm: invariant to gain and offset.
    ZeroMeanUnitNorm,
    /// Divide by the sum of the pixels (the original code): invariant to gain only.
    UnitSum,
}

/// Parameters of the one-way descriptor (paper section III.B; the original code's
/// values where the paper is silent, see `ORIGINAL.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DescriptorParams {
    /// Side of the kept centre of a warped patch (patch pixels): the paper warps
    /// 24x24 patches and keeps their 12x12 centre. Poses are warped straight from
    /// the image into the centre, which gives the same pixels: the centre of any
    /// pose maps back inside the 24x24 window (6 sqrt 2 / 0.8 < 12).
    pub crop_size: usize,
    /// Affine poses per training feature (the original: 500). Each pose is one
    /// stored sample, so this and the number of features set the classification
    /// cost.
    pub poses_per_feature: usize,
    /// In-plane rotation theta of a pose is drawn from [-max, max] degrees
    /// (original: 60). The pose is R(phi) diag(l1, l2) R(theta - phi).
    pub max_rotation_deg: f64,
    /// Also use every pose turned by a half turn, for outlets mounted ground up.
    pub half_turn: bool,
    /// Range of the stretches l1, l2 of a pose (original: 0.8..1.2); phi, the
    /// stretch direction, is drawn from [0, 360) degrees.
    pub stretch: [f64; 2],
    /// Perturbed warps averaged into each pose's sample (original: 500).
    pub noisy_copies: usize,
    /// Perturbation of a copy: rotation angles (degrees, +-), stretches (relative,
    /// +-) and centre (patch pixels, +-).
    pub noise_rotation_deg: f64,
    pub noise_stretch: f64,
    pub noise_shift_px: f64,
    /// Intensity normalisation of a sample.
    pub normalisation: Normalisation,
    /// Dimension of the PCA space (paper: 100).
    pub pca_dims: usize,
    /// Patch pixels spanned by the pitch of a receptacle's two blade slots: the
    /// scale convention of the crate's helpers (12.7: one patch pixel per mm).
    pub slot_pitch_patch_px: f64,
    /// A candidate's bounding-box extent max(w, h) over the slot pitch, for a power
    /// hole and for a ground hole: sets the one or two scales at which a candidate
    /// is classified ([`OneWayDescriptor::classify_candidate`]).
    pub candidate_extent: [f64; 2],
    /// Test scales relative to the training scale: from `scale_range[0]` to
    /// `scale_range[1]` by a factor `scale_step` (paper: 0.5..2 by 1.15).
    pub scale_range: [f64; 2],
    pub scale_step: f64,
    /// Seed of the pose and perturbation draws.
    pub seed: u64,
}

impl Default for DescriptorParams {
    fn default() -> Self {
        Self {
            crop_size: 12,
            poses_per_feature: 64,
            max_rotation_deg: 60.0,
            half_turn: true,
            stretch: [0.8, 1.2],
            noisy_copies: 8,
            noise_rotation_deg: 5.0,
            noise_stretch: 0.05,
            noise_shift_px: 0.5,
            normalisation: Normalisation::ZeroMeanUnitNorm,
            pca_dims: 24,
            slot_pitch_patch_px: 12.7,
            candidate_extent: [0.53, 0.34],
            scale_range: [0.5, 2.0],
            scale_step: 1.15,
            seed: 0x0e5c_71e0,
        }
    }
}

impl DescriptorParams {
    /// The scale (image pixels per patch pixel) at which the built-in convention
    /// samples holes whose blade slots are `pitch_px` image pixels apart.
    pub fn scale_for_slot_pitch(&self, pitch_px: f64) -> f64 {
        pitch_px / self.slot_pitch_patch_px
    }

    /// The scales at which a dark blob `size` = [w, h] pixels across would be
    /// sampled if it were a power hole and if it were a ground hole.
    pub fn candidate_scales(&self, size: [u32; 2]) -> [f64; 2] {
        let extent = size[0].max(size[1]).max(1) as f64;
        self.candidate_extent.map(|fraction| self.scale_for_slot_pitch(extent / fraction.max(1e-3)))
    }

    fn check(&self) -> Result<(), DescriptorError> {
        let bad = |what: &str| Err(DescriptorError::Params(what.to_string()));
        if self.crop_size < 2 || self.crop_size > MAX_CROP {
            return bad("crop_size must be within 2..=24");
        }
        if self.poses_per_feature == 0 || self.noisy_copies == 0 {
            return bad("poses_per_feature and noisy_copies must be at least 1");
        }
        if self.pca_dims == 0 {
            return bad("pca_dims must be at least 1");
        }
        if !(self.stretch[0] > 0.0 && self.stretch[0] <= self.stretch[1] && self.stretch[1].is_finite()) {
            return bad("stretch must be a range of positive numbers");
        }
        if !(self.slot_pitch_patch_px > 0.0 && self.slot_pitch_patch_px.is_finite()) {
            return bad("slot_pitch_patch_px must be positive");
        }
        if !(self.scale_step > 1.0 && self.scale_range[0] > 0.0 && self.scale_range[0] <= self.scale_range[1]) {
            return bad("scale_step must exceed 1 and scale_range be a positive range");
        }
        Ok(())
    }
}

/// A labelled point of a training image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TrainingFeature {
    /// Centre in the training image (pixels, OpenCV convention).
    pub centre: Point2<f64>,
    pub class: Class,
    /// Image pixels per patch pixel at this feature (see the module's scale
    /// convention; for holes, [`DescriptorParams::scale_for_slot_pitch`] of the
    /// slot pitch measured in the training image).
    pub scale: f64,
}

/// What went wrong in training.
#[derive(Debug, thiserror::Error)]
pub enum DescriptorError {
    #[error("invalid descriptor parameters: {0}")]
    Params(String),
    #[error("no training features")]
    NoFeatures,
    #[error("the training image is empty ({width}x{height})")]
    EmptyImage { width: u32, height: u32 },
    #[error("training feature {index} at ({u}, {v}) with scale {scale} is not usable: {why}")]
    BadFeature { index: usize, u: f64, v: f64, scale: f64, why: &'static str },
}

/// The outcome of classifying one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Classification {
    /// Class of the nearest training sample.
    pub class: Class,
    /// L2 distance to it in PCA space (samples have unit norm before projection).
    pub distance: f32,
    /// Nearest distance per class: power, ground, background (infinite when the
    /// descriptor holds no sample of the class).
    pub class_distances: [f32; 3],
    /// The scale (image pixels per patch pixel) at which it was found.
    pub scale: f64,
}

/// A trained one-way descriptor: PCA basis and the projected samples of every pose
/// of every training feature. Goes into template files (serde).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OneWayDescriptor {
    params: DescriptorParams,
    /// PCA dimension actually used (at most `params.pca_dims`).
    dims: usize,
    /// Row stride of `basis` and `samples`: `dims` rounded up to a multiple of 8.
    stride: usize,
    /// Mean sample (crop_size^2 values).
    mean: Vec<f32>,
    /// Basis vectors, `stride` rows of crop_size^2 values (rows past `dims` zero).
    basis: Vec<f32>,
    /// Projected samples, `stride` values each, grouped by class: power, ground,
    /// background.
    samples: Vec<f32>,
    /// Samples per class: power, ground, background.
    counts: [usize; 3],
    /// Median scale of the training holes (image pixels per patch pixel).
    reference_scale: f64,
}

/// Largest supported crop side (keeps per-call buffers on the stack).
const MAX_CROP: usize = 24;

const CLASSES: [Class; 3] = [Class::Power, Class::Ground, Class::Background];

fn class_index(class: Class) -> usize {
    match class {
        Class::Power => 0,
        Class::Ground => 1,
        Class::Background => 2,
    }
}

/// Deterministic generator for poses and perturbations (splitmix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [a, b).
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// An affine pose R(phi) diag(l1, l2) R(theta - phi), angles in radians.
#[derive(Debug, Clone, Copy)]
struct Pose {
    theta: f64,
    phi: f64,
    l1: f64,
    l2: f64,
}

fn rotation(a: f64) -> Matrix2<f64> {
    let (s, c) = a.sin_cos();
    Matrix2::new(c, -s, s, c)
}

impl Pose {
    /// The inverse pose: from the simulated view's patch to the training patch.
    fn inverse(&self) -> Matrix2<f64> {
        rotation(self.phi - self.theta) * Matrix2::new(1.0 / self.l1, 0.0, 0.0, 1.0 / self.l2) * rotation(-self.phi)
    }
}

fn draw_poses(params: &DescriptorParams) -> Vec<Pose> {
    let mut rng = Rng(params.seed);
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

/// Bilinear grey value at (u, v), coordinates clamped to the image.
#[inline]
fn bilinear(grey: &GrayImage, u: f64, v: f64) -> f32 {
    let (w, h) = grey.dimensions();
    let u = u.clamp(0.0, (w - 1) as f64);
    let v = v.clamp(0.0, (h - 1) as f64);
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
fn normalise(sample: &mut [f32], how: Normalisation) {
    match how {
        Normalisation::ZeroMeanUnitNorm => {
            let mean = sample.iter().sum::<f32>() / sample.len() as f32;
            sample.iter_mut().for_each(|x| *x -= mean);
            let norm = sample.iter().map(|x| x * x).sum::<f32>().sqrt();
            let k = if norm > 1e-3 { 1.0 / norm } else { 0.0 };
            sample.iter_mut().for_each(|x| *x *= k);
        }
        Normalisation::UnitSum => {
            let sum = sample.iter().sum::<f32>();
            let k = if sum > 1e-3 { 1.0 / sum } else { 0.0 };
            sample.iter_mut().for_each(|x| *x *= k);
        }
    }
}

/// Offsets of the crop's pixel centres from the patch centre (patch pixels).
fn crop_offsets(crop: usize) -> impl Iterator<Item = f64> + Clone {
    let half = (crop as f64 - 1.0) / 2.0;
    (0..crop).map(move |i| i as f64 - half)
}

/// The sample of one pose of a feature: the mean of `noisy_copies` perturbed warps.
fn pose_sample(
    grey: &GrayImage,
    feature: &TrainingFeature,
    pose: &Pose,
    params: &DescriptorParams,
    rng: &mut Rng,
    out: &mut [f32],
) {
    out.iter_mut().for_each(|x| *x = 0.0);
    let copies = params.noisy_copies;
    let (dr, ds, dp) = (params.noise_rotation_deg.to_radians(), params.noise_stretch, params.noise_shift_px);
    for copy in 0..copies {
        let perturbed = if copy == 0 {
            *pose
        } else {
            Pose {
                theta: pose.theta + rng.range(-dr, dr),
                phi: pose.phi + rng.range(-dr, dr),
                l1: pose.l1 * (1.0 + rng.range(-ds, ds)),
                l2: pose.l2 * (1.0 + rng.range(-ds, ds)),
            }
        };
        let shift = if copy == 0 { Vector2::zeros() } else { Vector2::new(rng.range(-dp, dp), rng.range(-dp, dp)) };
        let to_image = perturbed.inverse() * feature.scale;
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

/// Trains the descriptor on labelled features of one grey image (use
/// [`crate::grey_of`] for the detector's grey).
pub fn train(
    grey: &GrayImage,
    features: &[TrainingFeature],
    params: &DescriptorParams,
) -> Result<OneWayDescriptor, DescriptorError> {
    let _span = tracing::debug_span!("descriptor_train", features = features.len()).entered();
    params.check()?;
    let (width, height) = grey.dimensions();
    if width == 0 || height == 0 {
        return Err(DescriptorError::EmptyImage { width, height });
    }
    if features.is_empty() {
        return Err(DescriptorError::NoFeatures);
    }
    for (index, f) in features.iter().enumerate() {
        let bad = |why| DescriptorError::BadFeature { index, u: f.centre.x, v: f.centre.y, scale: f.scale, why };
        if !(f.scale > 0.0 && f.scale.is_finite()) {
            return Err(bad("scale must be positive"));
        }
        let inside =
            (0.0..=(width - 1) as f64).contains(&f.centre.x) && (0.0..=(height - 1) as f64).contains(&f.centre.y);
        if !inside {
            return Err(bad("centre outside the image"));
        }
    }

    let dim = params.crop_size * params.crop_size;
    let poses = draw_poses(params);
    let mut rng = Rng(params.seed ^ 0x5EED_0F_C0E1);
    // Raw samples grouped by class.
    let mut raw: Vec<f32> = Vec::with_capacity(features.len() * poses.len() * dim);
    let mut counts = [0usize; 3];
    let mut sample = vec![0.0f32; dim];
    for class in CLASSES {
        for f in features.iter().filter(|f| f.class == class) {
            for pose in &poses {
                pose_sample(grey, f, pose, params, &mut rng, &mut sample);
                raw.extend_from_slice(&sample);
                counts[class_index(class)] += 1;
            }
        }
    }
    let n = raw.len() / dim;

    // PCA: eigenvectors of the samples' covariance.
    let mut mean = vec![0.0f64; dim];
    for s in raw.chunks_exact(dim) {
        mean.iter_mut().zip(s).for_each(|(m, &x)| *m += x as f64);
    }
    mean.iter_mut().for_each(|m| *m /= n as f64);
    let centred = DMatrix::<f64>::from_fn(n, dim, |i, j| raw[i * dim + j] as f64 - mean[j]);
    let covariance = centred.tr_mul(&centred) / n as f64;
    let eigen = covariance.symmetric_eigen();
    let mut order: Vec<usize> = (0..dim).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let dims = params.pca_dims.min(dim);
    let stride = dims.div_ceil(8) * 8;
    let mut basis = vec![0.0f32; stride * dim];
    for (row, &e) in order.iter().take(dims).enumerate() {
        for j in 0..dim {
            basis[row * dim + j] = eigen.eigenvectors[(j, e)] as f32;
        }
    }
    let mean: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
    let mut descriptor = OneWayDescriptor {
        params: params.clone(),
        dims,
        stride,
        mean,
        basis,
        samples: vec![0.0; n * stride],
        counts,
        reference_scale: 1.0,
    };
    let mut samples = vec![0.0f32; n * stride];
    for (s, out) in raw.chunks_exact(dim).zip(samples.chunks_exact_mut(stride)) {
        descriptor.project(s, out);
    }
    descriptor.samples = samples;
    let mut hole_scales: Vec<f64> = features.iter().filter(|f| f.class != Class::Background).map(|f| f.scale).collect();
    if hole_scales.is_empty() {
        hole_scales = features.iter().map(|f| f.scale).collect();
    }
    hole_scales.sort_by(f64::total_cmp);
    descriptor.reference_scale = hole_scales[hole_scales.len() / 2];
    Ok(descriptor)
}

/// Background training features: the candidates farther than `exclude_radius`
/// pixels from every point of `exclude` (e.g. the labelled holes), the most
/// contrasted first, at most one per `exclude_radius / 2` neighbourhood, at most
/// `max` features. Each kept candidate gives two features, one at the scale at
/// which it would be classified as a power hole and one as a ground hole (the
/// default [`DescriptorParams::candidate_scales`]), while `max` allows.
pub fn background_features(
    grey: &GrayImage,
    candidates: &[Candidate],
    exclude: &[Point2<f64>],
    exclude_radius: f64,
    max: usize,
) -> Vec<TrainingFeature> {
    let (w, h) = grey.dimensions();
    let params = DescriptorParams::default();
    let mut order: Vec<&Candidate> = candidates
        .iter()
        .filter(|c| {
            c.centre.x.is_finite()
                && c.centre.y.is_finite()
                && c.centre.x >= 0.0
                && c.centre.y >= 0.0
                && c.centre.x <= w.saturating_sub(1) as f64
                && c.centre.y <= h.saturating_sub(1) as f64
                && exclude.iter().all(|e| (c.centre - e).norm() > exclude_radius)
        })
        .collect();
    order.sort_by(|a, b| b.contrast.total_cmp(&a.contrast));
    let spacing = (exclude_radius / 2.0).max(1.0);
    let mut kept: Vec<Point2<f64>> = Vec::new();
    let mut features = Vec::new();
    for c in order {
        if features.len() >= max {
            break;
        }
        if kept.iter().any(|k| (c.centre - k).norm() < spacing) {
            continue;
        }
        kept.push(c.centre);
        for scale in params.candidate_scales(c.size) {
            if features.len() < max {
                features.push(TrainingFeature { centre: c.centre, class: Class::Background, scale });
            }
        }
    }
    features
}

impl OneWayDescriptor {
    /// The parameters it was trained with.
    pub fn params(&self) -> &DescriptorParams {
        &self.params
    }

    /// Dimension of the PCA space.
    pub fn dims(&self) -> usize {
        self.dims
    }

    /// Stored samples per class: power, ground, background.
    pub fn sample_counts(&self) -> [usize; 3] {
        self.counts
    }

    /// Median scale of the training holes (image pixels per patch pixel).
    pub fn reference_scale(&self) -> f64 {
        self.reference_scale
    }

    /// The paper's test scales: the reference scale times 0.5 .. 2 by x1.15.
    pub fn scale_ladder(&self) -> Vec<f64> {
        let [lo, hi] = self.params.scale_range;
        let mut scales = Vec::new();
        let mut s = lo;
        while s <= hi * (1.0 + 1e-9) {
            scales.push(self.reference_scale * s);
            s *= self.params.scale_step;
        }
        scales
    }

    /// PCA coefficients of a normalised sample into `out` (`stride` values).
    fn project(&self, sample: &[f32], out: &mut [f32]) {
        let dim = self.mean.len();
        for (o, row) in out.iter_mut().zip(self.basis.chunks_exact(dim)) {
            *o = row.iter().zip(sample).zip(&self.mean).map(|((b, x), m)| b * (x - m)).sum();
        }
    }

    /// The normalised crop around `centre` at `scale`, axis-aligned.
    fn sample_at(&self, grey: &GrayImage, centre: Point2<f64>, scale: f64, out: &mut [f32]) {
        let crop = self.params.crop_size;
        let (w, h) = grey.dimensions();
        if w == 0 || h == 0 {
            out.iter_mut().for_each(|x| *x = 0.0);
            return;
        }
        // Separable bilinear weights: the grid is axis-aligned at test time.
        let axis = |c: f64, len: u32| {
            let mut taps = [(0usize, 0usize, 0.0f32); MAX_CROP];
            for (t, o) in taps.iter_mut().zip(crop_offsets(crop)) {
                let p = (c + o * scale).clamp(0.0, (len - 1) as f64);
                let p0 = p as usize;
                *t = (p0, (p0 + 1).min(len as usize - 1), (p - p0 as f64) as f32);
            }
            taps
        };
        let (xs, ys) = (axis(centre.x, w), axis(centre.y, h));
        let (xs, ys) = (&xs[..crop], &ys[..crop]);
        let raw = grey.as_raw();
        let w = w as usize;
        let mut k = 0;
        for &(y0, y1, ty) in ys {
            let (r0, r1) = (&raw[y0 * w..(y0 + 1) * w], &raw[y1 * w..(y1 + 1) * w]);
            for &(x0, x1, tx) in xs {
                let top = r0[x0] as f32 + (r0[x1] as f32 - r0[x0] as f32) * tx;
                let bottom = r1[x0] as f32 + (r1[x1] as f32 - r1[x0] as f32) * tx;
                out[k] = top + (bottom - top) * ty;
                k += 1;
            }
        }
        normalise(out, self.params.normalisation);
    }

    /// Nearest squared distance per class to the projected query.
    fn nearest(&self, query: &[f32]) -> [f32; 3] {
        let mut best = [f32::INFINITY; 3];
        let mut start = 0;
        for (c, &count) in self.counts.iter().enumerate() {
            let block = &self.samples[start * self.stride..(start + count) * self.stride];
            start += count;
            for s in block.chunks_exact(self.stride) {
                let mut acc = [0.0f32; 8];
                for (qc, sc) in query.chunks_exact(8).zip(s.chunks_exact(8)) {
                    for l in 0..8 {
                        let d = qc[l] - sc[l];
                        acc[l] += d * d;
                    }
                }
                let d = acc.iter().sum::<f32>();
                if d < best[c] {
                    best[c] = d;
                }
            }
        }
        best
    }

    /// Classifies the point `centre` of a grey image, sampled at `scale` image
    /// pixels per patch pixel. Never panics: pixels outside the image are clamped.
    pub fn classify(&self, grey: &GrayImage, centre: Point2<f64>, scale: f64) -> Classification {
        let mut sample = [0.0f32; MAX_CROP * MAX_CROP];
        let mut query = [0.0f32; MAX_CROP * MAX_CROP + 8];
        let dim = self.mean.len();
        let (sample, query) = (&mut sample[..dim], &mut query[..self.stride]);
        let scale = if scale.is_finite() && scale > 0.0 { scale } else { self.reference_scale };
        let centre = if centre.x.is_finite() && centre.y.is_finite() { centre } else { Point2::origin() };
        self.sample_at(grey, centre, scale, sample);
        self.project(sample, query);
        let best = self.nearest(query);
        let (c, d2) =
            best.iter().enumerate().fold((2, f32::INFINITY), |acc, (c, &d)| if d < acc.1 { (c, d) } else { acc });
        Classification { class: CLASSES[c], distance: d2.sqrt(), class_distances: best.map(f32::sqrt), scale }
    }

    #[doc(hidden)]
    pub fn debug_nearest(&self, grey: &GrayImage, centre: Point2<f64>, scale: f64) -> (usize, f32, Vec<f32>) {
        let dim = self.mean.len();
        let mut sample = vec![0.0f32; dim];
        let mut query = vec![0.0f32; self.stride];
        self.sample_at(grey, centre, scale, &mut sample);
        self.project(&sample, &mut query);
        let mut best = (0, f32::INFINITY);
        for (i, s) in self.samples.chunks_exact(self.stride).enumerate() {
            let d: f32 = s.iter().zip(&query).map(|(a, b)| (a - b) * (a - b)).sum();
            if d < best.1 {
                best = (i, d);
            }
        }
        (best.0, best.1.sqrt(), sample)
    }

    /// Classifies at each of `scales` and keeps the nearest match (the paper's
    /// multi-scale search; [`Self::scale_ladder`] gives its scales).
    pub fn classify_multiscale(&self, grey: &GrayImage, centre: Point2<f64>, scales: &[f64]) -> Classification {
        let mut best: Option<Classification> = None;
        for &s in scales {
            let c = self.classify(grey, centre, s);
            best = match best {
                Some(b) if b.distance <= c.distance => Some(b),
                _ => Some(c),
            };
        }
        best.unwrap_or_else(|| self.classify(grey, centre, self.reference_scale))
    }

    /// Classifies a candidate at the scales its size implies: the scale at which it
    /// would be a power hole and the one at which it would be a ground hole (one
    /// scale when the two are within a ladder step), clamped to the ladder's range.
    pub fn classify_candidate(&self, grey: &GrayImage, candidate: &Candidate) -> Classification {
        let [lo, hi] = self.params.scale_range.map(|r| r * self.reference_scale);
        let [sp, sg] = self.params.candidate_scales(candidate.size).map(|s| s.clamp(lo, hi));
        if sp.max(sg) / sp.min(sg) < self.params.scale_step {
            return self.classify(grey, candidate.centre, (sp * sg).sqrt());
        }
        if std::env::var("PERHYP").is_err() {
            return self.classify_multiscale(grey, candidate.centre, &[sp, sg]);
        }
        // Each hypothesis holds when its class is nearer than the background at its scale.
        let p = self.classify(grey, candidate.centre, sp);
        let g = self.classify(grey, candidate.centre, sg);
        let [dp, _, bp] = p.class_distances;
        let [_, dg, bg] = g.class_distances;
        let power = dp < bp;
        let ground = dg < bg;
        match (power, ground) {
            (true, false) => Classification { class: Class::Power, distance: dp, ..p },
            (false, true) => Classification { class: Class::Ground, distance: dg, ..g },
            (true, true) if dp <= dg => Classification { class: Class::Power, distance: dp, ..p },
            (true, true) => Classification { class: Class::Ground, distance: dg, ..g },
            (false, false) if bp <= bg => Classification { class: Class::Background, distance: bp, ..p },
            (false, false) => Classification { class: Class::Background, distance: bg, ..g },
        }
    }
}
