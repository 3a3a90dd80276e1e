//! Beyond the paper: a reported outlet is a verified outlet. After refinement
//! every hole must have been seen where the outlet's homography puts it (its
//! outline, of the predicted size and orientation, fitted there with contrast and
//! a small residual), and the outlines must tell which way round the outlet is:
//! the neutral slot is longer than the hot one (8.7 against 7.1 mm; a 5-20R's
//! neutral is a T, longer still). The ground holes, where the outlet has them,
//! must be darker than where a half turn would put them; where they are clearly
//! so they decide the half turn, a mirror image is never reported (the camera
//! sees the front), and the slots only veto a reading they clearly contradict.
//! Otherwise a reading whose slot outlines fit no better than the swapped ones
//! (neutral and hot exchanged) is refused: it would send the arm to the wrong
//! slot. A false outlet costs far more than a missed one.

use crate::refine::{HoleShape, RefineParams, Refined, compare_outlines};
use image::GrayImage;
use nalgebra::{Matrix2, Point2};

/// Parameters of the verification.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerifyParams {
    /// Each hole's outline must explain at least this share of the grey-level
    /// variance in its window (R^2 of the fit): an opening of the predicted
    /// shape, not a shadow edge or noise beside one.
    pub min_explained: f64,
    /// The outlet's slot outlines together must explain the pixels better than
    /// the swapped reading's by at least this fraction of their own residual (sum
    /// of squares over every slot): below it the evidence cannot tell the reading
    /// from its mirror or half turn, and no outlet is reported. Pooled over the
    /// slots because on real photos both slots may look short (blur, oblique
    /// views): each neutral then prefers the short outline, but less than each
    /// hot one does.
    pub min_identity_gain: f64,
    /// Where the ground holes decided the half turn, the slot outlines refuse
    /// the reading only if they fit the swapped one better by more than this
    /// fraction (on the Willow views, correct readings gave -0.18..0.13, a
    /// median of 0.044: slot lengths there are weak evidence either way).
    pub max_identity_contradiction: f64,
    /// A hole whose outline finds no opening of the refinement's contrast
    /// ([`RefineParams::min_relative_contrast`]) is looked for again at the
    /// homography's prediction with this much (relative to the face): a
    /// washed-out or shadowed hole exactly where the outlet puts it.
    pub faint_contrast: f64,
}

impl Default for VerifyParams {
    fn default() -> Self {
        Self { min_explained: 0.1, min_identity_gain: 0.02, max_identity_contradiction: 0.1, faint_contrast: 0.05 }
    }
}

/// One hole's evidence in 0..1: the share of its window's variance that its
/// outline explains, lowered by its offset from the homography's prediction
/// (0 at `tolerance_px`).
pub fn hole_score(fit: &Refined, offset_px: f64, tolerance_px: f64) -> f64 {
    let placed = 1.0 - (offset_px / tolerance_px.max(1e-9)).powi(2);
    (fit.explained * placed).clamp(0.0, 1.0)
}

/// The outline a hole would have in the swapped reading, with its mm to pixel
/// map: a slot of the other length (the outlet's other slot kind). `None` when
/// the template's slots are all alike (nothing to tell them apart by), and for
/// round holes: the ground hole's flat (0.9 mm deep) is not evidence that holds
/// on real photographs, whose ground holes shine or have dark dots beside them
/// (on the Willow photo the flat read the wrong way on 5 of 8 holes, by up to
/// 38% of the residual). The ground holes' places still decide a half turn
/// (`Detector`'s ground check).
pub fn swapped_outline(
    shape: HoleShape,
    outlines: &[HoleShape],
    mm_to_px: &Matrix2<f64>,
) -> Option<(HoleShape, Matrix2<f64>)> {
    match shape {
        HoleShape::Round { .. } => None,
        HoleShape::Slot { length_mm, .. } => outlines
            .iter()
            .find(|o| matches!(o, HoleShape::Slot { length_mm: l, .. } if (l - length_mm).abs() > 0.5))
            .map(|o| (*o, *mm_to_px)),
    }
}

/// The outlet's identity evidence: (SSE of the swapped outlines - SSE of its own)
/// over SSE of its own, summed over the holes (`(centre, mm_to_px, outline)`).
/// `None` when no hole could be compared.
pub fn identity_gain(
    grey: &GrayImage,
    holes: &[(Point2<f64>, Matrix2<f64>, HoleShape)],
    outlines: &[HoleShape],
    params: &RefineParams,
) -> Option<f64> {
    let (mut gain, mut own) = (0.0, 0.0);
    for (centre, mm_to_px, shape) in holes {
        let Some(other) = swapped_outline(*shape, outlines, mm_to_px) else { continue };
        if let Some([g, o]) = compare_outlines(grey, *centre, mm_to_px, *shape, other, params) {
            gain += g;
            own += o;
        }
    }
    (own > 0.0).then(|| gain / own)
}

#[cfg(test)]
mod tests {
    use super::*;

    const NEUTRAL: HoleShape = HoleShape::Slot { width_mm: 2.0, length_mm: 8.7 };
    const HOT: HoleShape = HoleShape::Slot { width_mm: 2.0, length_mm: 7.1 };
    const GROUND: HoleShape = HoleShape::Round { diameter_mm: 5.0, flat_mm: 1.6 };

    /// A bright face with a dark slot 2 mm wide and `length_mm` long at (30, 30),
    /// 2 px per mm, anti-aliased by 4x4 supersampling.
    fn slot_image(length_mm: f64) -> GrayImage {
        GrayImage::from_fn(60, 60, |x, y| {
            let mut dark = 0.0;
            for k in 0..16 {
                let u = (x as f64 + (k % 4) as f64 / 4.0 - 0.375 - 30.0) / 2.0;
                let v = (y as f64 + (k / 4) as f64 / 4.0 - 0.375 - 30.0) / 2.0;
                if u.abs() <= 1.0 && v.abs() <= length_mm / 2.0 {
                    dark += 1.0 / 16.0;
                }
            }
            image::Luma([(200.0 - 170.0 * dark) as u8])
        })
    }

    #[test]
    fn a_slot_is_told_long_or_short_by_its_outline() {
        let map = Matrix2::identity() * 2.0;
        let outlines = [NEUTRAL, HOT, GROUND];
        let params = RefineParams::default();
        let centre = Point2::new(30.0, 30.0);
        let long = slot_image(8.7);
        let short = slot_image(7.1);
        let gain = |image: &GrayImage, shape| identity_gain(image, &[(centre, map, shape)], &outlines, &params);
        let (right_long, wrong_long) = (gain(&long, NEUTRAL).expect("fit"), gain(&long, HOT).expect("fit"));
        let (right_short, wrong_short) = (gain(&short, HOT).expect("fit"), gain(&short, NEUTRAL).expect("fit"));
        assert!(right_long > 0.05 && wrong_long < 0.0, "long slot: {right_long:.3} / {wrong_long:.3}");
        assert!(right_short > 0.05 && wrong_short < 0.0, "short slot: {right_short:.3} / {wrong_short:.3}");
    }

    #[test]
    fn only_slots_of_two_lengths_have_a_swapped_outline() {
        let map = Matrix2::identity();
        assert_eq!(swapped_outline(NEUTRAL, &[NEUTRAL, HOT, GROUND], &map).map(|o| o.0), Some(HOT));
        assert_eq!(swapped_outline(HOT, &[NEUTRAL, HOT, GROUND], &map).map(|o| o.0), Some(NEUTRAL));
        assert_eq!(swapped_outline(GROUND, &[NEUTRAL, HOT, GROUND], &map), None);
        assert_eq!(swapped_outline(HOT, &[HOT, HOT, GROUND], &map), None);
    }

    #[test]
    fn a_hole_scores_its_explained_share_less_its_offset() {
        let fit = Refined {
            centre: Point2::origin(),
            rms: 1.0,
            contrast: 100.0,
            sigma_px: 0.1,
            explained: 0.8,
            pixels: 100,
            total_ss: 1e4,
            edge_px: 0.0,
            shape: nalgebra::Matrix2::identity(),
        };
        assert!((hole_score(&fit, 0.0, 1.2) - 0.8).abs() < 1e-12);
        assert!((hole_score(&fit, 0.6, 1.2) - 0.6).abs() < 1e-12);
        assert_eq!(hole_score(&fit, 1.2, 1.2), 0.0);
        assert_eq!(hole_score(&fit, 5.0, 1.2), 0.0);
    }
}
