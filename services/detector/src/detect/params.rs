//! Parameters of every stage of the detector.

use super::FARTHEST_OUTLET_MM;
use crate::candidates::CandidateParams;
use crate::hashing::HashParams;
use crate::refine::RefineParams;
use crate::verify::VerifyParams;
use outlet_protocol::CameraModel;
use outlet_protocol::geometry::SLOT_PITCH_MM;

/// Parameters of every stage; `Default` is the paper's where it gives them.
#[derive(Debug, Clone)]
pub struct DetectorParams {
    pub candidates: CandidateParams,
    pub hash: HashParams,
    pub refine: RefineParams,
    pub verify: VerifyParams,
    /// Candidates classified at most (the most contrasted first).
    pub max_candidates: usize,
    /// From this image side (pixels) on, candidates need at least
    /// `large_image_min_contrast`: at 1280x960 and up no rendered hole is lost
    /// and half the clutter goes (measured in tests/candidates.rs).
    pub large_image_px: u32,
    pub large_image_min_contrast: f32,
    /// After refinement every kept hole must lie within this distance of one
    /// plane's homography through them, in pixels or in mm on the outlet (the
    /// larger): real outlets differ from nominal by a few tenths of a mm.
    pub max_plane_px: f64,
    pub max_plane_mm: f64,
    /// When nothing is found, look again with the candidates whose nearest hole
    /// sample is within this distance of their nearest background sample taken
    /// as holes (PCA distance; 0 = no second look).
    pub second_look_margin: f32,
    /// When the second look finds nothing either, a third: the candidates it
    /// still left in the background are classified again this many ladder
    /// steps either side of the scales their size implies, and count as holes
    /// by the same margin (0 = no third look). See
    /// [`crate::descriptor::OneWayDescriptor::classify_candidate_spread`].
    pub third_look_spread: u32,
    /// When the third look finds nothing either, a last one: a candidate classed
    /// as one hole class whose nearest sample of the other is within this
    /// distance of it counts as the other (a far ground hole is a round blur
    /// much like a far slot's). 0 = no such look. 0.1 (session 9): VGA
    /// approaches at 50 cm 32 -> 34 of 35, the V000 template on the Willow
    /// views 129 -> 136 of 279, no false alarm in 2300 negatives.
    pub swap_look_margin: f32,
    /// For outlets whose power holes map onto themselves under a half turn: how
    /// much darker (relative) the found ground holes must be than the places a
    /// half-turned outlet would put them.
    pub ground_contrast: f64,
    /// From this relative darkness on, the ground holes alone decide the half
    /// turn (on the Willow photographs and their views: 0.35 or more in nine of
    /// ten readings); the slot outlines then only veto
    /// ([`VerifyParams::max_identity_contradiction`]). 0.15 (0.2 until session
    /// 16): a 2x2 in a specular highlight 60 cm from a VGA camera shows its
    /// grounds 0.16 darker than the half-turned places (a face near 240 leaves
    /// little room), and its 9 px slots cannot tell neutral from hot. A
    /// half-turned reading puts its grounds on bare face, brighter than the real
    /// ones: its contrast is below zero, far from either bound.
    pub ground_decides: f64,
    /// When nothing is found in an image whose larger side is at least this
    /// (pixels), look again at half the resolution, and so on down the pyramid:
    /// the descriptor and the hashing know holes up to about 50 px of slot pitch,
    /// which an HD camera passes at 25 cm and a VGA one at 13 cm (0 = never).
    pub pyramid_min_px: u32,
    /// In an image whose larger side is at least this (pixels), look at half
    /// resolution first and at full resolution only when nothing is found there:
    /// an HD frame's holes are large enough at half size from 10 to 60 cm, and
    /// the half level costs a quarter (the outlet found is refined and verified
    /// at full resolution all the same). 0 = never.
    pub coarse_first_px: u32,
    /// After a coarse-first look found nothing, full resolution is looked at
    /// only if, with a camera, an outlet at the farthest working distance
    /// ([`FARTHEST_OUTLET_MM`]) could show a slot pitch under this many pixels
    /// at half resolution: holes that small are what the half level can miss
    /// and full resolution can see. Without a camera full resolution is always
    /// looked at. 0 = always.
    pub full_after_coarse_below_pitch_px: f64,
    /// A hole whose centre could not be fitted is taken from the homography of
    /// the fitted holes only when at least this many were fitted: four fix a
    /// homography exactly and check nothing. The predicted hole's outline must
    /// also show at the predicted place, but a large hole's outline shows even
    /// 1.7 mm off: with four, a 2x1 at 10 cm came out with two holes 18 px
    /// (135 px slot pitch) from the real ones (`outlet eval --approach`).
    pub min_fitted_for_prediction: usize,
    /// A hole taken from the homography is off by the real outlet's departure
    /// from the nominal geometry (mm, per axis): on the Willow photographs the
    /// labelled holes leave 0.48-0.60 mm RMS from the contract's geometry.
    pub predicted_sigma_mm: f64,
    /// When fewer holes than the hashing's minimum refine onto one plane from its
    /// homography, but at least this many do, the others are looked for once
    /// more where those put them (as faint holes are), and the outlet stands
    /// only if the hashing's minimum is then reached on one plane.
    pub min_holes_to_look_again: usize,
}

impl Default for DetectorParams {
    fn default() -> Self {
        Self {
            candidates: CandidateParams::high_recall(),
            hash: HashParams::default(),
            refine: RefineParams::default(),
            verify: VerifyParams::default(),
            max_candidates: 400,
            large_image_px: 1000,
            large_image_min_contrast: 1.3,
            max_plane_px: 1.2,
            max_plane_mm: 0.8,
            second_look_margin: 0.25,
            third_look_spread: 1,
            swap_look_margin: 0.1,
            ground_contrast: 0.05,
            ground_decides: 0.15,
            pyramid_min_px: 640,
            coarse_first_px: 1280,
            full_after_coarse_below_pitch_px: 12.0,
            min_fitted_for_prediction: 5,
            predicted_sigma_mm: 0.5,
            min_holes_to_look_again: 6,
        }
    }
}

impl DetectorParams {
    /// Whether full resolution is worth a look after the half level of a
    /// coarse-first image found nothing ([`Self::full_after_coarse_below_pitch_px`]).
    pub fn full_after_coarse(&self, camera: Option<&CameraModel>) -> bool {
        let below = self.full_after_coarse_below_pitch_px;
        match camera {
            Some(c) if below > 0.0 => {
                let f = (c.fx * c.fy).sqrt();
                let least_half_pitch = SLOT_PITCH_MM * f / FARTHEST_OUTLET_MM / 2.0;
                // A broken camera (NaN) looks again, as one without a camera.
                least_half_pitch.is_nan() || least_half_pitch < below
            }
            _ => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_resolution_follows_a_failed_half_level_only_where_a_far_outlet_could_be_too_small_there() {
        let params = DetectorParams::default();
        let camera = |f: f64| CameraModel::new(1600, 1200, [f, f, 800.0, 600.0], [0.0; 5]).expect("camera");
        // The Willow camera (f 1475 px): 13.4 px of slot pitch at 70 cm and half resolution.
        assert!(!params.full_after_coarse(Some(&camera(1475.0))));
        // A 1280x960 camera (f 1050 px): 9.5 px there, under the 10 px the half level needs.
        assert!(params.full_after_coarse(Some(&camera(1050.0))));
        assert!(params.full_after_coarse(None), "without a camera the outlet's size is unknown");
        let always = DetectorParams { full_after_coarse_below_pitch_px: 0.0, ..DetectorParams::default() };
        assert!(always.full_after_coarse(Some(&camera(1475.0))));
    }
}
