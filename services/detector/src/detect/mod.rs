//! The detector: the paper's stages in order (`candidates` → `classify` → `hash`)
//! and what goes beyond it (`refine`: sub-pixel holes, and a final check that the
//! refined holes lie where one outlet plane puts them). Here: the detector and
//! its levels (full frame, windows, the half-resolution first look); in
//! `looks`, one level's stages and its later looks; `holes`, each hypothesis's
//! holes refined and the outlet verified from them; `ground`, the ground
//! holes' check of a half turn; `params`, every stage's parameters;
//! `pyramid`, the half-resolution image.

mod ground;
mod holes;
mod looks;
mod params;
mod pyramid;

pub use holes::MIN_SIGMA_OF_MEDIAN;
pub use params::DetectorParams;
pub use pyramid::half_resolution;
pub(crate) use pyramid::with_crop;

use crate::hashing::HashTable;
use crate::refine::HoleShape;
use crate::template::Template;
use crate::{Candidate, Class, grey_of};
use image::{GrayImage, RgbImage};
use nalgebra::{Matrix2, Matrix3, Point2, Vector2};
use outlet_protocol::{CameraModel, HoleKind};
use pyramid::half_camera;
use std::time::Instant;

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
    /// Gives the holes' vector to this thread's next detection.
    fn recycle(self) {
        crate::give_spare(&SPARE_HOLES, self.holes);
    }

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
#[derive(Debug, Clone, Default)]
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

/// A finer level's verification of a refused reading: the outlet in its
/// pixels, or `None`.
type Escalate<'a> = &'a mut dyn FnMut(&Hypothesis) -> Option<Detection>;

/// The readings a level's verification refused, and what the level above
/// does with each as it is refused.
#[derive(Default)]
struct Refusals<'a> {
    list: Vec<Hypothesis>,
    /// Given by the level above (a half level's caller): the reading verified
    /// at that level's resolution, the outlet in its pixels or `None`.
    escalate: Option<Escalate<'a>>,
    /// What `escalate` verified: it ends this level's looks.
    escalated: Option<Detection>,
}

thread_local! {
    /// Hole guesses made over for a refinement: a followed outlet's in its
    /// window, a reading's half turn, a half level's outlet at full resolution.
    static GUESS_SCRATCH: std::cell::RefCell<Vec<Option<Point2<f64>>>> =
        const { std::cell::RefCell::new(Vec::new()) };
    /// Holes' vectors of detections let go (a half level's outlet once
    /// verified at full resolution, the last report of
    /// [`Detector::detect_grey_into`]), for the next detection's holes.
    static SPARE_HOLES: std::cell::RefCell<Vec<Vec<DetectedHole>>> = const { std::cell::RefCell::new(Vec::new()) };
    /// The reports of half levels, kept between frames: one per level in use
    /// at once.
    static SPARE_REPORTS: std::cell::RefCell<Vec<DetectReport>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// A template ready to detect with.
#[derive(Debug, Clone)]
pub struct Detector {
    template: Template,
    table: HashTable,
    outlines: Vec<HoleShape>,
    /// The ground check's template places, found once.
    ground_places: Option<ground::GroundPlaces>,
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
        let ground_places = ground::GroundPlaces::of(&template.geometry);
        Self { template, table, outlines, ground_places, params }
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
        let mut report = DetectReport::default();
        self.detect_grey_into(grey, camera, &mut report);
        report
    }

    /// [`Self::detect_grey`] into `report`, whatever it held, reusing its
    /// vectors (the candidates, the detection's holes): a caller that keeps
    /// its report takes nothing from the heap per frame in the steady state.
    pub fn detect_grey_into(&self, grey: &GrayImage, camera: Option<&CameraModel>, report: &mut DetectReport) {
        self.detect_level(grey, camera, grey.width().max(grey.height()), &mut Refusals::default(), report);
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
        // Copied into a buffer this thread keeps, not a new image each search.
        pyramid::with_crop(grey, [x, y, cw, ch], |crop| self.detect_crop(crop, [x, y], [w, h], camera))
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
        let mut report = DetectReport::default();
        self.detect_level(
            crop,
            camera.as_ref(),
            frame_size[0].max(frame_size[1]),
            &mut Refusals::default(),
            &mut report,
        );
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
        let lens = Lens { camera: camera.as_ref() };
        let result = if guesses.len() != self.template.geometry.holes.len() {
            Err(format!(
                "{} hole guesses for a template of {} holes",
                guesses.len(),
                self.template.geometry.holes.len()
            ))
        } else {
            crate::with_scratch(&GUESS_SCRATCH, |shifted| {
                shifted.clear();
                shifted.extend(guesses.iter().map(|g| Some(g - shift)));
                self.refine(crop, &lens, &(to_crop * homography), shifted, score)
            })
            .and_then(|mut d| {
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

    /// [`Self::detect_grey_into`], with the size-dependent choices made for an
    /// image whose larger side is `largest` (this one, or the frame it was cut
    /// from), also giving the hypotheses that hashing found in this image and
    /// its verification here refused (`refused`), each passed on as it is
    /// refused to the level above when that asks for it.
    fn detect_level(
        &self,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        largest: u32,
        refused: &mut Refusals,
        report: &mut DetectReport,
    ) {
        if let Some(old) = report.detection.take() {
            old.recycle();
        }
        report.rejected = None;
        let mut times = StageTimes::default();
        let coarse_first = self.params.coarse_first_px > 0 && largest >= self.params.coarse_first_px;
        if coarse_first
            && let Some(half) = self.at_half_resolution(grey, camera, largest, &mut times, Some(&mut report.candidates))
        {
            match half {
                Ok(found) => {
                    (report.detection, report.times) = (Some(found), times);
                    return;
                }
                Err(rejected) if !self.params.full_after_coarse(camera) => {
                    (report.rejected, report.times) = (rejected, times);
                    return;
                }
                Err(_) => {}
            }
        }
        let t = Instant::now();
        let _span = tracing::debug_span!("detect", width = grey.width(), height = grey.height()).entered();
        // Larger images resolve holes well; texture (carpet, paint) brings
        // hundreds of faint blobs that a looser contrast would let in.
        let mut min_contrast = self.params.candidates.min_contrast;
        if largest >= self.params.large_image_px {
            min_contrast = min_contrast.max(self.params.large_image_min_contrast);
        }
        // The looks take this thread's vectors, and give them back before the
        // half level's detection takes them in turn.
        let classified = &mut report.candidates;
        let (mut detection, mut rejected) = crate::with_scratch(&looks::LEVEL_SCRATCH, |scratch| {
            self.looks(grey, camera, min_contrast, t, &mut times, refused, scratch, classified)
        });
        // (Coarse first: the levels below were looked at already. A reading
        // the level above verified ends the search.)
        if detection.is_none()
            && refused.escalated.is_none()
            && !coarse_first
            && self.params.pyramid_min_px > 0
            && largest >= self.params.pyramid_min_px
            && let Some(half) = self.at_half_resolution(grey, camera, largest, &mut times, None)
        {
            match half {
                Ok(found) => detection = Some(found),
                Err(why) => rejected = why.or(rejected),
            }
        }
        if detection.is_some() {
            rejected = None;
        }
        (report.detection, report.times, report.rejected) = (detection, times, rejected);
    }

    /// The outlet found in the image at half resolution (each level of a pyramid
    /// in turn, while nothing is found), in this image's pixels; `Err` with why
    /// not. The level's candidates, in this image's pixels, go to `candidates`
    /// when given. None when the half image or its camera cannot be made.
    fn at_half_resolution(
        &self,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        largest: u32,
        times: &mut StageTimes,
        candidates: Option<&mut Vec<(Candidate, Class)>>,
    ) -> Option<LevelOutcome> {
        // The half image and its level's report are this thread's, kept
        // between frames (one of each per level in use at once).
        let mut report = crate::take_spare(&SPARE_REPORTS);
        // OpenCV pixel centres: full = 2 half + 0.5, in the image as captured
        // and in undistorted pixels alike (the camera is scaled the same way).
        let up = Matrix3::new(2.0, 0.0, 0.5, 0.0, 2.0, 0.5, 0.0, 0.0, 1.0);
        let to_full = |p: Point2<f64>| Point2::new(2.0 * p.x + 0.5, 2.0 * p.y + 0.5);
        let lens = Lens { camera };
        // What hashing finds at the half level but its verification refuses
        // (most often a faint hole: a real ground hole of a few pixels at half
        // size) is verified at once at full resolution, where the hole's
        // outline has four times the pixels; the full level's verification
        // decides, as for any outlet. Once one stands, the half level looks no
        // further (on V017, a steep Willow photograph, its three later looks
        // and the quarter level took 9 of 20 ms).
        let mut verify_at_full = |h: &Hypothesis| {
            let guesses: Vec<Option<Point2<f64>>> = h.guesses.iter().map(|g| g.map(to_full)).collect();
            match self.refine_either(grey, &lens, &(up * h.transform), &guesses, h.score) {
                Ok(found) => {
                    tracing::debug!("refused at half resolution, verified at full resolution");
                    Some(found)
                }
                Err(why) => {
                    tracing::debug!(reason = %why, "refused at half and at full resolution");
                    None
                }
            }
        };
        let mut refused = Refusals { escalate: Some(&mut verify_at_full), ..Refusals::default() };
        let looked = pyramid::with_half_resolution(grey, |half| {
            let half_camera = match camera {
                Some(c) => Some(half_camera(c, half.width(), half.height())?),
                None => None,
            };
            self.detect_level(half, half_camera.as_ref(), largest / 2, &mut refused, &mut report);
            Some(())
        });
        let escalated = refused.escalated.take();
        if looked.flatten().is_none() {
            crate::give_spare(&SPARE_REPORTS, report);
            return None;
        }
        *times += report.times;
        if let Some(candidates) = candidates {
            candidates.clear();
            candidates.extend(report.candidates.iter().map(|(c, class)| {
                let centre = to_full(c.centre);
                let size = [c.size[0].saturating_mul(2), c.size[1].saturating_mul(2)];
                (Candidate { centre, size, area: c.area.saturating_mul(4), ..*c }, *class)
            }));
        }
        let outcome = match report.detection.take() {
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
                let full = crate::with_scratch(&GUESS_SCRATCH, |guesses| {
                    guesses.clear();
                    guesses.extend(d.holes.iter().map(|h| Some(h.pixel)));
                    self.refine(grey, &Lens { camera }, &d.homography, guesses, d.score)
                });
                d.recycle();
                times.refine += ms_since(t);
                full.map_err(|why| {
                    tracing::debug!(reason = %why, "half-resolution outlet refused at full resolution");
                    Some(format!("found at half resolution, refused at full resolution: {why}"))
                })
            }
            // Verified at full resolution as it was refused (`verify_at_full`).
            None => escalated.ok_or_else(|| report.rejected.take()),
        };
        crate::give_spare(&SPARE_REPORTS, report);
        Some(outcome)
    }
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
