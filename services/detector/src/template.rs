//! Templates: what the detector knows of one kind of outlet, learnt from ONE
//! labelled image (paper section IV): the holes' geometry and the trained one-way
//! descriptor. Files are postcard behind a header with a format version and a
//! CRC-32, so that a truncated, corrupted or too-new file is named and refused.

use crate::descriptor::{DescriptorError, DescriptorParams, OneWayDescriptor, TrainingFeature, background_features};
use crate::{Candidate, Class};
use image::GrayImage;
use nalgebra::{Matrix2, Matrix3, Point2};
use outlet_protocol::OutletGeometry;
use outlet_protocol::math::{apply_homography, fit_homography};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The file format this build writes and the newest it reads.
pub const TEMPLATE_FORMAT_VERSION: u32 = 1;
const MAGIC: &[u8; 8] = b"OUTLETTP";
const HEADER_LEN: usize = 8 + 4 + 8 + 4;

/// A trained outlet template.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Template {
    /// `2x1`, `2x2`, or the name given at training.
    pub name: String,
    /// Holes in the outlet frame (mm), template order.
    pub geometry: OutletGeometry,
    pub descriptor: OneWayDescriptor,
}

/// A template as its file holds it (the same layout as [`Template`]), before
/// the descriptor's checks.
#[derive(Deserialize)]
struct TemplateData {
    name: String,
    geometry: OutletGeometry,
    descriptor: crate::descriptor::DescriptorData,
}

/// Why a template could not be made or read.
#[derive(Debug, thiserror::Error)]
pub enum TemplateError {
    #[error("cannot read template {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path} is not an outlet template file")]
    NotATemplate { path: String },
    #[error("template {path} has format version {found}; this build reads up to {supported}")]
    TooNew { path: String, found: u32, supported: u32 },
    #[error("template {path} is truncated: {got} of {expected} bytes")]
    Truncated { path: String, expected: u64, got: u64 },
    #[error("template {path} is corrupted: checksum {found:08x}, expected {expected:08x}")]
    Checksum { path: String, found: u32, expected: u32 },
    #[error("template {name} cannot be encoded: {reason}")]
    Encode { name: String, reason: String },
    #[error("template {path} cannot be decoded: {reason}")]
    Decode { path: String, reason: String },
    #[error("template {name}: {reason}")]
    Invalid { name: String, reason: String },
    #[error("training template {name}: {source}")]
    Training { name: String, source: DescriptorError },
}

impl Template {
    /// The file's bytes: header (magic, version, payload length, CRC-32), then postcard.
    pub fn to_bytes(&self) -> Result<Vec<u8>, TemplateError> {
        let payload = postcard::to_stdvec(self)
            .map_err(|e| TemplateError::Encode { name: self.name.clone(), reason: e.to_string() })?;
        let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&TEMPLATE_FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Parses a template file's bytes; `path` names it in errors.
    pub fn from_bytes(bytes: &[u8], path: &str) -> Result<Self, TemplateError> {
        let path = path.to_string();
        if bytes.len() < MAGIC.len() && MAGIC.starts_with(bytes) {
            // Empty, or cut inside the magic: a template file that was never finished.
            return Err(TemplateError::Truncated { path, expected: HEADER_LEN as u64, got: bytes.len() as u64 });
        }
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(TemplateError::NotATemplate { path });
        }
        if bytes.len() < HEADER_LEN {
            return Err(TemplateError::Truncated { path, expected: HEADER_LEN as u64, got: bytes.len() as u64 });
        }
        let word = |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
        let version = word(8);
        if version > TEMPLATE_FORMAT_VERSION || version == 0 {
            return Err(TemplateError::TooNew { path, found: version, supported: TEMPLATE_FORMAT_VERSION });
        }
        let mut len_bytes = [0u8; 8];
        len_bytes.copy_from_slice(&bytes[12..20]);
        let len = u64::from_le_bytes(len_bytes);
        let expected_crc = word(20);
        let payload = &bytes[HEADER_LEN..];
        if (payload.len() as u64) < len {
            let expected = (HEADER_LEN as u64).saturating_add(len);
            return Err(TemplateError::Truncated { path, expected, got: bytes.len() as u64 });
        }
        let payload = &payload[..len as usize];
        let found = crc32fast::hash(payload);
        if found != expected_crc {
            return Err(TemplateError::Checksum { path, found, expected: expected_crc });
        }
        // Decoded first, checked after: postcard would reduce the checks' own
        // messages to "Serde Deserialization Error".
        let data: TemplateData = postcard::from_bytes(payload)
            .map_err(|e| TemplateError::Decode { path: path.clone(), reason: e.to_string() })?;
        let invalid = |reason: String| TemplateError::Invalid { name: path.clone(), reason };
        let descriptor = OneWayDescriptor::try_from(data.descriptor).map_err(|e| invalid(e.to_string()))?;
        data.geometry.validate(&path).map_err(|e| invalid(e.to_string()))?;
        Ok(Template { name: data.name, geometry: data.geometry, descriptor })
    }

    pub fn read(path: &Path) -> Result<Self, TemplateError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| TemplateError::Io { path: name.clone(), source })?;
        Self::from_bytes(&bytes, &name)
    }

    pub fn write(&self, path: &Path) -> Result<(), TemplateError> {
        std::fs::write(path, self.to_bytes()?)
            .map_err(|source| TemplateError::Io { path: path.display().to_string(), source })
    }
}

/// One labelled training image: the holes' pixels in the geometry's order, and
/// the hole candidates found in it.
#[derive(Debug, Clone)]
pub struct TrainingImage<'a> {
    pub grey: &'a GrayImage,
    pub holes: Vec<Point2<f64>>,
    pub candidates: Vec<Candidate>,
}

/// Empty pixels between the images of the training mosaic: wider than a warped
/// patch reaches (24 patch pixels at the largest scale).
const MOSAIC_GAP_PX: u32 = 64;

/// The images side by side in one, and where each one's origin went: the
/// descriptor samples every feature from one image.
fn mosaic(images: &[&GrayImage]) -> (GrayImage, Vec<f64>) {
    let width = images.iter().map(|g| g.width() + MOSAIC_GAP_PX).sum::<u32>();
    let height = images.iter().map(|g| g.height()).max().unwrap_or(0);
    let mut out = GrayImage::from_pixel(width.max(1), height.max(1), image::Luma([128]));
    let mut offsets = Vec::with_capacity(images.len());
    let mut x = 0;
    for g in images {
        image::imageops::replace(&mut out, *g, x as i64, 0);
        offsets.push(x as f64);
        x += g.width() + MOSAIC_GAP_PX;
    }
    (out, offsets)
}

/// Trains a template from labelled views of the outlet (the paper: ONE image)
/// and background images; without backgrounds, only the views' candidates away
/// from the holes serve. With `calibrate_sizes` the candidates' sizes on the
/// labelled holes set how candidates are scaled for classification (worth it for
/// photographs; the rendered default suits renders).
pub fn train_template(
    name: &str,
    geometry: OutletGeometry,
    views: &[TrainingImage],
    backgrounds: &[(&GrayImage, Vec<Candidate>)],
    params: &DescriptorParams,
    calibrate_sizes: bool,
) -> Result<Template, TemplateError> {
    let options = TrainingOptions { calibrate_sizes, ..TrainingOptions::default() };
    train_template_with(name, geometry, views, backgrounds, params, &options)
}

/// How a template is trained beyond the paper's one-way descriptor.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrainingOptions<'a> {
    /// The candidates' sizes on the labelled holes set how candidates are
    /// scaled for classification (for photographs).
    pub calibrate_sizes: bool,
    /// Each labelled hole also trained foreshortened by each of these (the
    /// ratio of a view's stretches, 1/cos of its off-axis angle: 2.0 is 60
    /// degrees) across three axes of the face 60 degrees apart, as ASIFT samples
    /// tilts: the poses' own stretches reach about 45 degrees from the training
    /// view. On the Willow views a tilt of 2.0 found more steep views, and one
    /// wrong (BENCHMARKS.md, "Tilted training"), so `outlet train` adds none
    /// unless asked.
    pub tilts: &'a [f64],
    /// Half the poses sampled at half resolution
    /// ([`crate::descriptor::train_with`]). Off for the built-in templates:
    /// BENCHMARKS.md, "Session 9: far samples withdrawn".
    pub far_samples: bool,
}

/// [`train_template`] with every option.
pub fn train_template_with(
    name: &str,
    geometry: OutletGeometry,
    views: &[TrainingImage],
    backgrounds: &[(&GrayImage, Vec<Candidate>)],
    params: &DescriptorParams,
    options: &TrainingOptions,
) -> Result<Template, TemplateError> {
    let TrainingOptions { calibrate_sizes, tilts, far_samples } = *options;
    let invalid = |reason: String| TemplateError::Invalid { name: name.to_string(), reason };
    geometry.validate(name).map_err(|e| invalid(e.to_string()))?;
    if let Some(t) = tilts.iter().find(|t| !(t.is_finite() && (1.0..=10.0).contains(*t))) {
        return Err(invalid(format!("tilt {t} is not within 1..=10")));
    }
    if views.is_empty() {
        return Err(invalid("no labelled training image".into()));
    }
    let images: Vec<&GrayImage> = views.iter().map(|v| v.grey).chain(backgrounds.iter().map(|(g, _)| *g)).collect();
    let (grey, offsets) = mosaic(&images);
    let shift = |p: Point2<f64>, k: usize| Point2::new(p.x + offsets[k], p.y);
    // Background: what else looks like a hole. The views' own non-hole
    // candidates (screw slots, face edges) are the most telling of all.
    const MAX_BACKGROUND: usize = 60;
    let per_view = (MAX_BACKGROUND / 2).div_ceil(views.len());
    let mut features = Vec::new();
    let mut pairs: Vec<(TrainingFeature, Candidate)> = Vec::new();
    for (k, view) in views.iter().enumerate() {
        if view.holes.len() != geometry.holes.len() {
            return Err(invalid(format!(
                "{} labelled holes for a geometry of {}",
                view.holes.len(),
                geometry.holes.len()
            )));
        }
        let pitch_px =
            slot_pitch_px(&geometry, &view.holes).ok_or_else(|| invalid("the labels are degenerate".into()))?;
        let scale = params.scale_for_slot_pitch(pitch_px);
        let outlet_to_image = outlet_homography(&geometry, &view.holes);
        for (h, p) in geometry.holes.iter().zip(&view.holes) {
            let feature = TrainingFeature::new(shift(*p, k), Class::from(h.kind), scale);
            features.push(feature);
            // An oblique view trains twice: as it is, for views like it, and
            // head-on, for the views between head-on and it (the poses' stretches
            // reach about 45 degrees either way).
            if let Some(view) = outlet_to_image.as_ref().and_then(|m| head_on_view(m, &h.position())) {
                let stretch = view.singular_values();
                if stretch.max() > HEAD_ON_ALSO_ABOVE * stretch.min() {
                    features.push(TrainingFeature { view, ..feature });
                }
                features.extend(tilted_views(&view, tilts).map(|view| TrainingFeature { view, ..feature }));
            }
            // The candidate that the candidate stage found on this hole.
            let on_hole = view
                .candidates
                .iter()
                .filter(|c| (c.centre - p).norm() < 0.3 * pitch_px)
                .min_by(|a, b| (a.centre - p).norm().total_cmp(&(b.centre - p).norm()));
            if let Some(c) = on_hole {
                pairs.push((feature, *c));
            }
        }
        let background = background_features(view.grey, &view.candidates, &view.holes, 0.35 * pitch_px, per_view);
        features.extend(background.into_iter().map(|f| TrainingFeature { centre: shift(f.centre, k), ..f }));
    }
    if !backgrounds.is_empty() {
        let per_image = MAX_BACKGROUND.div_ceil(backgrounds.len());
        for (j, (g, candidates)) in backgrounds.iter().enumerate() {
            let k = views.len() + j;
            let background = background_features(g, candidates, &[], 0.0, per_image);
            features.extend(background.into_iter().map(|f| TrainingFeature { centre: shift(f.centre, k), ..f }));
        }
    }
    let mut descriptor = crate::descriptor::train_with(&grey, &features, params, far_samples)
        .map_err(|source| TemplateError::Training { name: name.to_string(), source })?;
    if calibrate_sizes {
        // How big the candidate stage sees this outlet's holes, relative to their
        // spacing: on a real photograph (blur, an oblique view, dots merging with
        // the ground holes) it differs from the rendered default.
        descriptor.calibrate_candidate_extent(&pairs);
    }
    Ok(Template { name: name.to_string(), geometry, descriptor })
}

/// The foreshortening (ratio of the view's stretches) beyond which a hole is also
/// trained head-on: 1.25 is 37 degrees off-axis, which the poses' own stretches
/// (0.8..1.2) nearly cover.
const HEAD_ON_ALSO_ABOVE: f64 = 1.25;

/// The head-on `view` turned away by each foreshortening of `tilts` about three
/// axes of the outlet's face 60 degrees apart: the face compressed by t across
/// the axis, so that a patch covers t times more of it that way.
fn tilted_views<'a>(view: &'a Matrix2<f64>, tilts: &'a [f64]) -> impl Iterator<Item = Matrix2<f64>> + 'a {
    const AXES: usize = 3;
    tilts.iter().flat_map(move |&t| {
        (0..AXES).map(move |k| {
            let (s, c) = (std::f64::consts::PI * k as f64 / AXES as f64).sin_cos();
            let axis = Matrix2::new(c, -s, s, c);
            view * axis * Matrix2::new(1.0, 0.0, 0.0, t) * axis.transpose()
        })
    })
}

/// The homography from the outlet frame (mm) to the labelled pixels, where the
/// labels fit one (lens distortion left in: it is nearly affine over an outlet).
fn outlet_homography(geometry: &OutletGeometry, pixels: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    let pairs: Vec<(Point2<f64>, Point2<f64>)> =
        geometry.holes.iter().zip(pixels).map(|(h, p)| (h.position(), *p)).collect();
    if pairs.len() < 4 {
        return None;
    }
    let h = fit_homography(&pairs)?;
    // Labels that no plane explains (a typo, a wrong order) get no view at all.
    let pitch = slot_pitch_px(geometry, pixels)?;
    let worst = pairs.iter().filter_map(|(t, p)| apply_homography(&h, t).map(|q| (q - p).norm())).fold(0.0, f64::max);
    (worst < 0.25 * pitch).then_some(h)
}

/// The outlet's image directions at an outlet point, scale removed: the local
/// Jacobian of `h` over the square root of its determinant. `None` for a
/// mirrored or degenerate view.
fn head_on_view(h: &Matrix3<f64>, t: &Point2<f64>) -> Option<Matrix2<f64>> {
    let at = |dx: f64, dy: f64| apply_homography(h, &Point2::new(t.x + dx, t.y + dy));
    let (xp, xm, yp, ym) = (at(0.5, 0.0)?, at(-0.5, 0.0)?, at(0.0, 0.5)?, at(0.0, -0.5)?);
    let j = Matrix2::new(xp.x - xm.x, yp.x - ym.x, xp.y - xm.y, yp.y - ym.y);
    let det = j.determinant();
    (det.is_finite() && det > 0.0).then(|| j / det.sqrt())
}

/// The image length of 12.7 mm near the holes: the mean ratio of pixel to mm
/// distances over all hole pairs, times the slot pitch.
fn slot_pitch_px(geometry: &OutletGeometry, pixels: &[Point2<f64>]) -> Option<f64> {
    let (mut sum, mut n) = (0.0, 0);
    for i in 0..pixels.len() {
        for j in i + 1..pixels.len() {
            let mm = (geometry.holes[i].position() - geometry.holes[j].position()).norm();
            let px = (pixels[i] - pixels[j]).norm();
            if mm > 1.0 && px.is_finite() {
                sum += px / mm;
                n += 1;
            }
        }
    }
    let ratio = sum / n.max(1) as f64;
    (n > 0 && ratio > 0.0).then_some(ratio * outlet_protocol::geometry::SLOT_PITCH_MM)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tilted_view_stretches_the_face_by_the_tilt_across_each_axis() {
        let head_on = Matrix2::new(0.8, -0.6, 0.6, 0.8);
        let views: Vec<Matrix2<f64>> = tilted_views(&head_on, &[2.0, 1.5]).collect();
        assert_eq!(views.len(), 6);
        for (v, t) in views.iter().zip([2.0, 2.0, 2.0, 1.5, 1.5, 1.5]) {
            let s = v.singular_values();
            assert!((s.max() - t).abs() < 1e-9 && (s.min() - 1.0).abs() < 1e-9, "{s:?} for tilt {t}");
        }
        // Three different axes, not one three times.
        assert!((views[0] - views[1]).norm() > 0.5 && (views[1] - views[2]).norm() > 0.5);
    }
}
