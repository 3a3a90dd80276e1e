//! The detector: the paper's stages in order (`candidates` → `classify` → `hash`)
//! and what goes beyond it (`refine`: sub-pixel holes, and a final check that the
//! refined holes lie where one outlet plane puts them).

use crate::candidates::{CandidateParams, find_candidates};
use crate::hashing::{HashParams, HashTable, Intrinsics, find_outlet};
use crate::refine::{HoleShape, RefineParams, Refined, outline_at, refine_hole};
use crate::template::Template;
use crate::verify::{VerifyParams, hole_score, identity_gain};
use crate::{Candidate, Class, grey_of};
use image::{GrayImage, RgbImage};
use nalgebra::{Matrix2, Matrix3, Point2, Vector2};
use outlet_protocol::geometry::SLOT_PITCH_MM;
use outlet_protocol::{CameraModel, HoleKind};
use std::time::Instant;

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

/// One hole of a found outlet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectedHole {
    pub kind: HoleKind,
    /// In the image as captured (distorted), OpenCV convention.
    pub pixel: Point2<f64>,
    /// Whether the sub-pixel fit placed this hole's centre. False where the fit
    /// could not (a faint or crowded hole), but the hole's outline was seen right
    /// where the other holes' homography puts it, which gives the centre; a hole
    /// not seen at all refuses the outlet ([`crate::verify`]).
    pub refined: bool,
    /// Evidence in 0..1 that the hole was seen where the outlet's homography puts
    /// it, with the predicted outline ([`crate::verify::hole_score`]).
    pub score: f64,
    /// Standard deviation of `pixel` per axis (pixels), from the outline fit's
    /// residuals ([`crate::refine::Refined::sigma_px`]).
    pub sigma_px: f64,
    /// How `sigma_px`'s variance divides among the image axes (trace 2,
    /// [`crate::refine::Refined::shape`]): the covariance of `pixel` is
    /// [`Self::covariance_px`].
    pub shape: Matrix2<f64>,
}

impl DetectedHole {
    /// The covariance of `pixel` (pixels²).
    pub fn covariance_px(&self) -> Matrix2<f64> {
        self.shape * self.sigma_px.powi(2)
    }
}

/// A found outlet.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Every hole of the template, in template order.
    pub holes: Vec<DetectedHole>,
    /// Template holes matched by a same-class candidate (the paper's score S).
    pub score: usize,
    /// Template (mm) to undistorted image (px) homography of the refined holes.
    pub homography: Matrix3<f64>,
}

impl Detection {
    /// The same outlet in an image whose origin lies `shift` pixels up and left
    /// of this one's (a crop's outlet in its frame).
    fn translate(&mut self, shift: Vector2<f64>) {
        for hole in &mut self.holes {
            hole.pixel += shift;
        }
        self.homography = translation(shift) * self.homography;
    }
}

/// The homography that moves pixels by `shift`.
fn translation(shift: Vector2<f64>) -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, shift.x, 0.0, 1.0, shift.y, 0.0, 0.0, 1.0)
}

/// The camera of `crop`, cut at `origin` from a frame of `camera`. Cropping
/// moves the principal point only: distortion is a function of the normalised
/// ray, which cropping does not change.
fn crop_camera(camera: Option<&CameraModel>, crop: &GrayImage, origin: [u32; 2]) -> Option<CameraModel> {
    let (width, height) = crop.dimensions();
    camera.map(|c| CameraModel { width, height, cx: c.cx - origin[0] as f64, cy: c.cy - origin[1] as f64, ..*c })
}

/// Milliseconds per stage.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    pub candidates: f64,
    pub classify: f64,
    pub hash: f64,
    pub refine: f64,
}

impl std::ops::AddAssign for StageTimes {
    fn add_assign(&mut self, other: Self) {
        self.candidates += other.candidates;
        self.classify += other.classify;
        self.hash += other.hash;
        self.refine += other.refine;
    }
}

impl StageTimes {
    pub fn total(&self) -> f64 {
        self.candidates + self.classify + self.hash + self.refine
    }
}

/// What one image gave: the outlet or none, and what led there.
#[derive(Debug, Clone)]
pub struct DetectReport {
    pub detection: Option<Detection>,
    /// Every candidate with its class.
    pub candidates: Vec<(Candidate, Class)>,
    pub times: StageTimes,
    /// Why an outlet that geometric hashing found was not reported (a hole not
    /// seen, off the plane, the ground holes or the outlines against its
    /// reading); `None` when one was reported or hashing found none.
    pub rejected: Option<String>,
}

/// What a pyramid level says: its outlet (in the full image's pixels), or why
/// not (the reason a found outlet was refused, if any).
type LevelOutcome = Result<Detection, Option<String>>;

/// A reading hashing found and verification refused: the template to
/// undistorted image homography and each hole's candidate centre (as captured).
struct Hypothesis {
    transform: Matrix3<f64>,
    guesses: Vec<Option<Point2<f64>>>,
    score: usize,
    /// Why verification refused it.
    why: String,
}

/// A template ready to detect with.
#[derive(Debug, Clone)]
pub struct Detector {
    template: Template,
    table: HashTable,
    outlines: Vec<HoleShape>,
    params: DetectorParams,
}

/// The farthest outlet the detector looks for when it knows the camera (mm):
/// the hashing's smallest scale, and what the half level of a large image must
/// resolve. The robot parks 20-50 cm from the wall.
pub const FARTHEST_OUTLET_MM: f64 = 700.0;

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl Detector {
    pub fn new(template: Template, params: DetectorParams) -> Self {
        let points: Vec<Point2<f64>> = template.geometry.holes.iter().map(|h| h.position()).collect();
        let classes: Vec<Class> = template.geometry.holes.iter().map(|h| Class::from(h.kind)).collect();
        let table = HashTable::new(&points, &classes, &params.hash);
        let outlines = HoleShape::us_outlines(&template.geometry);
        Self { template, table, outlines, params }
    }

    pub fn template(&self) -> &Template {
        &self.template
    }

    pub fn params(&self) -> &DetectorParams {
        &self.params
    }

    /// Finds the template's outlet in an image, or reports none. With a camera,
    /// geometry works on undistorted coordinates; pixels are reported as captured.
    pub fn detect(&self, image: &RgbImage, camera: Option<&CameraModel>) -> DetectReport {
        let grey = grey_of(image);
        self.detect_grey(&grey, camera)
    }

    pub fn detect_grey(&self, grey: &GrayImage, camera: Option<&CameraModel>) -> DetectReport {
        self.detect_sized(grey, camera, grey.width().max(grey.height()))
    }

    /// Looks for the outlet in `window` (`[x, y, width, height]` pixels, clipped
    /// to the image) only, as [`Self::detect_grey`] would in the whole image: the
    /// same stages and the same verification, with the choices that depend on
    /// the image's size (the pyramid, the contrast of large images) made for the
    /// whole image. Pixels, homography and candidates are in the whole image's
    /// coordinates. Tracking ([`crate::track`]) looks where the outlet was.
    pub fn detect_window(&self, grey: &GrayImage, camera: Option<&CameraModel>, window: [u32; 4]) -> DetectReport {
        let (w, h) = grey.dimensions();
        let [x, y] = [window[0].min(w), window[1].min(h)];
        let [cw, ch] = [window[2].min(w - x), window[3].min(h - y)];
        if cw == 0 || ch == 0 {
            return DetectReport {
                detection: None,
                candidates: Vec::new(),
                times: StageTimes::default(),
                rejected: Some("the search window is empty".into()),
            };
        }
        let crop = image::imageops::crop_imm(grey, x, y, cw, ch).to_image();
        self.detect_crop(&crop, [x, y], [w, h], camera)
    }

    /// [`Self::detect_window`] on the window's pixels alone: `crop` is the part
    /// of a `frame_size` frame whose top left pixel is `origin`. A caller that
    /// converts frames to grey itself converts only the window (tracking).
    pub fn detect_crop(
        &self,
        crop: &GrayImage,
        origin: [u32; 2],
        frame_size: [u32; 2],
        camera: Option<&CameraModel>,
    ) -> DetectReport {
        let camera = crop_camera(camera, crop, origin);
        let mut report = self.detect_sized(crop, camera.as_ref(), frame_size[0].max(frame_size[1]));
        let shift = Vector2::new(origin[0] as f64, origin[1] as f64);
        if let Some(d) = report.detection.as_mut() {
            d.translate(shift);
        }
        for (c, _) in &mut report.candidates {
            c.centre += shift;
        }
        report
    }

    /// Verifies the outlet where `homography` (template mm to the frame's
    /// undistorted pixels) puts it, each hole's fit starting from `guesses`
    /// (the frame's pixels as captured, template order): the refinement and
    /// every check of a detection ([`Self::refine`]: each hole seen on one
    /// plane, not mirrored, the ground holes and the outlines for its reading),
    /// without candidates or hashing. Tracking ([`crate::track`]) gives the last
    /// frame's outlet. `crop` is the part of a `frame_size` frame at `origin`,
    /// as in [`Self::detect_crop`]; pixels and homography come back in the
    /// frame's coordinates, `score` is carried into the detection. A hole found
    /// farther than `max_move_px` from its guess refuses the outlet: the
    /// outlet moved more than a follow should take on trust.
    #[allow(clippy::too_many_arguments)] // a crop's place and the outlet to verify there
    pub fn verify_at(
        &self,
        crop: &GrayImage,
        origin: [u32; 2],
        camera: Option<&CameraModel>,
        homography: &Matrix3<f64>,
        guesses: &[Point2<f64>],
        score: usize,
        max_move_px: f64,
    ) -> DetectReport {
        let t = Instant::now();
        let shift = Vector2::new(origin[0] as f64, origin[1] as f64);
        let camera = crop_camera(camera, crop, origin);
        let to_crop = translation(-shift);
        let shifted: Vec<Option<Point2<f64>>> = guesses.iter().map(|g| Some(g - shift)).collect();
        let lens = Lens { camera: camera.as_ref() };
        let result = if guesses.len() != self.template.geometry.holes.len() {
            Err(format!(
                "{} hole guesses for a template of {} holes",
                guesses.len(),
                self.template.geometry.holes.len()
            ))
        } else {
            self.refine(crop, &lens, &(to_crop * homography), &shifted, score).and_then(|mut d| {
                d.translate(shift);
                for (hole, guess) in d.holes.iter().zip(guesses) {
                    let moved = (hole.pixel - guess).norm();
                    if moved.is_nan() || moved > max_move_px {
                        return Err(format!("a hole moved {moved:.1} px, more than {max_move_px:.1} px"));
                    }
                }
                Ok(d)
            })
        };
        let times = StageTimes { refine: ms_since(t), ..StageTimes::default() };
        match result {
            Ok(d) => DetectReport { detection: Some(d), candidates: Vec::new(), times, rejected: None },
            Err(why) => {
                tracing::debug!(reason = %why, "the followed outlet is not verified");
                DetectReport { detection: None, candidates: Vec::new(), times, rejected: Some(why) }
            }
        }
    }

    /// [`Self::detect_grey`], with the size-dependent choices made for an image
    /// whose larger side is `largest` (this one, or the frame it was cut from).
    fn detect_sized(&self, grey: &GrayImage, camera: Option<&CameraModel>, largest: u32) -> DetectReport {
        self.detect_level(grey, camera, largest, &mut Vec::new())
    }

    /// [`Self::detect_sized`], also giving the hypotheses that hashing found in
    /// this image and its verification here refused (`refused`).
    fn detect_level(
        &self,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        largest: u32,
        refused: &mut Vec<Hypothesis>,
    ) -> DetectReport {
        let mut times = StageTimes::default();
        let coarse_first = self.params.coarse_first_px > 0 && largest >= self.params.coarse_first_px;
        if coarse_first && let Some((half, candidates)) = self.at_half_resolution(grey, camera, largest, &mut times) {
            match half {
                Ok(found) => return DetectReport { detection: Some(found), candidates, times, rejected: None },
                Err(rejected) if !self.params.full_after_coarse(camera) => {
                    return DetectReport { detection: None, candidates, times, rejected };
                }
                Err(_) => {}
            }
        }
        let t = Instant::now();
        let _span = tracing::debug_span!("detect", width = grey.width(), height = grey.height()).entered();
        let mut params = self.params.candidates.clone();
        if largest >= self.params.large_image_px {
            // Larger images resolve holes well; texture (carpet, paint) brings
            // hundreds of faint blobs that a looser contrast would let in.
            params.min_contrast = params.min_contrast.max(self.params.large_image_min_contrast);
        }
        let mut candidates = find_candidates(grey, &params);
        candidates.sort_by(|a, b| b.contrast.total_cmp(&a.contrast));
        candidates.truncate(self.params.max_candidates);
        times.candidates = ms_since(t);

        let t = Instant::now();
        let classifications: Vec<_> =
            candidates.iter().map(|c| self.template.descriptor.classify_candidate(grey, c)).collect();
        let classified: Vec<(Candidate, Class)> =
            candidates.iter().zip(&classifications).map(|(c, k)| (*c, k.class)).collect();
        times.classify = ms_since(t);

        // What the image and the camera tell the hashing: the frame's size, and
        // with a camera the scales an outlet 5-70 cm away can have (sqrt of the
        // Jacobian's determinant; down to the most foreshortening hashing allows):
        // an arm's camera sees the outlet to the last centimetres (issue 21).
        let mut hash = self.params.hash.clone();
        hash.image_size = Some([grey.width() as f64, grey.height() as f64]);
        if let Some(c) = camera {
            let f = (c.fx * c.fy).sqrt();
            hash.scale_range = Some([f / FARTHEST_OUTLET_MM * hash.min_axis_ratio.clamp(0.0, 1.0).sqrt(), f / 50.0]);
            hash.intrinsics = Some(Intrinsics { fx: c.fx, fy: c.fy, cx: c.cx, cy: c.cy });
        }
        let lens = Lens { camera };
        let (mut detection, mut rejected) = self.search(grey, &lens, &classified, &hash, &mut times, refused);
        if detection.is_none() && self.params.second_look_margin > 0.0 {
            // A second look: candidates the descriptor put only narrowly in the
            // background (shadowed or washed-out holes) count as their nearer hole
            // class. Hashing, its significance test and the plane check still
            // stand between them and a false alarm.
            let margin = self.params.second_look_margin;
            let relax = |k: &crate::descriptor::Classification| {
                let [p, g, b] = k.class_distances;
                match k.class {
                    Class::Background if p.min(g) < b + margin => {
                        if p <= g {
                            Class::Power
                        } else {
                            Class::Ground
                        }
                    }
                    other => other,
                }
            };
            let relaxed: Vec<(Candidate, Class)> =
                candidates.iter().zip(&classifications).map(|(c, k)| (*c, relax(k))).collect();
            if relaxed.iter().zip(&classified).any(|(a, b)| a.1 != b.1) {
                let (second, why) = self.search(grey, &lens, &relaxed, &hash, &mut times, refused);
                detection = second;
                rejected = why.or(rejected);
            }
            let spread = self.params.third_look_spread;
            if detection.is_none() && spread > 0 {
                // A third look, only after the first two found nothing (what
                // they find stays as it was): the candidates still background
                // at the scale their size implies, looked at a step either side.
                let t = Instant::now();
                let third: Vec<(Candidate, Class)> = relaxed
                    .iter()
                    .map(|&(c, class)| match class {
                        Class::Background => {
                            (c, relax(&self.template.descriptor.classify_candidate_spread(grey, &c, spread)))
                        }
                        class => (c, class),
                    })
                    .collect();
                times.classify += ms_since(t);
                if third.iter().zip(&relaxed).any(|(a, b)| a.1 != b.1) {
                    let (found, why) = self.search(grey, &lens, &third, &hash, &mut times, refused);
                    detection = found;
                    rejected = why.or(rejected);
                }
            }
            let swap = self.params.swap_look_margin;
            if detection.is_none() && swap > 0.0 {
                // Where the descriptor nearly could not tell the hole classes
                // apart, the candidate also counts as the other class (a copy at
                // the same place: one place can match only one hole).
                let mut swapped = relaxed.clone();
                for (&(c, class), k) in relaxed.iter().zip(&classifications) {
                    let [p, g, _] = k.class_distances;
                    match class {
                        Class::Power if g < p + swap => swapped.push((c, Class::Ground)),
                        Class::Ground if p < g + swap => swapped.push((c, Class::Power)),
                        _ => {}
                    }
                }
                if swapped.len() > relaxed.len() {
                    let (found, why) = self.search(grey, &lens, &swapped, &hash, &mut times, refused);
                    detection = found;
                    rejected = why.or(rejected);
                }
            }
        }
        // (Coarse first: the levels below were looked at already.)
        if detection.is_none()
            && !coarse_first
            && self.params.pyramid_min_px > 0
            && largest >= self.params.pyramid_min_px
            && let Some((half, _)) = self.at_half_resolution(grey, camera, largest, &mut times)
        {
            match half {
                Ok(found) => detection = Some(found),
                Err(why) => rejected = why.or(rejected),
            }
        }
        if detection.is_some() {
            rejected = None;
        }
        DetectReport { detection, candidates: classified, times, rejected }
    }

    /// The outlet found in the image at half resolution (each level of a pyramid
    /// in turn, while nothing is found), in this image's pixels; `Err` with why
    /// not. None when the half image or its camera cannot be made.
    fn at_half_resolution(
        &self,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        largest: u32,
        times: &mut StageTimes,
    ) -> Option<(LevelOutcome, Vec<(Candidate, Class)>)> {
        let half = half_resolution(grey)?;
        let half_camera = match camera {
            Some(c) => Some(half_camera(c, half.width(), half.height())?),
            None => None,
        };
        let mut refused = Vec::new();
        let report = self.detect_level(&half, half_camera.as_ref(), largest / 2, &mut refused);
        *times += report.times;
        // OpenCV pixel centres: full = 2 half + 0.5, in the image as captured
        // and in undistorted pixels alike (the camera is scaled the same way).
        let up = Matrix3::new(2.0, 0.0, 0.5, 0.0, 2.0, 0.5, 0.0, 0.0, 1.0);
        let to_full = |p: Point2<f64>| Point2::new(2.0 * p.x + 0.5, 2.0 * p.y + 0.5);
        // The level's candidates in this image's pixels.
        let candidates = report
            .candidates
            .iter()
            .map(|(c, class)| {
                let centre = to_full(c.centre);
                let size = [c.size[0].saturating_mul(2), c.size[1].saturating_mul(2)];
                (Candidate { centre, size, area: c.area.saturating_mul(4), ..*c }, *class)
            })
            .collect();
        let outcome = match report.detection {
            Some(mut d) => {
                for h in &mut d.holes {
                    h.pixel = to_full(h.pixel);
                    h.sigma_px *= 2.0;
                }
                d.homography = up * d.homography;
                // Found at half resolution, refined and verified again at full
                // resolution: the half level's centres carry twice its pixel
                // error (on the Willow views, 4-6 px where full resolution gives
                // 1-2). Where the full level refuses, so does the detector: the
                // half level's outlet once stood in its place, and on a Willow
                // view it held a hole predicted 6.8 px (2 mm) from the real one
                // that full resolution had found to lie elsewhere; without it the
                // approaches and the Willow views lost no other find.
                let t = Instant::now();
                let guesses: Vec<Option<Point2<f64>>> = d.holes.iter().map(|h| Some(h.pixel)).collect();
                let full = self.refine(grey, &Lens { camera }, &d.homography, &guesses, d.score);
                times.refine += ms_since(t);
                full.map_err(|why| {
                    tracing::debug!(reason = %why, "half-resolution outlet refused at full resolution");
                    Some(format!("found at half resolution, refused at full resolution: {why}"))
                })
            }
            // What hashing found here but the half level's verification refused
            // (most often a faint hole: a real ground hole of a few pixels at
            // half size) is verified again at full resolution, where the
            // hole's outline has four times the pixels; the full level's
            // verification decides, as for any outlet.
            None => {
                let t = Instant::now();
                let lens = Lens { camera };
                let mut outcome = Err(report.rejected);
                for h in &refused {
                    let guesses: Vec<Option<Point2<f64>>> = h.guesses.iter().map(|g| g.map(to_full)).collect();
                    match self.refine_either(grey, &lens, &(up * h.transform), &guesses, h.score) {
                        Ok(found) => {
                            tracing::debug!("refused at half resolution, verified at full resolution");
                            outcome = Ok(found);
                            break;
                        }
                        Err(why) => tracing::debug!(reason = %why, "refused at half and at full resolution"),
                    }
                }
                times.refine += ms_since(t);
                outcome
            }
        };
        Some((outcome, candidates))
    }

    /// Hashing over the hole-classed candidates, then refinement and
    /// verification: the outlet, or why the one hashing found was refused.
    fn search(
        &self,
        grey: &GrayImage,
        lens: &Lens,
        classified: &[(Candidate, Class)],
        hash: &HashParams,
        times: &mut StageTimes,
        refused: &mut Vec<Hypothesis>,
    ) -> (Option<Detection>, Option<String>) {
        let t = Instant::now();
        let holes: Vec<&(Candidate, Class)> =
            classified.iter().filter(|(_, class)| *class != Class::Background).collect();
        let points: Vec<Point2<f64>> = holes.iter().map(|(c, _)| lens.undistort(c.centre)).collect();
        let classes: Vec<Class> = holes.iter().map(|(_, class)| *class).collect();
        let sizes: Vec<f64> = holes.iter().map(|(c, _)| c.size[0].max(c.size[1]) as f64).collect();
        let found = find_outlet(&self.table, &points, &classes, &sizes, hash);
        times.hash += ms_since(t);
        let Some(m) = found else { return (None, None) };
        let t = Instant::now();
        let guesses: Vec<Option<Point2<f64>>> =
            m.assignment.iter().map(|a| a.and_then(|k| holes.get(k).map(|(c, _)| c.centre))).collect();
        // A later look with more candidates often finds the same reading again:
        // verification would refuse it again, for the same reason.
        let same = |h: &&Hypothesis| h.transform == m.transform && h.guesses == guesses && h.score == m.score;
        if let Some(h) = refused.iter().find(same) {
            tracing::debug!(reason = %h.why, "the same reading as one refused before");
            return (None, Some(h.why.clone()));
        }
        let result = self.refine_either(grey, lens, &m.transform, &guesses, m.score);
        if let Err(why) = &result {
            refused.push(Hypothesis { transform: m.transform, guesses, score: m.score, why: why.clone() });
        }
        times.refine += ms_since(t);
        match result {
            Ok(d) => (Some(d), None),
            Err(why) => {
                tracing::debug!(reason = %why, "outlet refused by verification");
                (None, Some(why))
            }
        }
    }

    /// [`Self::refine`] of the hashing's reading, or else of its half turn.
    fn refine_either(
        &self,
        grey: &GrayImage,
        lens: &Lens,
        transform: &Matrix3<f64>,
        guesses: &[Option<Point2<f64>>],
        score: usize,
    ) -> Result<Detection, String> {
        self.refine(grey, lens, transform, guesses, score).or_else(|why| {
            // Hashing leaves a duplex's two readings of the same power holes
            // to the image: the half-turned one, if its ground holes say so.
            let Some((c, image)) = self.table.half_turn() else { return Err(why) };
            let turn = Matrix3::new(-1.0, 0.0, 2.0 * c.x, 0.0, -1.0, 2.0 * c.y, 0.0, 0.0, 1.0);
            let turned: Vec<Option<Point2<f64>>> =
                image.iter().map(|k| k.and_then(|k| guesses.get(k).copied().flatten())).collect();
            self.refine(grey, lens, &(transform * turn), &turned, score)
                .map_err(|turned_why| format!("{why}; half-turned: {turned_why}"))
        })
    }

    /// Refines every hole from the hashing's homography, then verifies the
    /// outlet: every hole seen on one plane's homography, not mirrored, ground
    /// holes where they should be, and outlines that tell its reading from the
    /// swapped one. `Err` says which check refused it.
    fn refine(
        &self,
        grey: &GrayImage,
        lens: &Lens,
        homography: &Matrix3<f64>,
        guesses: &[Option<Point2<f64>>],
        score: usize,
    ) -> Result<Detection, String> {
        let model: Vec<Point2<f64>> = self.template.geometry.holes.iter().map(|h| h.position()).collect();
        let mut fits: Vec<Option<Refined>> = Vec::with_capacity(model.len());
        let mut jacobians: Vec<Matrix2<f64>> = Vec::with_capacity(model.len());
        let degenerate = || "the homography maps a hole to infinity".to_string();
        for (i, t) in model.iter().enumerate() {
            let predicted = lens.distort(apply(homography, t).ok_or_else(degenerate)?);
            // The candidate's own centre where it is close to the prediction.
            let guess = match guesses.get(i).copied().flatten() {
                Some(g) if (g - predicted).norm() < 3.0 => g,
                _ => predicted,
            };
            let jacobian = local_jacobian(homography, lens, t).ok_or_else(degenerate)?;
            let fit = refine_hole(grey, guess, &jacobian, self.outlines[i], &self.params.refine);
            tracing::trace!(hole = i, ?guess, ?predicted, fitted = ?fit.map(|f| f.centre), "hole refined");
            fits.push(fit);
            jacobians.push(jacobian);
        }
        let mut refined: Vec<Option<Point2<f64>>> = fits.iter().map(|f| f.map(|r| r.centre)).collect();
        // The refined holes must lie where one plane puts them. Holes that do not
        // (a fit caught by a glint or a dark spot) are dropped one by one, worst
        // first; the outlet stands only if enough holes remain.
        let min_holes = self.params.hash.min_score(model.len()).max(4);
        // Pixels per mm along the outlet's least foreshortened direction.
        let scale = local_jacobian(homography, lens, &centroid(&model)).ok_or_else(degenerate)?.singular_values().max();
        let tolerance = self.params.max_plane_px.max(self.params.max_plane_mm * scale);
        // Too few holes on one plane yet may be the hashing's homography, made
        // from a few candidates' centres, guessing the far holes too far off for
        // their outlines (blur, a real outlet a little off the nominal one): with
        // enough of them, the rest are looked for where the fitted holes put them.
        let h = plane_fit(&model, &mut refined, lens, tolerance, min_holes.min(self.params.min_holes_to_look_again))?;
        // A hole not found (faint: washed out, in shadow; or its first guess too
        // far off) is looked for once more where the seen holes' homography puts
        // it, with less contrast; it counts only if it lands on that plane too.
        let faint = RefineParams { min_relative_contrast: self.params.verify.faint_contrast, ..self.params.refine };
        let mut wants_prediction = vec![false; model.len()];
        let mut faint_found = false;
        for (i, t) in model.iter().enumerate() {
            if refined[i].is_some() {
                continue;
            }
            let Some(q) = apply(&h, t) else { continue };
            let Some(jacobian) = local_jacobian(&h, lens, t) else { continue };
            let moved = refine_hole(grey, lens.distort(q), &jacobian, self.outlines[i], &faint);
            tracing::trace!(hole = i, at = ?lens.distort(q), fitted = ?moved.map(|f| f.centre), "looked for again");
            match moved.map(|fit| (fit, (q - lens.undistort(fit.centre)).norm())) {
                Some((fit, d)) if d <= tolerance => {
                    tracing::debug!(hole = i, "faint hole fitted where the other holes put it");
                    refined[i] = Some(fit.centre);
                    fits[i] = Some(fit.with_sigma_at_least(tolerance / 2.0));
                    jacobians[i] = jacobian;
                    faint_found = true;
                }
                // An opening clearly beside the predicted place: the hole may be
                // there, or the outlet not where the homography says; not seen.
                Some((_, d)) if d.is_nan() || d > 2.0 * tolerance => {}
                // None found, or one pulled a little off (a dark dot beside a
                // ground hole): the outline must show at the predicted place.
                _ => wants_prediction[i] = true,
            }
        }
        // The faint holes join the fit and are checked by it (a faint fit off the
        // plane is dropped); any centre predicted below comes from this fit.
        let seen = refined.iter().flatten().count();
        let h = if faint_found || seen < min_holes {
            plane_fit(&model, &mut refined, lens, tolerance, min_holes)?
        } else {
            h
        };
        // A fitted hole's sigma is at least what the other holes say of it: its
        // outline fit measures the image noise, not the fit's bias (a T-slot's
        // branch, a blurred edge, a worn opening), which shows as the hole's
        // distance from where the rest of the outlet puts it.
        for (i, spread) in agreement_sigmas(&model, &refined, lens).into_iter().enumerate() {
            if let (Some(spread), Some(fit)) = (spread, fits[i].as_mut()) {
                *fit = fit.with_sigma_at_least(spread);
            }
        }
        // No hole is much surer than the outlet's typical one: the holes share
        // the blur, the noise and the outline model's error, and a fit that
        // claims far less than its neighbours is mostly one that was lucky in
        // its pixels (see `MIN_SIGMA_OF_MEDIAN`).
        let mut fitted_sigmas: Vec<f64> =
            fits.iter().zip(&refined).filter_map(|(f, r)| r.and(f.as_ref()).map(|f| f.sigma_px)).collect();
        if !fitted_sigmas.is_empty() {
            let mid = fitted_sigmas.len() / 2;
            let median = *fitted_sigmas.select_nth_unstable_by(mid, f64::total_cmp).1;
            for (fit, r) in fits.iter_mut().zip(&refined) {
                if let (Some(fit), Some(_)) = (fit.as_mut(), r) {
                    *fit = fit.with_sigma_at_least(MIN_SIGMA_OF_MEDIAN * median);
                }
            }
        }
        // A centre taken from the homography is only as good as the fit it comes
        // from: it takes at least `min_fitted_for_prediction` fitted holes. Its outline
        // must show right there (`refined` false); its sigma carries the fitted
        // holes' error carried through the homography and the real outlet's
        // departure from the nominal geometry.
        let fitted: Vec<(Point2<f64>, Point2<f64>, f64)> = model
            .iter()
            .zip(&refined)
            .zip(&fits)
            .filter_map(|((t, r), f)| Some((*t, lens.undistort((*r)?), f.as_ref()?.sigma_px)))
            .collect();
        let mut predicted_only = vec![false; model.len()];
        for (i, t) in model.iter().enumerate() {
            if refined[i].is_some() || !wants_prediction[i] || fitted.len() < self.params.min_fitted_for_prediction {
                continue;
            }
            let Some(q) = apply(&h, t) else { continue };
            let predicted = lens.distort(q);
            let Some(jacobian) = local_jacobian(&h, lens, t) else { continue };
            let Some(fit) = outline_at(grey, predicted, &jacobian, self.outlines[i], &faint) else { continue };
            let carried = prediction_sigma(&fitted, t).unwrap_or(f64::INFINITY);
            let nominal = self.params.predicted_sigma_mm * jacobian.singular_values().max();
            let sigma_px = (fit.sigma_px.powi(2) + carried.powi(2) + nominal.powi(2)).sqrt().max(tolerance / 2.0);
            if !sigma_px.is_finite() {
                continue;
            }
            tracing::debug!(hole = i, sigma_px, "hole seen where the fitted holes put it");
            predicted_only[i] = true;
            refined[i] = Some(predicted);
            // Mostly the carried and nominal errors, the same on both axes.
            fits[i] = Some(Refined { sigma_px, shape: Matrix2::identity(), ..fit });
            jacobians[i] = jacobian;
        }
        // Every hole must have been seen: a hole predicted from the others may lie
        // on the bare plate (the arm would go there), so the outlet is refused.
        let mut holes = Vec::with_capacity(model.len());
        for (i, ((t, r), hole)) in model.iter().zip(&refined).zip(&self.template.geometry.holes).enumerate() {
            let kind = hole.kind.as_str();
            let (Some(pixel), Some(fit)) = (r, fits[i]) else {
                return Err(match fits[i] {
                    None if wants_prediction[i] && fitted.len() < self.params.min_fitted_for_prediction => format!(
                        "hole {i} ({kind}): not fitted, and {} fitted holes are too few to predict it",
                        fitted.len()
                    ),
                    None => format!("hole {i} ({kind}): no opening of its outline found where the homography puts it"),
                    Some(_) => format!("hole {i} ({kind}): its opening is off the outlet's plane"),
                });
            };
            let predicted = apply(&h, t).map(|q| lens.distort(q)).ok_or_else(degenerate)?;
            let offset = (pixel - predicted).norm();
            if fit.explained < self.params.verify.min_explained {
                return Err(format!("hole {i} ({kind}): its outline explains only {:.2} of the pixels", fit.explained));
            }
            // A centre taken from the homography is weaker evidence than a fitted one.
            let score = hole_score(&fit, offset, tolerance) * if predicted_only[i] { 0.5 } else { 1.0 };
            let refined = !predicted_only[i];
            holes.push(DetectedHole {
                kind: hole.kind,
                pixel: *pixel,
                refined,
                score,
                sigma_px: fit.sigma_px,
                shape: fit.shape,
            });
        }
        // Never a mirror image: the camera sees the outlet's front.
        let det = local_jacobian(&h, lens, &centroid(&model)).ok_or_else(degenerate)?.determinant();
        if det.is_nan() || det <= 0.0 {
            return Err("the refined holes read as a mirror image".to_string());
        }
        let ground = self.ground_evidence(grey, lens, &h);
        if ground == GroundEvidence::Against {
            return Err("the ground holes are no darker than where a half turn would put them".to_string());
        }
        // The outlines decide the reading against its half turn, unless the
        // ground holes did: then the mirror is all that is left, and a camera
        // never sees one (the determinant above), so the slots only veto a
        // reading they clearly contradict. Slot lengths are weak evidence on
        // real photographs (a T-slot and a hot slot 8-12 px long in blur).
        let seen: Vec<(Point2<f64>, Matrix2<f64>, HoleShape)> =
            holes.iter().zip(&jacobians).zip(&self.outlines).map(|((d, j), o)| (d.pixel, *j, *o)).collect();
        if let Some(gain) = identity_gain(grey, &seen, &self.outlines, &self.params.refine) {
            tracing::debug!(gain, ?ground, "outlines against the swapped reading");
            let least = match ground {
                GroundEvidence::Decides => -self.params.verify.max_identity_contradiction,
                _ => self.params.verify.min_identity_gain,
            };
            if gain.is_nan() || gain < least {
                return Err(format!(
                    "the slot outlines fit the swapped reading (neutral and hot exchanged) about as well: gain {gain:.3}"
                ));
            }
        }
        Ok(Detection { holes, score, homography: h })
    }

    /// An outlet whose power holes map onto themselves under a half turn (every
    /// US duplex) matches its own half-turned self on the power holes alone: the
    /// ground holes then land on the plate, where nothing is (a false alarm that
    /// sends the arm beside the holes). The ground holes decide: where this
    /// detection puts them must be darker than where the half-turned one would.
    fn ground_evidence(&self, grey: &GrayImage, lens: &Lens, h: &Matrix3<f64>) -> GroundEvidence {
        let holes = &self.template.geometry.holes;
        let power: Vec<Point2<f64>> =
            holes.iter().filter(|t| t.kind == HoleKind::Power).map(|t| t.position()).collect();
        let ground: Vec<Point2<f64>> =
            holes.iter().filter(|t| t.kind == HoleKind::Ground).map(|t| t.position()).collect();
        if power.is_empty() || ground.is_empty() {
            return GroundEvidence::Silent;
        }
        let c = centroid(&power);
        let turn = |p: &Point2<f64>| Point2::from(2.0 * c.coords - p.coords);
        let symmetric = power.iter().all(|p| power.iter().any(|q| (turn(p) - q).norm() < 1.0));
        let turned: Vec<Point2<f64>> = ground.iter().map(turn).collect();
        // Where the turned grounds fall on holes of the template, nothing tells them apart.
        let on_holes = turned.iter().any(|g| holes.iter().any(|t| (t.position() - g).norm() < 2.0));
        if !symmetric || on_holes {
            return GroundEvidence::Silent;
        }
        let Some(jacobian) = local_jacobian(h, lens, &c) else { return GroundEvidence::Against };
        // Half the ground hole's width (4.8 mm) in pixels.
        let radius = (2.4 * jacobian.singular_values().min()).max(1.5);
        let darkness = |points: &[Point2<f64>]| -> Option<f64> {
            let mut sum = 0.0;
            for t in points {
                sum += dark_quartile(grey, lens.distort(apply(h, t)?), radius)?;
            }
            Some(sum / points.len() as f64)
        };
        match (darkness(&ground), darkness(&turned)) {
            (Some(here), Some(there)) => {
                // How much darker, relative to the half-turned places.
                let contrast = (there - here) / (there + 1.0);
                tracing::debug!(here, there, contrast, "ground holes against their half-turned places");
                if contrast.is_nan() || contrast <= self.params.ground_contrast {
                    GroundEvidence::Against
                } else if contrast >= self.params.ground_decides {
                    GroundEvidence::Decides
                } else {
                    GroundEvidence::Weak
                }
            }
            // A half-turned ground outside the image says nothing against this one.
            (Some(_), None) => GroundEvidence::Silent,
            _ => GroundEvidence::Against,
        }
    }
}

/// A fitted hole's sigma is at least this share of the median sigma of the
/// outlet's fitted holes. Rendered scenes (2100 frames), |error|^2 / 2 sigma^2
/// (1 on average if honest) by the hole's sigma over that median: below 0.5, 2.5
/// on average and 1% beyond 26; 0.5-0.7, 1.15; 0.7-0.85, 0.88; above, 0.7-0.75.
/// 0.8 rather than 0.7 trims the worst holes' NEES by a little more.
pub const MIN_SIGMA_OF_MEDIAN: f64 = 0.8;

/// The homography through the fitted holes (`refined`, template order), after
/// dropping one by one, worst first, the holes further than `tolerance` pixels
/// from it: a fit caught by a glint or a dark spot. `Err` when fewer than
/// `min_holes` remain.
fn plane_fit(
    model: &[Point2<f64>],
    refined: &mut [Option<Point2<f64>>],
    lens: &Lens,
    tolerance: f64,
    min_holes: usize,
) -> Result<Matrix3<f64>, String> {
    let mut pairs: Vec<(Point2<f64>, Point2<f64>)> = Vec::with_capacity(model.len());
    loop {
        pairs.clear();
        pairs.extend(model.iter().zip(refined.iter()).filter_map(|(t, r)| r.map(|r| (*t, lens.undistort(r)))));
        if pairs.len() < min_holes {
            return Err(format!("only {} holes lie on one plane", pairs.len()));
        }
        let h = fit_homography(&pairs).ok_or("no homography through the refined holes")?;
        let worst = model
            .iter()
            .zip(refined.iter())
            .enumerate()
            .filter_map(|(i, (t, r))| {
                let r = lens.undistort((*r)?);
                apply(&h, t).map(|q| (i, (q - r).norm()))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((i, e)) if e > tolerance || e.is_nan() => {
                tracing::debug!(hole = i, error_px = e, tolerance, "hole off the plane: dropped");
                refined[i] = None;
            }
            _ => return Ok(h),
        }
    }
}

/// Per fitted hole, the standard deviation per axis (pixels) its disagreement
/// with the other holes implies: with e its residual from the homography
/// through all of them and r from the homography through the others
/// (leave-one-out), e r / 2 estimates its variance per axis (the studentised
/// residual of least squares: e shrinks by the hole's leverage and r grows by
/// it, their product does neither). `None` for a hole not fitted, or where
/// fewer than five others are.
fn agreement_sigmas(model: &[Point2<f64>], refined: &[Option<Point2<f64>>], lens: &Lens) -> Vec<Option<f64>> {
    let pairs: Vec<(usize, Point2<f64>, Point2<f64>)> =
        model.iter().zip(refined).enumerate().filter_map(|(i, (t, r))| Some((i, *t, lens.undistort((*r)?)))).collect();
    let mut out = vec![None; model.len()];
    if pairs.len() < 6 {
        return out;
    }
    let all: Vec<(Point2<f64>, Point2<f64>)> = pairs.iter().map(|(_, t, p)| (*t, *p)).collect();
    let Some(full) = fit_homography(&all) else { return out };
    let mut others: Vec<(Point2<f64>, Point2<f64>)> = Vec::with_capacity(all.len());
    for (k, (i, t, p)) in pairs.iter().enumerate() {
        others.clear();
        others.extend(all.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, pair)| *pair));
        let (Some(e), Some(r)) = (
            apply(&full, t).map(|q| (q - p).norm()),
            fit_homography(&others).and_then(|h| apply(&h, t)).map(|q| (q - p).norm()),
        ) else {
            continue;
        };
        let sigma = (e * r / 2.0).sqrt();
        if let Some(slot) = out.get_mut(*i) {
            *slot = sigma.is_finite().then_some(sigma);
        }
    }
    out
}

/// Standard deviation per axis (pixels) of the point the homography through
/// `fitted` (template mm, undistorted pixel, that pixel's sigma) puts `t` at,
/// from the fitted pixels' own errors carried through the fit (numerically:
/// each pixel moved in turn). Large where `t` lies far outside the fitted holes.
fn prediction_sigma(fitted: &[(Point2<f64>, Point2<f64>, f64)], t: &Point2<f64>) -> Option<f64> {
    let pairs: Vec<(Point2<f64>, Point2<f64>)> = fitted.iter().map(|(m, p, _)| (*m, *p)).collect();
    let base = apply(&fit_homography(&pairs)?, t)?;
    let step = 0.01;
    let mut variance = 0.0;
    for (k, (_, _, sigma)) in fitted.iter().enumerate() {
        for axis in 0..2 {
            let mut moved = pairs.clone();
            moved[k].1[axis] += step;
            let q = apply(&fit_homography(&moved)?, t)?;
            variance += ((q - base) / step).norm_squared() * sigma * sigma;
        }
    }
    // Per axis: half the trace.
    let sigma = (variance / 2.0).sqrt();
    sigma.is_finite().then_some(sigma)
}

/// What the ground holes say about a reading against its half turn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum GroundEvidence {
    /// Nothing: no ground holes, an outlet not symmetric under a half turn, or
    /// the half-turned places outside the image.
    Silent,
    /// Darker than the half-turned places, but not by [`DetectorParams::ground_decides`].
    Weak,
    /// Clearly darker: the half turn is decided.
    Decides,
    /// Not darker: the reading is refused.
    Against,
}

/// The mean of the darkest quarter of the grey values within `radius` pixels of
/// `centre`; `None` when the disc leaves the image.
fn dark_quartile(grey: &GrayImage, centre: Point2<f64>, radius: f64) -> Option<f64> {
    let (w, h) = grey.dimensions();
    let r = radius.ceil();
    // In floating point first: a centre far outside (or not finite) fails here.
    let inside = |c: f64, size: u32| c.round() - r >= 0.0 && c.round() + r < size as f64;
    if !(radius.is_finite() && inside(centre.x, w) && inside(centre.y, h)) {
        return None;
    }
    let (r, cx, cy) = (r as i64, centre.x.round() as i64, centre.y.round() as i64);
    // A histogram, not a sorted copy: the darkest quarter's mean all the same.
    let mut histogram = [0u32; 256];
    let mut count = 0usize;
    for y in cy - r..=cy + r {
        for x in cx - r..=cx + r {
            let (dx, dy) = (x as f64 - centre.x, y as f64 - centre.y);
            if dx * dx + dy * dy <= radius * radius {
                histogram[grey.get_pixel(x as u32, y as u32)[0] as usize] += 1;
                count += 1;
            }
        }
    }
    if count == 0 {
        return None;
    }
    let quarter = (count / 4).max(1);
    let (mut left, mut sum) = (quarter, 0.0);
    for (value, &n) in histogram.iter().enumerate() {
        let take = left.min(n as usize);
        sum += (value * take) as f64;
        left -= take;
        if left == 0 {
            break;
        }
    }
    Some(sum / quarter as f64)
}

/// Distortion on the way in and out of the geometric stages.
struct Lens<'a> {
    camera: Option<&'a CameraModel>,
}

impl Lens<'_> {
    /// Undistorted pixel (same intrinsics, no distortion) of a captured pixel.
    fn undistort(&self, p: Point2<f64>) -> Point2<f64> {
        match self.camera {
            Some(c) if !c.is_rectified() => {
                let n = c.undistort_pixel(p);
                Point2::new(c.fx * n.x + c.cx, c.fy * n.y + c.cy)
            }
            _ => p,
        }
    }

    fn distort(&self, p: Point2<f64>) -> Point2<f64> {
        match self.camera {
            Some(c) if !c.is_rectified() => {
                let d = c.distort_normalized(Vector2::new((p.x - c.cx) / c.fx, (p.y - c.cy) / c.fy));
                Point2::new(c.fx * d.x + c.cx, c.fy * d.y + c.cy)
            }
            _ => p,
        }
    }
}

/// The image at half resolution: each pixel the mean of a 2x2 block. None when
/// the image is too small to halve.
pub fn half_resolution(grey: &GrayImage) -> Option<GrayImage> {
    let (w, h) = (grey.width() / 2, grey.height() / 2);
    if w < 16 || h < 16 {
        return None;
    }
    // Row slices, not per-pixel look-ups: on a 1567x1070 photograph the look-ups
    // cost 1 ms of a 26 ms detection (perf), the slices a fifth of that.
    let stride = grey.width() as usize;
    let raw = grey.as_raw();
    let mut out = vec![0u8; w as usize * h as usize];
    for (y, row) in out.chunks_exact_mut(w as usize).enumerate() {
        let top = &raw[2 * y * stride..][..2 * w as usize];
        let bottom = &raw[(2 * y + 1) * stride..][..2 * w as usize];
        for ((o, t), b) in row.iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2)) {
            let sum = u32::from(t[0]) + u32::from(t[1]) + u32::from(b[0]) + u32::from(b[1]);
            *o = ((sum + 2) / 4) as u8;
        }
    }
    GrayImage::from_raw(w, h, out)
}

/// The camera of the half-resolution image: focal lengths halved, the principal
/// point where the same ray lands (OpenCV pixel centres), the same distortion.
fn half_camera(camera: &CameraModel, width: u32, height: u32) -> Option<CameraModel> {
    // Checked as a camera of its own size, unless it is a window cut from a
    // checked camera's frame (its principal point may lie far outside it).
    let half = CameraModel {
        width,
        height,
        fx: camera.fx / 2.0,
        fy: camera.fy / 2.0,
        cx: (camera.cx - 0.5) / 2.0,
        cy: (camera.cy - 0.5) / 2.0,
        distortion: camera.distortion,
    };
    let finite = [half.fx, half.fy, half.cx, half.cy].iter().all(|v| v.is_finite());
    (finite && half.fx >= 0.5 && half.fy >= 0.5 && width > 0 && height > 0).then_some(half)
}

fn centroid(points: &[Point2<f64>]) -> Point2<f64> {
    Point2::from(points.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / points.len().max(1) as f64)
}

pub use outlet_protocol::math::apply_homography as apply;

/// d(captured pixel)/d(template mm) at a template point.
fn local_jacobian(h: &Matrix3<f64>, lens: &Lens, t: &Point2<f64>) -> Option<Matrix2<f64>> {
    let at = |dx: f64, dy: f64| apply(h, &Point2::new(t.x + dx, t.y + dy)).map(|q| lens.distort(q));
    let (xp, xm, yp, ym) = (at(0.5, 0.0)?, at(-0.5, 0.0)?, at(0.0, 0.5)?, at(0.0, -0.5)?);
    Some(Matrix2::new(xp.x - xm.x, yp.x - ym.x, xp.y - xm.y, yp.y - ym.y))
}

pub use outlet_protocol::math::fit_homography;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_half_image_is_the_mean_of_each_2x2_block_rounded() {
        // Odd sides: the last row and column have no partner and are left out.
        let grey = GrayImage::from_fn(41, 35, |x, y| image::Luma([((x * 73 + y * 151 + x * y * 7) % 256) as u8]));
        let half = half_resolution(&grey).expect("large enough");
        assert_eq!(half.dimensions(), (20, 17));
        for (x, y, p) in half.enumerate_pixels() {
            let sum: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(dx, dy)| u32::from(grey.get_pixel(2 * x + dx, 2 * y + dy).0[0]))
                .sum();
            assert_eq!(p.0[0], ((sum + 2) / 4) as u8, "at ({x}, {y})");
        }
        assert!(half_resolution(&GrayImage::new(31, 40)).is_none(), "under 16 px a side");
    }

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

    /// A 2x1's six holes (template mm) seen at 3 px per mm, shifted to (300, 200).
    fn seen_2x1() -> (Vec<Point2<f64>>, Vec<Point2<f64>>) {
        let model: Vec<Point2<f64>> =
            outlet_protocol::OutletGeometry::us_2x1().holes.iter().map(|h| h.position()).collect();
        let image = model.iter().map(|t| Point2::new(300.0 + 3.0 * t.x, 200.0 + 3.0 * t.y)).collect();
        (model, image)
    }

    #[test]
    fn the_plane_fit_drops_a_hole_off_the_plane_and_refuses_when_too_few_remain() {
        let (model, image) = seen_2x1();
        let lens = Lens { camera: None };
        let mut refined: Vec<Option<Point2<f64>>> = image.iter().map(|p| Some(*p)).collect();
        refined[1] = Some(image[1] + Vector2::new(6.0, -2.0));
        let h = plane_fit(&model, &mut refined, &lens, 1.0, 4).expect("five holes remain");
        assert_eq!(refined[1], None, "the moved hole is dropped");
        assert!(refined.iter().filter(|r| r.is_some()).count() == 5);
        let q = apply(&h, &model[1]).expect("finite");
        assert!((q - image[1]).norm() < 1e-6, "the fit puts the dropped hole back at {q}");
        let mut refined: Vec<Option<Point2<f64>>> = image.iter().map(|p| Some(*p)).collect();
        refined[1] = Some(image[1] + Vector2::new(6.0, -2.0));
        let why = plane_fit(&model, &mut refined, &lens, 1.0, 6).expect_err("only five on the plane");
        assert!(why.contains("only 5 holes"), "{why}");
    }

    #[test]
    fn a_hole_the_others_disagree_with_gets_the_disagreement_as_its_sigma() {
        let (model, image) = seen_2x1();
        let lens = Lens { camera: None };
        let exact: Vec<Option<Point2<f64>>> = image.iter().map(|p| Some(*p)).collect();
        let sigmas = agreement_sigmas(&model, &exact, &lens);
        assert!(sigmas.iter().all(|s| s.is_some_and(|s| s < 1e-6)), "{sigmas:?}");
        // One hole 0.8 px off, as a fit pulled by a T-slot's branch would be.
        let mut moved = exact.clone();
        moved[4] = Some(image[4] + Vector2::new(0.8, 0.0));
        let sigmas = agreement_sigmas(&model, &moved, &lens);
        let own = sigmas[4].expect("fitted");
        assert!(own > 0.3 && own < 0.8, "the moved hole: {own:.3} px");
        let others = sigmas.iter().enumerate().filter(|(i, _)| *i != 4).filter_map(|(_, s)| *s).fold(0.0, f64::max);
        assert!(others < own, "the others {others:.3} px, the moved hole {own:.3} px");
        // Too few fitted holes to tell: no claim.
        let mut few = exact;
        few[0] = None;
        assert!(agreement_sigmas(&model, &few, &lens).iter().all(Option::is_none));
    }

    #[test]
    fn a_prediction_from_four_holes_is_less_sure_than_one_from_five() {
        let (model, image) = seen_2x1();
        let with = |ks: &[usize]| -> Vec<(Point2<f64>, Point2<f64>, f64)> {
            ks.iter().map(|&k| (model[k], image[k], 0.2)).collect()
        };
        // Hole 5 (the lower ground) from the upper receptacle and the lower slots.
        let four = prediction_sigma(&with(&[0, 1, 3, 4]), &model[5]).expect("four");
        let five = prediction_sigma(&with(&[0, 1, 2, 3, 4]), &model[5]).expect("five");
        assert!(four.is_finite() && five.is_finite());
        assert!(four > five, "four holes {four:.3} px, five {five:.3} px");
        // Extrapolating far beyond the fitted holes is less sure than between them.
        let far = prediction_sigma(&with(&[0, 1, 2, 3, 4]), &Point2::new(0.0, 120.0)).expect("far");
        assert!(far > 2.0 * five, "far {far:.3} px, near {five:.3} px");
        // Sure pixels make a sure prediction: the sigma scales with theirs.
        let sure: Vec<_> = with(&[0, 1, 2, 3, 4]).into_iter().map(|(m, p, _)| (m, p, 0.02)).collect();
        let sure = prediction_sigma(&sure, &model[5]).expect("sure");
        assert!((sure * 10.0 - five).abs() < 1e-3 * five, "{sure} against {five}");
    }

    #[test]
    fn the_dark_quartile_sees_a_hole_and_refuses_discs_it_cannot_read() {
        // A grey face at 200 with a dark hole of radius 3 at (20, 20).
        let image = GrayImage::from_fn(40, 40, |x, y| {
            let (dx, dy) = (x as f64 - 20.0, y as f64 - 20.0);
            image::Luma([if dx * dx + dy * dy <= 9.0 { 20 } else { 200 }])
        });
        let on_hole = dark_quartile(&image, Point2::new(20.0, 20.0), 5.0).expect("inside");
        let on_face = dark_quartile(&image, Point2::new(8.0, 30.0), 5.0).expect("inside");
        assert_eq!((on_hole, on_face), (20.0, 200.0));
        for centre in [(2.0, 20.0), (20.0, 38.0), (f64::NAN, 20.0), (1e300, 20.0), (-1e300, f64::INFINITY)] {
            assert_eq!(dark_quartile(&image, Point2::new(centre.0, centre.1), 5.0), None, "{centre:?}");
        }
        assert_eq!(dark_quartile(&image, Point2::new(20.0, 20.0), f64::INFINITY), None);
    }
}
