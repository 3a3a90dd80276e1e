//! Training: every pose of every labelled feature sampled, PCA of the samples,
//! and the projected samples stored for the nearest-neighbour search.

use super::poses::{Rng, draw_poses, pose_sample};
use super::{CLASSES, DescriptorError, DescriptorParams, FAR, LANES, OneWayDescriptor, TrainingFeature, class_index};
use crate::{Candidate, Class};
use image::GrayImage;
use nalgebra::{DMatrix, Point2};

/// Trains the descriptor on labelled features of one grey image (use
/// [`crate::grey_of`] for the detector's grey; paste images side by side to train
/// on several).
pub fn train(
    grey: &GrayImage,
    features: &[TrainingFeature],
    params: &DescriptorParams,
) -> Result<OneWayDescriptor, DescriptorError> {
    train_with(grey, features, params, false)
}

/// [`train`], and with `far_samples` every other pose sampled from the image
/// at half resolution, the feature at half its scale: a far hole (a slot 7 px
/// long at 60 cm on VGA) is the blur of a few pixels, which a sharp training
/// image never shows. On rendered approaches it found more far outlets, but
/// also a wrong outlet on a real photograph's view (BENCHMARKS.md, "Session 9:
/// far samples withdrawn"), so nothing trains with it unless asked.
pub fn train_with(
    grey: &GrayImage,
    features: &[TrainingFeature],
    params: &DescriptorParams,
    far_samples: bool,
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
    let mut rng = Rng::new(params.seed ^ 0x005E_ED0F_C0E1);
    // Normalised samples, grouped by class.
    let mut raw: Vec<f32> = Vec::with_capacity(features.len() * poses.len() * dim);
    let mut counts = [0usize; 3];
    let mut sample = vec![0.0f32; dim];
    let half = if far_samples { crate::detect::half_resolution(grey) } else { None };
    for class in CLASSES {
        for f in features.iter().filter(|f| f.class == class) {
            // The same feature in the half image's pixels (OpenCV centres).
            let halved = half.as_ref().map(|h| {
                let centre = Point2::new((f.centre.x - 0.5) / 2.0, (f.centre.y - 0.5) / 2.0);
                (h, TrainingFeature { centre, scale: f.scale / 2.0, ..*f })
            });
            for (i, pose) in poses.iter().enumerate() {
                match &halved {
                    Some((h, g)) if i % 2 == 1 => pose_sample(h, g, pose, params, &mut rng, &mut sample),
                    _ => pose_sample(grey, f, pose, params, &mut rng, &mut sample),
                }
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
        index: Default::default(),
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
    descriptor.index = super::nearest::SampleIndex::new(dims, &samples, counts);
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
