//! Stage 2, classification (paper section III.B): the one-way descriptor.
//!
//! Every labelled training feature (a power hole, a ground hole or a background
//! spot) is warped by a fixed set of affine poses that simulate viewpoint changes;
//! each pose gives one sample, the mean of a few slightly perturbed warps. Samples
//! are intensity-normalised and reduced by PCA; a test point takes the class of its
//! exact nearest neighbour (L2) among all samples in PCA space, unless that
//! neighbour is too far away (then it is background, see
//! [`DescriptorParams::max_distance`]).
//!
//! Scale convention: a patch is sampled on a grid of patch pixels, and `scale` is
//! the number of image pixels per patch pixel. The crate's convention (used by
//! [`DescriptorParams::scale_for_slot_pitch`], [`background_features`] and
//! [`OneWayDescriptor::classify_candidate`]) is that the pitch between a
//! receptacle's two blade slots (12.7 mm) spans
//! [`DescriptorParams::slot_pitch_patch_px`] patch pixels, by default 12.7: one
//! patch pixel per millimetre of the outlet face, so the kept 12x12 centre shows a
//! hole and the face right around it but none of its neighbours.
//!
//! ```
//! use outlet_detector::Class;
//! use outlet_detector::descriptor::{DescriptorParams, TrainingFeature, train};
//! // A dark slot on a bright face.
//! let grey = image::GrayImage::from_fn(64, 64, |x, y| {
//!     image::Luma([if (31..=33).contains(&x) && (26..=38).contains(&y) { 20 } else { 200 }])
//! });
//! let params = DescriptorParams::default();
//! let scale = params.scale_for_slot_pitch(12.7); // 1 image pixel per mm
//! let slot = TrainingFeature::new(nalgebra::Point2::new(32.0, 32.0), Class::Power, scale);
//! let flat = TrainingFeature::new(nalgebra::Point2::new(10.0, 10.0), Class::Background, scale);
//! let descriptor = train(&grey, &[slot, flat], &params).unwrap();
//! assert_eq!(descriptor.classify(&grey, slot.centre, scale).class, Class::Power);
//! ```

use crate::{Candidate, Class};
use image::GrayImage;
use nalgebra::{DMatrix, Matrix2, Point2, Vector2};
use serde::{Deserialize, Serialize};

/// How a sample is made invariant to linear intensity changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Normalisation {
    /// Subtract the mean, divide by the L2 norm: invariant to gain and offset.
    ZeroMeanUnitNorm,
    /// Divide by the mean of the pixels and subtract one (the original divided by
    /// the sum: the same up to a factor and a shift): invariant to gain only, but
    /// keeps how much darker a hole is than its surroundings.
    UnitMean,
}

/// Parameters of the one-way descriptor (paper section III.B; the original code's
/// values where the paper is silent, see `ORIGINAL.md`). Our choices were measured
/// on rendered images (`descriptor_parameter_sweep` in `tests/descriptor.rs`:
/// trained on one white 2x1, tested on held-out orange, hallway and 2x2 outlets);
/// the figures below are per-class accuracy at the outlet's scale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DescriptorParams {
    /// Side of the kept centre of a warped patch (patch pixels). Paper: warp
    /// 24x24 patches and keep their 12x12 centre. We warp straight from the image
    /// into the centre, which gives the same pixels: the centre of any pose maps
    /// back inside the 24x24 window (6 sqrt 2 / 0.8 < 12).
    pub crop_size: usize,
    /// Affine poses per training feature, each one stored sample (original: 500).
    /// Poses set the classification cost; 64 and 128 poses measured no better than
    /// 32; 16 lose 1-3 points on ground holes and gain 1-4 on background.
    pub poses_per_feature: usize,
    /// In-plane rotation theta of a pose is drawn from [-max, max] degrees
    /// (original: 60). A pose is R(phi) diag(l1, l2) R(theta - phi), the first
    /// one the identity.
    pub max_rotation_deg: f64,
    /// Also use every pose turned by a half turn, for outlets mounted ground up
    /// (without: ground holes 98% -> 90%, at the scale from the candidate's size
    /// 93% -> 79%).
    pub half_turn: bool,
    /// Range of the stretches l1, l2 of a pose (original: 0.8..1.2); phi, the
    /// stretch direction, is drawn from [0, 360) degrees.
    pub stretch: [f64; 2],
    /// Perturbed warps averaged into each pose's sample (original: 500 per pose;
    /// 1, 4 and 16 measured alike here, 4 costs 15 ms of training).
    pub noisy_copies: usize,
    /// Perturbation of a copy: angles (degrees, +-) and stretches (relative, +-).
    pub noise_rotation_deg: f64,
    pub noise_stretch: f64,
    /// Perturbation of a copy's centre (patch pixels, +-).
    pub noise_shift_px: f64,
    /// Intensity normalisation of a sample: zero mean and unit norm, the only one
    /// also invariant to an offset. Dividing by the mean as the original did
    /// (invariant to gain only) kept fewer ground holes at a `max_distance`
    /// rejecting as much background (85%): 74-85% against 97-99%.
    pub normalisation: Normalisation,
    /// Dimension of the PCA space (paper: 100). With `max_distance` 0.45: 16
    /// dims reject too little background (77%), 32 and more lose holes (100:
    /// power 82-89%, ground 92-93%) and cost more (100: 3x per point).
    pub pca_dims: usize,
    /// A point whose nearest hole sample is farther than this (PCA space; samples
    /// have unit norm) is background: the background of one training image never
    /// covers all the dark things of the world (plain nearest neighbour: 68%
    /// background rejected; with 0.45 and the margin below, 85%).
    pub max_distance: f32,
    /// A hole class wins when its nearest sample is nearer than the background's
    /// plus this margin (PCA space): a dark spot of the background image looks
    /// like a ground hole in a 12 mm window (plain nearest neighbour: ground 60-69%;
    /// with the margin 97-99%).
    pub background_margin: f32,
    /// Patch pixels spanned by the pitch of a receptacle's two blade slots: the
    /// crate's scale convention (12.7: one patch pixel per mm). More context
    /// (1.27 mm per patch pixel: 10.0) rejects more background (87-92%) but
    /// loses holes (power 90-97%, ground 86-94%).
    pub slot_pitch_patch_px: f64,
    /// A candidate's bounding-box extent max(w, h) over the slot pitch, for a power
    /// hole and for a ground hole (measured on rendered images: medians 0.53 and
    /// 0.34, spread +-20%): sets the scales at which a candidate is classified.
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
            max_rotation_deg: 180.0,
            half_turn: false,
            stretch: [0.8, 1.2],
            noisy_copies: 4,
            noise_rotation_deg: 5.0,
            noise_stretch: 0.05,
            noise_shift_px: 0.5,
            normalisation: Normalisation::ZeroMeanUnitNorm,
            pca_dims: 24,
            max_distance: 0.45,
            background_margin: 0.1,
            slot_pitch_patch_px: 12.7,
            candidate_extent: [0.53, 0.34],
            scale_range: [0.5, 2.0],
            scale_step: 1.15,
            seed: 0x0e5c_71e0,
        }
    }
}

impl DescriptorParams {
    /// The scale (image pixels per patch pixel) at which the crate's convention
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
        let finite = [self.max_rotation_deg, self.noise_rotation_deg, self.noise_stretch, self.noise_shift_px];
        if !finite.iter().all(|v| v.is_finite()) {
            return bad("rotation and noise ranges must be finite");
        }
        if !(self.slot_pitch_patch_px > 0.0 && self.slot_pitch_patch_px.is_finite()) {
            return bad("slot_pitch_patch_px must be positive");
        }
        if !(self.scale_step > 1.0 && self.scale_range[0] > 0.0 && self.scale_range[0] <= self.scale_range[1]) {
            return bad("scale_step must exceed 1 and scale_range be a positive range");
        }
        // The test scales run from scale_range[0] to [1] by scale_step: a bounded ladder.
        let steps = (self.scale_range[1] / self.scale_range[0]).ln() / self.scale_step.ln();
        if !(steps.is_finite() && steps <= MAX_SCALE_STEPS) {
            return bad("scale_range and scale_step give more than 100 test scales");
        }
        if !self.candidate_extent.iter().all(|e| *e > 0.0 && e.is_finite()) {
            return bad("candidate_extent must be positive");
        }
        if self.max_distance.is_nan() || self.background_margin.is_nan() {
            return bad("max_distance and background_margin must be numbers");
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
    /// convention: for holes, [`DescriptorParams::scale_for_slot_pitch`] of the
    /// slot pitch measured in the training image, e.g. from its labels).
    pub scale: f64,
    /// How the outlet lies in the training image at this feature: the image
    /// directions of the outlet frame's x and y (columns), scale removed (unit
    /// determinant). Samples are taken through it, so that they show the outlet
    /// as if seen head-on and upright, and the poses then span the views to come
    /// from there: a photograph taken 60 degrees off-axis and ground up trains as
    /// well as a frontal one. The identity where it is not known (background).
    #[serde(default = "Matrix2::identity")]
    pub view: Matrix2<f64>,
}

impl TrainingFeature {
    /// A feature seen as it is in the image (`view` the identity).
    pub fn new(centre: Point2<f64>, class: Class, scale: f64) -> Self {
        Self { centre, class, scale, view: Matrix2::identity() }
    }
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
    #[error("inconsistent descriptor data: {0}")]
    Inconsistent(&'static str),
}

/// The outcome of classifying one point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Classification {
    pub class: Class,
    /// Distance in PCA space to the nearest sample of `class`.
    pub distance: f32,
    /// Nearest distance per class: power, ground, background (infinite when the
    /// descriptor holds no sample of the class).
    pub class_distances: [f32; 3],
    /// The scale (image pixels per patch pixel) at which it was decided.
    pub scale: f64,
}

/// A trained one-way descriptor: PCA mean and basis, and the projected samples of
/// every pose of every training feature with their classes. Goes into template
/// files (serde; checked for consistency when read).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "DescriptorData", into = "DescriptorData")]
pub struct OneWayDescriptor {
    params: DescriptorParams,
    /// PCA dimension.
    dims: usize,
    /// Row stride of `basis`: `dims` rounded up to a multiple of 8.
    stride: usize,
    /// Mean sample (crop_size^2 values).
    mean: Vec<f32>,
    /// Transposed basis: crop_size^2 rows of `stride` values (columns past `dims`
    /// zero), so that projecting is a sum of scaled rows.
    basis: Vec<f32>,
    /// Projected samples grouped by class (power, ground, background), each class
    /// padded to a multiple of 8 samples with far-away ones; a block of 8 samples
    /// is stored dimension-major (8 values of dimension 0, then of 1, ...) so that
    /// the nearest-neighbour loop runs on 8 samples at once.
    samples: Vec<f32>,
    /// Samples per class: power, ground, background (without padding).
    counts: [usize; 3],
    /// Median scale of the training holes (image pixels per patch pixel).
    reference_scale: f64,
}

/// The serialised form of [`OneWayDescriptor`], before its checks.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct DescriptorData {
    params: DescriptorParams,
    dims: usize,
    mean: Vec<f32>,
    basis: Vec<f32>,
    samples: Vec<f32>,
    counts: [usize; 3],
    reference_scale: f64,
}

impl From<OneWayDescriptor> for DescriptorData {
    fn from(d: OneWayDescriptor) -> Self {
        Self {
            params: d.params,
            dims: d.dims,
            mean: d.mean,
            basis: d.basis,
            samples: d.samples,
            counts: d.counts,
            reference_scale: d.reference_scale,
        }
    }
}

impl TryFrom<DescriptorData> for OneWayDescriptor {
    type Error = DescriptorError;

    fn try_from(d: DescriptorData) -> Result<Self, Self::Error> {
        d.params.check()?;
        let dim = d.params.crop_size * d.params.crop_size;
        let stride = d.dims.div_ceil(LANES) * LANES;
        let padded: usize = d.counts.iter().map(|c| c.div_ceil(LANES) * LANES).sum();
        if d.dims == 0 || d.dims > dim {
            return Err(DescriptorError::Inconsistent("PCA dimension out of range"));
        }
        if d.mean.len() != dim || d.basis.len() != dim * stride {
            return Err(DescriptorError::Inconsistent("mean or basis size does not match the crop"));
        }
        if d.samples.len() != padded * d.dims {
            return Err(DescriptorError::Inconsistent("sample count does not match the class counts"));
        }
        if !(d.reference_scale > 0.0 && d.reference_scale.is_finite()) {
            return Err(DescriptorError::Inconsistent("reference scale must be positive"));
        }
        if ![&d.mean, &d.basis, &d.samples].iter().all(|v| v.iter().all(|x| x.is_finite())) {
            return Err(DescriptorError::Inconsistent("mean, basis or samples hold a value that is not finite"));
        }
        Ok(Self {
            params: d.params,
            dims: d.dims,
            stride,
            mean: d.mean,
            basis: d.basis,
            samples: d.samples,
            counts: d.counts,
            reference_scale: d.reference_scale,
        })
    }
}

/// Most test scales a descriptor may ask for (the paper's ladder has 10).
const MAX_SCALE_STEPS: f64 = 100.0;
/// Largest supported crop side (keeps per-call buffers on the stack).
const MAX_CROP: usize = 24;
/// Samples compared at once, and the padding of vectors.
const LANES: usize = 8;
/// Coordinate of padding samples: never anyone's nearest neighbour.
const FAR: f32 = 1e15;
/// Leading PCA dimensions after which a block of samples may be given up.
const HEAD_DIMS: usize = 8;

/// Adds the squared differences between `query` and 8 samples stored
/// dimension-major (`samples[d * 8 + lane]`) to `acc`.
#[inline]
fn accumulate(acc: &mut [f32; LANES], query: &[f32], samples: &[f32]) {
    for (&q, s) in query.iter().zip(samples.chunks_exact(LANES)) {
        for l in 0..LANES {
            let d = s[l] - q;
            acc[l] += d * d;
        }
    }
}

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

/// The poses shared by every feature: the identity first.
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

/// Bilinear grey value at (u, v), coordinates clamped to the (non-empty) image.
#[inline]
fn bilinear(grey: &GrayImage, u: f64, v: f64) -> f32 {
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
fn normalise(sample: &mut [f32], how: Normalisation) {
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
fn crop_offsets(crop: usize) -> impl Iterator<Item = f64> + Clone {
    let half = (crop as f64 - 1.0) / 2.0;
    (0..crop).map(move |i| i as f64 - half)
}

/// The sample of one pose of a feature: the mean of `noisy_copies` perturbed warps
/// (the first one unperturbed), normalised.
fn pose_sample(
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

/// Trains the descriptor on labelled features of one grey image (use
/// [`crate::grey_of`] for the detector's grey; paste images side by side to train
/// on several).
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
    let mut rng = Rng(params.seed ^ 0x005E_ED0F_C0E1);
    // Normalised samples, grouped by class.
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

    // PCA: eigenvectors of the samples' covariance, largest eigenvalues first.
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
    let stride = dims.div_ceil(LANES) * LANES;
    let mut basis = vec![0.0f32; dim * stride];
    for (column, &e) in order.iter().take(dims).enumerate() {
        for j in 0..dim {
            basis[j * stride + column] = eigen.eigenvectors[(j, e)] as f32;
        }
    }

    let mut descriptor = OneWayDescriptor {
        params: params.clone(),
        dims,
        stride,
        mean: mean.iter().map(|&m| m as f32).collect(),
        basis,
        samples: Vec::new(),
        counts,
        reference_scale: 1.0,
    };
    // Project, and store in blocks of 8 samples, dimension-major.
    let padded: usize = counts.iter().map(|c| c.div_ceil(LANES) * LANES).sum();
    let mut samples = vec![FAR; padded * dims];
    let mut projected = vec![0.0f32; stride];
    let (mut first_raw, mut first_out) = (0, 0);
    for count in counts {
        for i in 0..count {
            descriptor.project(&raw[(first_raw + i) * dim..(first_raw + i + 1) * dim], &mut projected);
            let (block, lane) = ((first_out + i) / LANES, (first_out + i) % LANES);
            for (d, &v) in projected.iter().take(dims).enumerate() {
                samples[block * LANES * dims + d * LANES + lane] = v;
            }
        }
        first_raw += count;
        first_out += count.div_ceil(LANES) * LANES;
    }
    descriptor.samples = samples;

    let mut hole_scales: Vec<f64> = features.iter().filter(|f| f.class != Class::Background).map(|f| f.scale).collect();
    if hole_scales.is_empty() {
        hole_scales = features.iter().map(|f| f.scale).collect();
    }
    hole_scales.sort_by(f64::total_cmp);
    descriptor.reference_scale = hole_scales[hole_scales.len() / 2];
    tracing::debug!(samples = n, dims, "descriptor trained");
    Ok(descriptor)
}

/// Background training features: the candidates farther than `exclude_radius`
/// pixels from every point of `exclude` (e.g. the labelled holes), the most
/// contrasted first, at most one per `exclude_radius / 2` neighbourhood (at least
/// 2 px), at most `max` features. Each kept candidate gives two features, at the
/// scales at which it would be taken for a power hole and for a ground hole
/// ([`DescriptorParams::candidate_scales`] of the default parameters), while `max`
/// allows.
pub fn background_features(
    grey: &GrayImage,
    candidates: &[Candidate],
    exclude: &[Point2<f64>],
    exclude_radius: f64,
    max: usize,
) -> Vec<TrainingFeature> {
    let (w, h) = grey.dimensions();
    let params = DescriptorParams::default();
    let inside = |p: &Point2<f64>| {
        p.x >= 0.0 && p.y >= 0.0 && p.x <= w.saturating_sub(1) as f64 && p.y <= h.saturating_sub(1) as f64
    };
    let mut order: Vec<&Candidate> = candidates
        .iter()
        .filter(|c| inside(&c.centre) && exclude.iter().all(|e| (c.centre - e).norm() > exclude_radius))
        .collect();
    order.sort_by(|a, b| b.contrast.total_cmp(&a.contrast));
    let spacing = (exclude_radius / 2.0).max(2.0);
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
                features.push(TrainingFeature::new(c.centre, Class::Background, scale));
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

    /// Sets [`DescriptorParams::candidate_extent`] from the candidates that the
    /// candidate stage found on labelled holes (e.g. of the training image): per
    /// hole class, the median of max(w, h) over the slot pitch. A class without
    /// candidates keeps its value. Returns the extents now used.
    ///
    /// Worth it on real photographs: on Willow's V000, seen about 60 degrees off
    /// axis, slots measure 0.24-0.33 of the pitch (rendered views: 0.53) and the
    /// ground holes merge with the dots beside them (0.5-0.66; rendered: 0.34).
    pub fn calibrate_candidate_extent(&mut self, holes: &[(TrainingFeature, Candidate)]) -> [f64; 2] {
        for (k, class) in [Class::Power, Class::Ground].into_iter().enumerate() {
            let mut ratios: Vec<f64> = holes
                .iter()
                .filter(|(f, _)| f.class == class && f.scale > 0.0 && f.scale.is_finite())
                .map(|(f, c)| c.size[0].max(c.size[1]).max(1) as f64 / (f.scale * self.params.slot_pitch_patch_px))
                .collect();
            if !ratios.is_empty() {
                ratios.sort_by(f64::total_cmp);
                self.params.candidate_extent[k] = ratios[ratios.len() / 2];
            }
        }
        self.params.candidate_extent
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
        out.iter_mut().for_each(|o| *o = 0.0);
        for ((&x, &m), row) in sample.iter().zip(&self.mean).zip(self.basis.chunks_exact(self.stride)) {
            let c = x - m;
            for (o, &b) in out.iter_mut().zip(row) {
                *o += c * b;
            }
        }
    }

    /// The normalised crop around `centre` at `scale` (axis-aligned), into `out`.
    fn sample_at(&self, grey: &GrayImage, centre: Point2<f64>, scale: f64, out: &mut [f32]) {
        let crop = self.params.crop_size;
        let (w, h) = grey.dimensions();
        if w == 0 || h == 0 {
            out.iter_mut().for_each(|x| *x = 0.0);
            return;
        }
        // Separable bilinear taps: the grid is axis-aligned at test time.
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
        let raw = grey.as_raw();
        let w = w as usize;
        let mut k = 0;
        for &(y0, y1, ty) in &ys[..crop] {
            let (r0, r1) = (&raw[y0 * w..(y0 + 1) * w], &raw[y1 * w..(y1 + 1) * w]);
            for &(x0, x1, tx) in &xs[..crop] {
                let top = r0[x0] as f32 + (r0[x1] as f32 - r0[x0] as f32) * tx;
                let bottom = r1[x0] as f32 + (r1[x1] as f32 - r1[x0] as f32) * tx;
                out[k] = top + (bottom - top) * ty;
                k += 1;
            }
        }
        normalise(out, self.params.normalisation);
    }

    /// Nearest squared distance per class to the projected query (exact, brute
    /// force over 8 samples at a time).
    fn nearest(&self, query: &[f32]) -> [f32; 3] {
        let dims = self.dims;
        let mut best = [f32::INFINITY; 3];
        let mut start = 0;
        for (c, &count) in self.counts.iter().enumerate() {
            let len = count.div_ceil(LANES) * LANES * dims;
            let Some(class_samples) = self.samples.get(start..start + len) else { break };
            start += len;
            // Partial distances over the leading (largest-variance) dimensions
            // already exceed the best so far for most blocks: skip the rest then.
            let head = dims.min(HEAD_DIMS);
            let mut lowest = f32::INFINITY;
            for block in class_samples.chunks_exact(LANES * dims) {
                let (first, rest) = block.split_at(head * LANES);
                let mut acc = [0.0f32; LANES];
                accumulate(&mut acc, &query[..head], first);
                if acc.iter().all(|&a| a >= lowest) {
                    continue;
                }
                accumulate(&mut acc, &query[head..], rest);
                lowest = acc.iter().fold(lowest, |a, &b| a.min(b));
            }
            best[c] = lowest;
        }
        best
    }

    /// The class for nearest distances per class (power, ground, background),
    /// among the hole classes `allowed`: the nearer allowed hole class when it is
    /// within `max_distance` and nearer than the background plus
    /// `background_margin`; otherwise background.
    fn decide(&self, d: [f32; 3], allowed: [bool; 2]) -> (Class, f32) {
        let hole = match allowed {
            [true, true] if d[0] <= d[1] => Some(0),
            [true, true] => Some(1),
            [true, false] => Some(0),
            [false, true] => Some(1),
            [false, false] => None,
        };
        match hole {
            Some(c) if d[c] <= self.params.max_distance && d[c] < d[2] + self.params.background_margin => {
                (CLASSES[c], d[c])
            }
            _ => (Class::Background, d[2]),
        }
    }

    /// Nearest distances per class of the point `centre` sampled at `scale`.
    fn distances(&self, grey: &GrayImage, centre: Point2<f64>, scale: f64) -> [f32; 3] {
        let dim = self.params.crop_size * self.params.crop_size;
        let mut sample = [0.0f32; MAX_CROP * MAX_CROP];
        let mut query = [0.0f32; MAX_CROP * MAX_CROP];
        if dim > sample.len() || self.stride > query.len() {
            return [f32::INFINITY; 3];
        }
        let (sample, query) = (&mut sample[..dim], &mut query[..self.stride]);
        self.sample_at(grey, centre, scale, sample);
        self.project(sample, query);
        self.nearest(&query[..self.dims]).map(f32::sqrt)
    }

    /// Classifies the point `centre` of a grey image sampled at `scale` image
    /// pixels per patch pixel (a non-positive or non-finite scale means the
    /// reference scale). Never panics: pixels outside the image are clamped.
    pub fn classify(&self, grey: &GrayImage, centre: Point2<f64>, scale: f64) -> Classification {
        let scale = if scale.is_finite() && scale > 0.0 { scale } else { self.reference_scale };
        let centre = if centre.x.is_finite() && centre.y.is_finite() { centre } else { Point2::origin() };
        let class_distances = self.distances(grey, centre, scale);
        let (class, distance) = self.decide(class_distances, [true, true]);
        Classification { class, distance, class_distances, scale }
    }

    /// Classifies at each of `scales` and keeps the decision of the scale whose
    /// nearest sample is nearest (the paper's multi-scale search per point;
    /// [`Self::scale_ladder`] gives its scales).
    pub fn classify_multiscale(&self, grey: &GrayImage, centre: Point2<f64>, scales: &[f64]) -> Classification {
        let nearest = |c: &Classification| c.class_distances.iter().fold(f32::INFINITY, |a, &b| a.min(b));
        scales
            .iter()
            .map(|&s| self.classify(grey, centre, s))
            .min_by(|a, b| nearest(a).total_cmp(&nearest(b)))
            .unwrap_or_else(|| self.classify(grey, centre, self.reference_scale))
    }

    /// Classifies a candidate at the scales its size implies, clamped to the
    /// ladder's range: it is a power hole when power wins at the scale of a power
    /// hole of its size, a ground hole when ground wins at the scale of a ground
    /// hole of its size (the nearer when both), else background. One scale when
    /// the two are within a ladder step.
    pub fn classify_candidate(&self, grey: &GrayImage, candidate: &Candidate) -> Classification {
        let [lo, hi] = self.params.scale_range.map(|r| r * self.reference_scale);
        let [sp, sg] = self.params.candidate_scales(candidate.size).map(|s| s.clamp(lo, hi));
        if sp.max(sg) / sp.min(sg) < self.params.scale_step {
            return self.classify(grey, candidate.centre, (sp * sg).sqrt());
        }
        let p = self.classify(grey, candidate.centre, sp);
        let g = self.classify(grey, candidate.centre, sg);
        let (pc, pd) = self.decide(p.class_distances, [true, false]);
        let (gc, gd) = self.decide(g.class_distances, [false, true]);
        match (pc == Class::Power, gc == Class::Ground) {
            (true, false) => Classification { class: pc, distance: pd, ..p },
            (false, true) => Classification { class: gc, distance: gd, ..g },
            (true, true) if pd <= gd => Classification { class: pc, distance: pd, ..p },
            (true, true) => Classification { class: gc, distance: gd, ..g },
            (false, false) if pd <= gd => Classification { class: Class::Background, distance: pd, ..p },
            (false, false) => Classification { class: Class::Background, distance: gd, ..g },
        }
    }

    /// [`Self::classify_candidate`] of each candidate, in order.
    pub fn classify_candidates(&self, grey: &GrayImage, candidates: &[Candidate]) -> Vec<Classification> {
        let _span = tracing::debug_span!("classify", candidates = candidates.len()).entered();
        candidates.iter().map(|c| self.classify_candidate(grey, c)).collect()
    }
}
