//! Tracking (beyond the paper): when the last frame had a verified outlet, look
//! for it first in a window around where it was, grown with the time since; the
//! whole frame is searched when the window finds nothing, when the last outlet
//! is too old, and every [`TrackParams::full_frame_every`] frames regardless. A
//! window's outlet goes through exactly the verification of a full frame's
//! ([`Detector::detect_window`]), so tracking can miss but cannot add a wrong
//! outlet that a full-frame search would not have given. With
//! [`TrackParams::follow`], before the window is searched, the last outlet is
//! verified where it was ([`Detector::verify_at`]: its holes refined from their
//! last places and every check of a detection), which costs the refinement
//! alone; the window is searched when that fails.

use crate::detect::{DetectReport, Detector, StageTimes};
use image::GrayImage;
use nalgebra::{Matrix3, Point2};
use outlet_protocol::CameraModel;
use outlet_protocol::math::apply_homography;

/// When and where to track.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackParams {
    /// A full-frame search at least every this many frames, however well the
    /// window does (a second outlet, a better view elsewhere); 0 or 1 = never
    /// track.
    pub full_frame_every: u32,
    /// Window margin on each side of the last outlet's holes, as a multiple of
    /// their extent: the plate and some wall around them, which the candidate
    /// stage's probes and the hashing's clutter test look at.
    pub margin: f64,
    /// More margin per second since the outlet was last seen (multiples of the
    /// extent): an arm approaching at 10 cm/s from 30 cm grows the outlet by a
    /// third in a second, and turns of the head move it by more.
    pub margin_per_s: f64,
    /// At least this many pixels of margin on each side.
    pub min_margin_px: f64,
    /// An outlet last seen longer ago than this (s) is looked for in the whole
    /// frame.
    pub max_age_s: f64,
    /// Verify the last outlet where it was before searching the window: 0.48
    /// ms instead of 1.1 per 640x480 frame. Off in session 13, when a fit
    /// started at the predicted place kept some of that place's error (the
    /// `white2x2` demo's followed holes 0.126 mm RMS in the face plane against
    /// 0.093 searched); on since the outline fit ends where it ends from any
    /// nearby start (`RefineParams::rough_edge_px`): 0.097 mm followed and
    /// searched alike, and no result beyond 5 sigma in either default demo
    /// scene (BENCHMARKS.md, session 14).
    pub follow: bool,
    /// A followed hole may move at most this fraction of the last outlet's
    /// closest hole spacing (pixels): a hole never takes its neighbour's place,
    /// and an outlet moving faster is searched for in the window instead.
    pub max_follow_move: f64,
}

impl Default for TrackParams {
    fn default() -> Self {
        Self {
            full_frame_every: 30,
            margin: 0.3,
            margin_per_s: 4.0,
            min_margin_px: 12.0,
            max_age_s: 0.5,
            follow: true,
            max_follow_move: 0.5,
        }
    }
}

/// Where a frame was searched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Searched {
    /// Only the window `[x, y, width, height]` around the last outlet.
    Window([u32; 4]),
    /// The last outlet verified where it was, within that window, without a
    /// search ([`Detector::verify_at`]).
    Followed([u32; 4]),
    /// The whole frame (after a window that found nothing, if `after_window`).
    FullFrame { after_window: bool },
}

/// One frame's result and how it was searched.
#[derive(Debug, Clone)]
pub struct Tracked {
    pub report: DetectReport,
    pub searched: Searched,
}

/// A verified outlet as tracking remembers it.
#[derive(Debug, Clone)]
struct LastOutlet {
    /// Hole pixels, template order.
    holes: Vec<Point2<f64>>,
    /// Its frame's time (s).
    time_s: f64,
    /// Template mm to undistorted pixels.
    homography: Matrix3<f64>,
    /// The hashing's score, carried into a followed detection.
    score: usize,
}

/// The tracking state of one camera's frames.
#[derive(Debug, Clone, Default)]
pub struct Tracker {
    params: TrackParams,
    /// The last verified outlet.
    last: Option<LastOutlet>,
    /// The homography and frame time (s) of the outlet verified the frame
    /// before the last one, when that frame had one: the motion to predict.
    before_last: Option<(Matrix3<f64>, f64)>,
    /// Frames searched by window only since the last full-frame search.
    windows_since_full: u32,
    /// The followed holes' guesses, kept between frames.
    guesses: Vec<Point2<f64>>,
}

impl Tracker {
    pub fn new(params: TrackParams) -> Self {
        Self { params, last: None, before_last: None, windows_since_full: 0, guesses: Vec::new() }
    }

    /// Forgets the last outlet: the next frame is searched whole.
    pub fn reset(&mut self) {
        self.last = None;
        self.before_last = None;
        self.windows_since_full = 0;
    }

    /// Detects in `grey`, captured at `time_s` (any clock, seconds; a time
    /// going backwards, as in a replay starting over, forgets the last outlet).
    pub fn detect_grey(
        &mut self,
        detector: &Detector,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        time_s: f64,
    ) -> Tracked {
        let size = [grey.width(), grey.height()];
        let mut tried = None;
        if let Some(w) = self.window_for(size, time_s) {
            // The follow reads only the pixels around the holes: from the frame
            // itself, without copying the window out of it.
            let mut spent = match self.follow(detector, grey, [0, 0], w, camera, time_s) {
                Ok(tracked) => return tracked,
                Err(spent) => spent,
            };
            // Copied into a buffer this thread keeps, not a new image each frame.
            let searched = crate::detect::with_crop(grey, w, |crop| {
                self.search_window_only(detector, crop, w, size, camera, time_s)
            });
            match searched {
                Ok(tracked) => return tracked,
                Err(times) => {
                    spent += times;
                    tried = Some(spent);
                }
            }
        }
        self.search_full_frame(detector, grey, camera, time_s, tried)
    }

    /// Searches `crop`, the grey pixels of `window` of a frame of `frame_size`:
    /// the tracked result when the outlet is found there, else the stages'
    /// times spent (to add to the whole frame's).
    pub fn search_window(
        &mut self,
        detector: &Detector,
        crop: &GrayImage,
        window: [u32; 4],
        frame_size: [u32; 2],
        camera: Option<&CameraModel>,
        time_s: f64,
    ) -> Result<Tracked, StageTimes> {
        let spent = match self.follow(detector, crop, [window[0], window[1]], window, camera, time_s) {
            Ok(tracked) => return Ok(tracked),
            Err(spent) => spent,
        };
        self.search_window_only(detector, crop, window, frame_size, camera, time_s).map_err(|mut times| {
            times += spent;
            times
        })
    }

    /// With [`TrackParams::follow`], verifies the last outlet where the motion
    /// puts it in `grey`, the part of the frame at `origin` (the whole frame,
    /// or `window` cut from it): the tracked result, or the time spent.
    fn follow(
        &mut self,
        detector: &Detector,
        grey: &GrayImage,
        origin: [u32; 2],
        window: [u32; 4],
        camera: Option<&CameraModel>,
        time_s: f64,
    ) -> Result<Tracked, StageTimes> {
        let (true, Some(LastOutlet { holes, time_s: then, homography, score })) =
            (self.params.follow, self.last.as_ref())
        else {
            return Err(StageTimes::default());
        };
        let max_move = self.params.max_follow_move * closest_spacing(holes);
        // The holes moved on as they did between the last two frames: an
        // approach at 10 cm/s moves a hole of an HD frame by several pixels
        // a frame, more than a fit started at its last place follows.
        let predicted = self.predicted(homography, *then, time_s);
        let model = detector.template().geometry.holes.iter().map(|h| h.position());
        self.guesses.clear();
        self.guesses.extend(holes.iter().zip(model).map(|(p, t)| {
            match (apply_homography(&predicted, &t), apply_homography(homography, &t)) {
                (Some(a), Some(b)) => p + (a - b),
                _ => *p,
            }
        }));
        let report = detector.verify_at(grey, origin, camera, &predicted, &self.guesses, *score, max_move);
        self.accept(report, time_s, Searched::Followed(window))
    }

    /// [`Self::search_window`] without the follow.
    fn search_window_only(
        &mut self,
        detector: &Detector,
        crop: &GrayImage,
        window: [u32; 4],
        frame_size: [u32; 2],
        camera: Option<&CameraModel>,
        time_s: f64,
    ) -> Result<Tracked, StageTimes> {
        let report = detector.detect_crop(crop, [window[0], window[1]], frame_size, camera);
        self.accept(report, time_s, Searched::Window(window))
    }

    /// A followed or window-searched frame's report: tracked when it has an
    /// outlet, else the stages' times spent.
    fn accept(&mut self, report: DetectReport, time_s: f64, searched: Searched) -> Result<Tracked, StageTimes> {
        if report.detection.is_none() {
            return Err(report.times);
        }
        self.windows_since_full += 1;
        self.remember(&report, time_s);
        Ok(Tracked { report, searched })
    }

    /// Searches the whole frame; `after_window` holds the times of a window
    /// searched first in vain, if one was.
    pub fn search_full_frame(
        &mut self,
        detector: &Detector,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        time_s: f64,
        after_window: Option<StageTimes>,
    ) -> Tracked {
        let mut report = detector.detect_grey(grey, camera);
        if let Some(t) = after_window {
            report.times += t;
        }
        self.windows_since_full = 0;
        self.remember(&report, time_s);
        Tracked { report, searched: Searched::FullFrame { after_window: after_window.is_some() } }
    }

    /// The last outlet's homography moved on to `time_s` by the motion between
    /// the last two frames (constant velocity), or as it was when there is no
    /// such motion or the frames are not evenly spaced.
    fn predicted(&self, last: &Matrix3<f64>, then: f64, time_s: f64) -> Matrix3<f64> {
        let Some((before, earlier)) = self.before_last.as_ref() else { return *last };
        let (gap, step) = (time_s - then, then - earlier);
        if !(gap > 0.0 && step > 0.0 && (gap / step - 1.0).abs() < 0.25) {
            return *last;
        }
        match before.try_inverse().map(|inv| last * inv * last) {
            Some(h) if h[(2, 2)].abs() > 1e-12 && h.iter().all(|v| v.is_finite()) => h / h[(2, 2)],
            _ => *last,
        }
    }

    fn remember(&mut self, report: &DetectReport, time_s: f64) {
        self.before_last = match (&self.last, &report.detection) {
            (Some(last), Some(_)) => Some((last.homography, last.time_s)),
            _ => None,
        };
        // The last outlet's vector is reused for this one's holes.
        let mut holes = self.last.take().map(|last| last.holes).unwrap_or_default();
        self.last = report.detection.as_ref().map(|d| {
            holes.clear();
            holes.extend(d.holes.iter().map(|h| h.pixel));
            LastOutlet { holes, time_s, homography: d.homography, score: d.score }
        });
    }

    /// The window (`[x, y, width, height]`) in which a frame of `size` captured
    /// at `time_s` is to be searched first, or None for the whole frame. The
    /// steps of [`Self::detect_grey`] for a caller that makes the grey image
    /// itself and, while tracking, only of the window: this, then
    /// [`Self::search_window`] with the window's grey pixels, then (when that
    /// fails, or without a window) [`Self::search_full_frame`].
    pub fn window_for(&mut self, size: [u32; 2], time_s: f64) -> Option<[u32; 4]> {
        let [width, height] = size;
        let p = &self.params;
        if p.full_frame_every <= 1 || self.windows_since_full + 1 >= p.full_frame_every {
            return None;
        }
        let LastOutlet { holes, time_s: then, .. } = self.last.as_ref()?;
        let age = time_s - then;
        if !(age.is_finite() && age >= 0.0 && age <= p.max_age_s) {
            self.last = None;
            self.before_last = None;
            return None;
        }
        let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for h in holes {
            (x0, y0, x1, y1) = (x0.min(h.x), y0.min(h.y), x1.max(h.x), y1.max(h.y));
        }
        let extent = (x1 - x0).max(y1 - y0);
        let margin = (extent * (p.margin + p.margin_per_s * age)).max(p.min_margin_px);
        if !(extent.is_finite() && margin.is_finite()) {
            return None;
        }
        let clamp = |v: f64, size: u32| v.clamp(0.0, size as f64);
        let (left, top) = (clamp((x0 - margin).floor(), width), clamp((y0 - margin).floor(), height));
        let (right, bottom) = (clamp((x1 + margin).ceil() + 1.0, width), clamp((y1 + margin).ceil() + 1.0, height));
        let (w, h) = (right - left, bottom - top);
        // A window that is most of the frame saves nothing.
        if w < 1.0 || h < 1.0 || w * h > 0.6 * width as f64 * height as f64 {
            return None;
        }
        Some([left as u32, top as u32, w as u32, h as u32])
    }
}

/// The smallest distance between two of the holes (pixels); 0 for fewer than two.
fn closest_spacing(holes: &[Point2<f64>]) -> f64 {
    let mut closest = f64::INFINITY;
    for (i, a) in holes.iter().enumerate() {
        for b in &holes[i + 1..] {
            closest = closest.min((a - b).norm());
        }
    }
    if closest.is_finite() { closest } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tracking(holes: &[(f64, f64)], time_s: f64) -> Tracker {
        let mut t = Tracker::new(TrackParams::default());
        t.last = Some(LastOutlet {
            holes: holes.iter().map(|&(x, y)| Point2::new(x, y)).collect(),
            time_s,
            homography: Matrix3::identity(),
            score: 0,
        });
        t
    }

    const HOLES: [(f64, f64); 3] = [(300.0, 200.0), (340.0, 200.0), (320.0, 260.0)];

    #[test]
    fn the_window_holds_the_last_holes_with_a_margin_growing_with_time() {
        let w = tracking(&HOLES, 0.0).window_for([640, 480], 1.0 / 30.0).expect("a window");
        let [x, y, width, height] = w.map(f64::from);
        for (u, v) in HOLES {
            assert!(u - x >= 18.0 && x + width - u >= 18.0 && v - y >= 18.0 && y + height - v >= 18.0, "{w:?}");
        }
        let later = tracking(&HOLES, 0.0).window_for([640, 480], 0.2).expect("a window");
        assert!(later[2] > w[2] && later[3] > w[3], "{later:?} against {w:?}");
    }

    #[test]
    fn a_window_is_clipped_to_the_image() {
        let edge = [(620.0, 20.0), (639.0, 20.0), (630.0, 60.0)];
        let [x, y, width, height] = tracking(&edge, 0.0).window_for([640, 480], 0.01).expect("a window");
        assert!(x + width <= 640 && y + height <= 480 && width > 0 && height > 0);
    }

    #[test]
    fn old_or_backward_or_broken_times_and_every_nth_frame_search_the_whole_frame() {
        for time in [0.6, -0.1, f64::NAN, f64::INFINITY] {
            let mut t = tracking(&HOLES, 0.0);
            assert_eq!(t.window_for([640, 480], time), None, "at {time}");
            assert!(t.last.is_none(), "the last outlet is forgotten at {time}");
        }
        let mut t = tracking(&HOLES, 0.0);
        t.windows_since_full = TrackParams::default().full_frame_every - 1;
        assert_eq!(t.window_for([640, 480], 0.01), None, "the whole frame is due");
        let never = TrackParams { full_frame_every: 1, ..TrackParams::default() };
        let mut t = Tracker { params: never, ..tracking(&HOLES, 0.0) };
        assert_eq!(t.window_for([640, 480], 0.01), None, "tracking off");
        // An outlet that fills most of the frame: nothing to save.
        let large = [(10.0, 10.0), (630.0, 10.0), (320.0, 470.0)];
        assert_eq!(tracking(&large, 0.0).window_for([640, 480], 0.01), None);
        assert_eq!(Tracker::default().window_for([640, 480], 0.0), None, "no outlet yet");
    }
}
