//! The parameters of geometric hashing and the minimum score they imply.

use super::fit::Intrinsics;

/// Parameters of geometric hashing (paper, section III.C; values of the original
/// code, `ORIGINAL.md`, where the paper has none). Figures quoted are from
/// `tests/hashing.rs`.
#[derive(Debug, Clone, PartialEq)]
pub struct HashParams {
    /// Bins per axis of the affine-coordinate grid (original: 30).
    pub bins: usize,
    /// The grid covers affine coordinates in [-range, range]^2; holes outside do
    /// not vote (original: 5).
    pub range: f64,
    /// Each template hole is filed in every bin within this many bins of its
    /// affine coordinates: 0.5 is the 2x2 block nearest to it, so a candidate half
    /// a bin (0.17) off still votes despite noise and perspective. A 3x3 block
    /// found no more outlets and cost twice the votes. Votes only choose what to
    /// score.
    pub vote_tolerance: f64,
    /// A model basis's angle must be at least this far from 0 and pi, radians
    /// (original: 0.5).
    pub min_basis_angle: f64,
    /// An online basis's angle must be at least this far from 0 and pi, radians.
    /// Smaller than the model's: a view 60 degrees off-axis squeezes 0.5 rad to
    /// about 0.26.
    pub min_online_angle: f64,
    /// Online bases are each candidate with every pair of its this many nearest
    /// neighbours of compatible size (the paper draws random pairs "in the
    /// proximity", up to 10 tries). 4 (6 pairs) found as many outlets among 150
    /// candidates as 6 (15 pairs), at a third of the time for `2x2`.
    pub neighbours: usize,
    /// Votes a model basis needs to be scored. `None`: min score - 4, at least 1
    /// (the three basis holes count, and one further hole may miss its bin): 1
    /// for `2x1`, so 4 of 6 holes are enough, and 4 for `2x2`. Original: 3.
    pub min_votes: Option<usize>,
    /// MaxDist of equation (2) as a fraction of the hole's predicted apparent size
    /// (`hole_size` times the transform's local scale), to reach holes that an
    /// affine first guess misplaces under perspective. The paper's fixed 5 px held
    /// for one camera distance; 0.6 x 7 mm = 4.2 mm is a third of the 12.7 mm slot
    /// pitch, so neighbouring holes never compete.
    pub max_dist_ratio: f64,
    /// MaxDist is never below this (pixels): position noise of tiny holes.
    pub min_max_dist_px: f64,
    /// Apparent size of a template hole, template units (mm): what `sizes`
    /// measures on the image, over the scale. 7 mm: the larger side of a hole's
    /// bounding box is 7.1-8.7 mm for the slots, 5 mm for the ground hole.
    pub hole_size: f64,
    /// A candidate's size may differ from the predicted hole size by this factor
    /// either way: slots and ground holes, foreshortening up to 60 degrees, and
    /// components cut at different threshold levels. Also bounds each candidate's
    /// neighbourhood: the outlet's extent at the largest scale its size allows.
    pub size_tolerance: f64,
    /// The minimum score S is this fraction of the template's holes, rounded up:
    /// 2/3 gives the paper's 4 of 6 for `2x1` and 8 of 12 for `2x2`. 8 is also two
    /// more than one duplex column (6 holes) can give, so a `2x1` outlet, or half
    /// a `2x2`, is never taken for a `2x2`.
    pub min_score_fraction: f64,
    /// The minimum score is never below this, nor below 4 (three holes fix the
    /// affine transform; at least one more must confirm it).
    pub min_score_floor: usize,
    /// Smallest ratio of the transform's singular values at any hole: cos of the
    /// largest off-axis angle, 0.5 = 60 degrees (the paper's views are within
    /// 40; a chance 5-of-6 among clutter was at 0.46). With a camera
    /// ([`Self::intrinsics`]) the ratio is taken along the ray to the hole
    /// (`view_axis_ratio`), so that the angle is the face's to the ray wherever
    /// the outlet lies in the image (session 12). Measured lower on the
    /// Willow photographs (BENCHMARKS.md): at 0.38 (68 degrees, with
    /// [`Self::oblique_axis_ratio`]) all nine photographs and 188 of 279 views
    /// were found against 129, but one steep, blurred view had a hole 5 px (10
    /// sigma) off: not the default until steep views refine better.
    pub min_axis_ratio: f64,
    /// [`Self::min_axis_ratio`] holds at the outlet's centre; each hole may be
    /// this much below it. Seen close and steeply, the ray to the far holes is
    /// a few degrees steeper than to the centre (a 2x2 at 50 cm and 59 degrees
    /// has holes at 62): with the limit at every hole, such views were refused
    /// although the view is within it. 0.05 (the far holes to about 63
    /// degrees): 5 and 2 more Willow views found (of 279 and 369), none wrong;
    /// Table I, 2000 negatives and the approaches unchanged (session 12).
    pub hole_axis_slack: f64,
    /// Views more oblique than this (axis ratio; 0.5 = 60 degrees) need
    /// [`Self::oblique_extra_holes`] matched holes more than [`Self::min_score`].
    pub oblique_axis_ratio: f64,
    /// 2: 6 of 6, 10 of 12. Points alone (no image) gave a chance 5-of-6 with two
    /// clutter points between 60 and 68 degrees, where 4 of 6 and 5 of 6 are
    /// shapes a steep enough affine map can make of clutter.
    pub oblique_extra_holes: usize,
    /// Local scales (sqrt of the Jacobian's determinant, pixels per template unit)
    /// an outlet may have, when the caller knows them: focal length over the
    /// working distances, e.g. 525 px / (200..500 mm) = 1.05..2.6 px/mm for the
    /// paper's 20-50 cm, with a margin. `None`: any scale.
    pub scale_range: Option<[f64; 2]>,
    /// Image width and height (pixels), when known: every hole must be predicted
    /// inside the image (an outlet partly out of view cannot be checked), and
    /// clutter density is measured in the image only. `None`: no such checks.
    pub image_size: Option<[f64; 2]>,
    /// The camera of the (undistorted) candidate pixels, when known: a
    /// hypothesis of 4 to `min_homography_matches - 1` matches is then fitted
    /// as a rigid plate's pose ([`Intrinsics`]: six unknowns, as the affine map
    /// it replaces, but with the perspective of a close, oblique view: at 10 cm
    /// and 38 degrees the affine fit missed holes by half their size). `None`:
    /// affine.
    pub intrinsics: Option<Intrinsics>,
    /// Largest ratio of the local scales (sqrt of the Jacobian's determinant) of
    /// two holes: the perspective allowed. A 2x2 outlet at 20 cm seen 60 degrees
    /// off-axis gives 1.65; 40 degrees 1.46.
    pub max_scale_variation: f64,
    /// Each match must be predicted by a least-squares fit to the other matches
    /// within this fraction of its predicted size (leave-one-out); the worst
    /// offender is dropped until all are. 0.3 dropped true holes of outlets 40
    /// degrees off-axis (an affine fit of 5 holes misses the perspective).
    pub max_loo_ratio: f64,
    /// A match closer than this to its leave-one-out prediction counts as this
    /// close (pixels): candidate centres are no more precise.
    pub position_precision_px: f64,
    /// Largest number of false alarms (NFA, a-contrario as in Moisan and Stival's
    /// AC-RANSAC): the expected number of hypotheses as good as the reported one
    /// if the candidates it does not use were uniform clutter of their density
    /// around it, over all hypotheses tried. Three matches are free (they fix the
    /// transform); each further one counts with the probability that clutter falls
    /// within its leave-one-out error. Measured on `2x1` (0.5 px noise; clutter of
    /// random power/ground class, 4-20 px, anywhere in 640x480):
    ///
    /// | max_nfa | 4 of 6 holes alone found | false alarms, 30-150 clutter candidates |
    /// |---|---|---|
    /// | 1e-3 | 89 / 140 | 1 / 500 |
    /// | 1e-2 | 140 / 140 | 2 / 500 (at 150 candidates 8 / 2000, at 80 1 / 2000) |
    /// | 1e-1 | 140 / 140 | 11 / 500 |
    ///
    /// `2x2` at 1e-2: 0 / 500 (3 / 2000 at 150 candidates).
    pub max_nfa: f64,
    /// Refits of a hypothesis, each followed by a re-score.
    pub refine_iterations: usize,
    /// Matches needed to fit a homography (8 unknowns); fewer get a least-squares
    /// affine fit (6 unknowns). 6 leaves 4 redundant equations; a homography
    /// through 5 points bends to fit almost any fifth, and its extrapolation to
    /// missing holes was off by up to 4.5 px.
    pub min_homography_matches: usize,
    /// Another verified interpretation of the candidates (sharing fewer than 3
    /// hole-candidate pairs with the best: another place, or the best's own
    /// candidates relabelled, e.g. turned 180 degrees) must score at least this
    /// much lower, or the answer is "none". Relabellings of the best's own
    /// candidates need only score lower: the best explains more of the same.
    pub rival_margin: usize,
}

impl Default for HashParams {
    fn default() -> Self {
        Self {
            bins: 30,
            range: 5.0,
            vote_tolerance: 0.5,
            min_basis_angle: 0.5,
            min_online_angle: 0.25,
            neighbours: 4,
            min_votes: None,
            max_dist_ratio: 0.6,
            min_max_dist_px: 1.5,
            hole_size: 7.0,
            size_tolerance: 2.5,
            min_score_fraction: 2.0 / 3.0,
            min_score_floor: 4,
            min_axis_ratio: 0.5,
            hole_axis_slack: 0.05,
            oblique_axis_ratio: 0.5,
            oblique_extra_holes: 2,
            scale_range: None,
            image_size: None,
            intrinsics: None,
            max_scale_variation: 2.0,
            max_loo_ratio: 0.4,
            position_precision_px: 0.5,
            max_nfa: 1e-2,
            refine_iterations: 3,
            min_homography_matches: 6,
            rival_margin: 1,
        }
    }
}

impl HashParams {
    /// Minimum score S for a template of `holes` holes (never below 4).
    pub fn min_score(&self, holes: usize) -> usize {
        let by_fraction = (self.min_score_fraction * holes as f64 - 1e-9).ceil();
        let by_fraction = if by_fraction.is_finite() && by_fraction > 0.0 { by_fraction as usize } else { 0 };
        by_fraction.max(self.min_score_floor).max(4)
    }

    /// Votes a model basis needs for a template of `holes` holes.
    pub fn min_votes(&self, holes: usize) -> usize {
        self.min_votes.unwrap_or_else(|| self.min_score(holes).saturating_sub(4)).max(1)
    }
}
