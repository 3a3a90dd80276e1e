//! Significance and ambiguity: the a-contrario number of false alarms of a
//! verified hypothesis, and the decision for the best one or none.

use super::MAX_TEMPLATE_HOLES;
use super::search::{Assignment, NONE, Projection, Search};
use crate::Class;
use nalgebra::{Point2, Vector2};

impl Search<'_> {
    /// ln of the expected number of chance hypotheses as good as this one, per
    /// hypothesis tried (a-contrario, as AC-RANSAC): the candidates around the
    /// outlet that it does not use are taken as uniform clutter of their local
    /// density; a hole is matched by chance within radius r with probability
    /// alpha = density x pi r^2, r its leave-one-out error. Three matches fix the
    /// transform and are free (the three least significant); k of the other n - 3
    /// holes all within the k-th smallest radius: C(n - 3, k) alpha_k^k, the best k.
    pub(super) fn log_nfa(&mut self, assignment: &Assignment, projection: &Projection, errors: &[f64]) -> f64 {
        let n = self.holes;
        let centre = projection.pos[..n].iter().fold(Vector2::zeros(), |acc, p| acc + p.coords) / n as f64;
        let centre = Point2::from(centre);
        let (mut spread, mut largest) = (0.0f64, 0.0f64);
        for (p, &size) in projection.pos[..n].iter().zip(&projection.size[..n]) {
            spread = spread.max((p - centre).norm());
            largest = largest.max(size);
        }
        // The window around the outlet, within the image when its size is known:
        // outside it there can be no clutter to count.
        let reach = 2.0 * spread + largest;
        let (mut lo, mut hi) = (centre - Vector2::repeat(reach), centre + Vector2::repeat(reach));
        if let Some([width, height]) = self.params.image_size {
            lo = Point2::new(lo.x.max(-0.5), lo.y.max(-0.5));
            hi = Point2::new(hi.x.min(width - 0.5), hi.y.min(height - 0.5));
        }
        let area = (hi.x - lo.x).max(largest) * (hi.y - lo.y).max(largest);
        self.next_stamp();
        for &i in &assignment[..n] {
            if i != NONE {
                self.used[i as usize] = self.stamp;
            }
        }
        let mut alphas = [1.0f64; MAX_TEMPLATE_HOLES];
        let mut m = 0;
        for j in 0..n {
            if assignment[j] == NONE {
                continue;
            }
            let (class, size) = (self.template_class[j], projection.size[j]);
            let mut count = 0usize;
            for i in 0..self.cand.len() {
                if self.used[i] != self.stamp
                    && self.cand.class[i] == class
                    && self.size_agrees(self.cand.size[i], size)
                    && (lo.x..=hi.x).contains(&self.cand.pos[i].x)
                    && (lo.y..=hi.y).contains(&self.cand.pos[i].y)
                {
                    count += 1;
                }
            }
            let r = errors[j].max(self.params.position_precision_px).max(1e-6);
            alphas[m] = ((count + 1) as f64 / area * std::f64::consts::PI * r * r).min(1.0);
            m += 1;
        }
        if m < 4 {
            return f64::INFINITY;
        }
        alphas[..m].sort_unstable_by(f64::total_cmp);
        let evidence = m - 3;
        let mut best = f64::INFINITY;
        for k in 1..=evidence {
            best = best.min(ln_binomial(n - 3, k) + k as f64 * alphas[k - 1].ln());
        }
        // k was chosen among `evidence` values.
        best + (evidence as f64).ln()
    }

    pub(super) fn assignment_of(&self, k: usize) -> &[u32] {
        let s = self.accepted[k].start;
        &self.accepted_assignments[s..s + self.holes]
    }

    /// True when `other` matches the candidates of `mine` to the half-turned
    /// holes: each power hole's candidate is the half-turned hole's in `other`.
    pub(super) fn is_half_turn_twin(&self, mine: &[u32], other: &[u32]) -> bool {
        let Some((_, image)) = &self.half_turn else { return false };
        let mut agree = 0;
        for (j, &candidate) in mine.iter().enumerate() {
            if candidate == NONE || self.table.classes[j] != Class::Power {
                continue;
            }
            match image[j] {
                Some(k) if other[k] == candidate => agree += 1,
                _ => return false,
            }
        }
        agree >= 3
    }

    /// The best significant hypothesis, if no other verified interpretation (a
    /// coincidence counts too) rivals it.
    pub(super) fn decide(&self) -> Option<usize> {
        let log_tests = (self.tests.max(1) as f64).ln();
        let limit = self.params.max_nfa.ln();
        let eligible = |k: &usize| self.accepted[*k].in_view && self.accepted[*k].log_nfa + log_tests <= limit;
        let best = (0..self.accepted.len()).filter(eligible).min_by(|&x, &y| {
            let (a, b) = (&self.accepted[x], &self.accepted[y]);
            b.score.cmp(&a.score).then(a.rms_px.total_cmp(&b.rms_px))
        })?;
        let mine = self.assignment_of(best);
        let score = self.accepted[best].score;
        for k in 0..self.accepted.len() {
            if k == best {
                continue;
            }
            let other = self.assignment_of(k);
            let shared = mine.iter().zip(other).filter(|&(&x, &y)| x != NONE && x == y).count();
            if shared >= 3 {
                continue; // the same pose, matched a little differently
            }
            let relabels_mine = other.iter().all(|&i| i == NONE || mine.contains(&i));
            if relabels_mine && self.is_half_turn_twin(mine, other) {
                // The same power holes read the other way up: the image, not the
                // points, tells them apart (the detector looks at the ground holes).
                continue;
            }
            let rival = self.accepted[k].score;
            let margin = if relabels_mine { 1 } else { self.params.rival_margin.max(1) };
            if rival + margin > score {
                tracing::debug!(best = score, rival, "geometric hashing: ambiguous outlet, none reported");
                return None;
            }
        }
        Some(best)
    }
}

/// ln of the binomial coefficient C(n, k).
pub(super) fn ln_binomial(n: usize, k: usize) -> f64 {
    (0..k.min(n)).map(|i| ((n - i) as f64 / (i + 1) as f64).ln()).sum()
}
