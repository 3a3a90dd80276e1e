//! One level's looks: candidates, their classes, hashing over the hole-classed
//! ones, and verification of what hashing found, again with relaxed classes
//! while nothing is found. The vectors of each step are the thread's, kept
//! between frames.

use super::{Detection, Detector, FARTHEST_OUTLET_MM, Hypothesis, Lens, Refusals, StageTimes, ms_since};
use crate::candidates::find_candidates_into;
use crate::descriptor::Classification;
use crate::hashing::{HashParams, Intrinsics, OutletMatch, find_outlet_into};
use crate::{Candidate, Class};
use image::GrayImage;
use nalgebra::{Matrix3, Point2};
use outlet_protocol::CameraModel;
use std::time::Instant;

/// The vectors of a level's looks, kept by each thread between frames
/// ([`Detector::looks`]).
#[derive(Default)]
pub(super) struct LevelScratch {
    candidates: Vec<Candidate>,
    classifications: Vec<Classification>,
    relaxed: Vec<(Candidate, Class)>,
    third: Vec<(Candidate, Class)>,
    swapped: Vec<(Candidate, Class)>,
}

/// The hashing's inputs and answer in [`Detector::search`], kept by each
/// thread between frames.
#[derive(Default)]
struct SearchScratch {
    holes: Vec<(Candidate, Class)>,
    points: Vec<Point2<f64>>,
    classes: Vec<Class>,
    sizes: Vec<f64>,
    guesses: Vec<Option<Point2<f64>>>,
    found: OutletMatch,
}

thread_local! {
    pub(super) static LEVEL_SCRATCH: std::cell::RefCell<LevelScratch> = std::cell::RefCell::new(LevelScratch::default());
    static SEARCH_SCRATCH: std::cell::RefCell<SearchScratch> = std::cell::RefCell::new(SearchScratch::default());
}

impl Detector {
    /// The looks of [`Self::detect_level`] at this level: candidates,
    /// classes, hashing and verification, then the later looks with relaxed
    /// classes while none is found. The outlet or why not; the report's
    /// candidates go to `classified`. `t` is when the level began.
    #[allow(clippy::too_many_arguments)] // the level's inputs and what it accumulates
    pub(super) fn looks(
        &self,
        grey: &GrayImage,
        camera: Option<&CameraModel>,
        min_contrast: f32,
        t: Instant,
        times: &mut StageTimes,
        refused: &mut Refusals,
        scratch: &mut LevelScratch,
        classified: &mut Vec<(Candidate, Class)>,
    ) -> (Option<Detection>, Option<String>) {
        let LevelScratch { candidates, classifications, relaxed, third, swapped } = scratch;
        find_candidates_into(grey, &self.params.candidates, min_contrast, candidates);
        // Highest contrast first, as they come (a stable sort of sorted ones
        // would change nothing, and takes a buffer beyond a hundred or so).
        let by_contrast = |a: &Candidate, b: &Candidate| b.contrast.total_cmp(&a.contrast);
        if !candidates.is_sorted_by(|a, b| by_contrast(a, b).is_le()) {
            candidates.sort_by(by_contrast);
        }
        candidates.truncate(self.params.max_candidates);
        times.candidates = ms_since(t);

        let t = Instant::now();
        classifications.clear();
        classifications.extend(candidates.iter().map(|c| self.template.descriptor.classify_candidate(grey, c)));
        // The report's own vector.
        classified.clear();
        classified.extend(candidates.iter().zip(classifications.iter()).map(|(c, k)| (*c, k.class)));
        let classified: &[(Candidate, Class)] = classified;
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
        let (mut detection, mut rejected) = self.search(grey, &lens, classified, &hash, times, refused);
        // A reading the level above verified (`Refusals::escalate`) ends the looks.
        if detection.is_none() && refused.escalated.is_none() && self.params.second_look_margin > 0.0 {
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
            relaxed.clear();
            relaxed.extend(candidates.iter().zip(classifications.iter()).map(|(c, k)| (*c, relax(k))));
            if relaxed.iter().zip(classified).any(|(a, b)| a.1 != b.1) {
                let (second, why) = self.search(grey, &lens, relaxed, &hash, times, refused);
                detection = second;
                rejected = why.or(rejected);
            }
            let spread = self.params.third_look_spread;
            if detection.is_none() && refused.escalated.is_none() && spread > 0 {
                // A third look, only after the first two found nothing (what
                // they find stays as it was): the candidates still background
                // at the scale their size implies, looked at a step either side.
                let t = Instant::now();
                third.clear();
                third.extend(relaxed.iter().map(|&(c, class)| match class {
                    Class::Background => {
                        (c, relax(&self.template.descriptor.classify_candidate_spread(grey, &c, spread)))
                    }
                    class => (c, class),
                }));
                times.classify += ms_since(t);
                if third.iter().zip(relaxed.iter()).any(|(a, b)| a.1 != b.1) {
                    let (found, why) = self.search(grey, &lens, third, &hash, times, refused);
                    detection = found;
                    rejected = why.or(rejected);
                }
            }
            let swap = self.params.swap_look_margin;
            if detection.is_none() && refused.escalated.is_none() && swap > 0.0 {
                // Where the descriptor nearly could not tell the hole classes
                // apart, the candidate also counts as the other class (a copy at
                // the same place: one place can match only one hole).
                swapped.clear();
                swapped.extend_from_slice(relaxed);
                for (&(c, class), k) in relaxed.iter().zip(classifications.iter()) {
                    let [p, g, _] = k.class_distances;
                    match class {
                        Class::Power if g < p + swap => swapped.push((c, Class::Ground)),
                        Class::Ground if p < g + swap => swapped.push((c, Class::Power)),
                        _ => {}
                    }
                }
                if swapped.len() > relaxed.len() {
                    let (found, why) = self.search(grey, &lens, swapped, &hash, times, refused);
                    detection = found;
                    rejected = why.or(rejected);
                }
            }
        }
        (detection, rejected)
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
        refused: &mut Refusals,
    ) -> (Option<Detection>, Option<String>) {
        crate::with_scratch(&SEARCH_SCRATCH, |scratch| {
            self.search_with(grey, lens, classified, hash, times, refused, scratch)
        })
    }

    #[allow(clippy::too_many_arguments)] // [`Self::search`]'s, and the thread's vectors
    fn search_with(
        &self,
        grey: &GrayImage,
        lens: &Lens,
        classified: &[(Candidate, Class)],
        hash: &HashParams,
        times: &mut StageTimes,
        refused: &mut Refusals,
        scratch: &mut SearchScratch,
    ) -> (Option<Detection>, Option<String>) {
        let t = Instant::now();
        let SearchScratch { holes, points, classes, sizes, guesses, found: m } = scratch;
        holes.clear();
        holes.extend(classified.iter().filter(|(_, class)| *class != Class::Background));
        points.clear();
        points.extend(holes.iter().map(|(c, _)| lens.undistort(c.centre)));
        classes.clear();
        classes.extend(holes.iter().map(|(_, class)| *class));
        sizes.clear();
        sizes.extend(holes.iter().map(|(c, _)| c.size[0].max(c.size[1]) as f64));
        let found = find_outlet_into(&self.table, points, classes, sizes, hash, m);
        times.hash += ms_since(t);
        if !found {
            return (None, None);
        }
        let t = Instant::now();
        guesses.clear();
        guesses.extend(m.assignment.iter().map(|a| a.and_then(|k| holes.get(k).map(|(c, _)| c.centre))));
        // A later look with more candidates often finds the same reading again:
        // verification would refuse it again, for the same reason.
        let same = |h: &&Hypothesis| h.transform == m.transform && h.guesses == *guesses && h.score == m.score;
        if let Some(h) = refused.list.iter().find(same) {
            tracing::debug!(reason = %h.why, "the same reading as one refused before");
            return (None, Some(h.why.clone()));
        }
        let result = self.refine_either(grey, lens, &m.transform, guesses, m.score);
        if let Err(why) = &result {
            let guesses = guesses.clone();
            let hypothesis = Hypothesis { transform: m.transform, guesses, score: m.score, why: why.clone() };
            if let Some(escalate) = refused.escalate.as_mut() {
                refused.escalated = escalate(&hypothesis);
            }
            refused.list.push(hypothesis);
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
    pub(super) fn refine_either(
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
            crate::with_scratch(&super::GUESS_SCRATCH, |turned| {
                turned.clear();
                turned.extend(image.iter().map(|k| k.and_then(|k| guesses.get(k).copied().flatten())));
                self.refine(grey, lens, &(transform * turn), turned, score)
            })
            .map_err(|turned_why| format!("{why}; half-turned: {turned_why}"))
        })
    }
}
