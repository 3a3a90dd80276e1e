//! Classification: a point's normalised crop projected into PCA space and the
//! class of its nearest training sample, at one scale, several, or the scales a
//! candidate's size implies.

use super::poses::{crop_offsets, normalise};
use super::{CLASSES, Classification, DescriptorParams, MAX_CROP, OneWayDescriptor, TrainingFeature};
use crate::{Candidate, Class};
use image::GrayImage;
use nalgebra::Point2;

thread_local! {
    /// The search's per-group bounds, kept between calls.
    static BOUNDS: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
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
    pub(super) fn project(&self, sample: &[f32], out: &mut [f32]) {
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

    /// Nearest squared distance per class to the projected query (exact).
    fn nearest(&self, query: &[f32]) -> [f32; 3] {
        crate::with_scratch(&BOUNDS, |bounds| self.index.nearest(query, bounds))
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
        self.choose_hole_class(p, g)
    }

    /// [`Self::classify_candidate`] over `spread` ladder steps either side of
    /// each scale the candidate's size implies, each hole class at the scale
    /// where its nearest sample is nearest. A dark blob's extent is a loose
    /// measure of a hole's scale (small and blurred holes, a slot's shaded
    /// ends, contacts shining inside), so the implied scale can be a step off.
    pub fn classify_candidate_spread(&self, grey: &GrayImage, candidate: &Candidate, spread: u32) -> Classification {
        if spread == 0 {
            return self.classify_candidate(grey, candidate);
        }
        let [lo, hi] = self.params.scale_range.map(|r| r * self.reference_scale);
        let implied = self.params.candidate_scales(candidate.size).map(|s| s.clamp(lo, hi));
        let step = self.params.scale_step;
        let spread = spread as i32;
        let [p, g] = [0, 1].map(|class| {
            let scale_at = |k: i32| (implied[class] * step.powi(k)).clamp(lo, hi);
            let mut best = self.classify(grey, candidate.centre, scale_at(-spread));
            let mut last = best.scale;
            for k in 1 - spread..=spread {
                // Steps past the ladder's ends clamp to the same scale: once is enough.
                let scale = scale_at(k);
                if scale == last {
                    continue;
                }
                last = scale;
                let c = self.classify(grey, candidate.centre, scale);
                if c.class_distances[class] < best.class_distances[class] {
                    best = c;
                }
            }
            best
        });
        self.choose_hole_class(p, g)
    }

    /// The decision between a candidate classified at a power hole's scale (`p`)
    /// and at a ground hole's scale (`g`).
    fn choose_hole_class(&self, p: Classification, g: Classification) -> Classification {
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
