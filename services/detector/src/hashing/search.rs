//! The online half: the voting of online bases, and each hypothesis scored
//! (equation (2)), refined and verified (leave-one-out); the candidates and
//! their grid are in `grid`.

use super::fit::{apply, fit_affine, fit_homography, fit_planar_pose};
use super::grid::{Candidates, Grid};
use super::{HashParams, HashTable, MAX_TEMPLATE_HOLES, cross, view_axis_ratio};
use nalgebra::{Matrix2, Matrix3, Point2};
use std::collections::HashSet;

/// No candidate (in assignments).
pub(super) const NONE: u32 = u32::MAX;

/// Every template hole's predicted position and apparent size (pixels).
#[derive(Clone, Copy)]
pub(super) struct Projection {
    pub(super) pos: [Point2<f64>; MAX_TEMPLATE_HOLES],
    pub(super) size: [f64; MAX_TEMPLATE_HOLES],
    /// The smallest axis ratio over the holes: cos of the most oblique view.
    pub(super) min_axis_ratio: f64,
}

/// A hypothesis that passed every check.
pub(super) struct Accepted {
    pub(super) score: usize,
    pub(super) rms_px: f64,
    /// See [`Search::log_nfa`].
    pub(super) log_nfa: f64,
    /// Every hole predicted inside the image (true when its size is unknown).
    pub(super) in_view: bool,
    pub(super) transform: Matrix3<f64>,
    pub(super) projection: Projection,
    /// Offset of its assignment in `Search::accepted_assignments`.
    pub(super) start: usize,
    pub(super) key: u64,
}

pub(super) type Assignment = [u32; MAX_TEMPLATE_HOLES];

pub(super) fn assignment_hash(a: &[u32]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &x in a {
        h ^= x as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
        h ^= h >> 29;
    }
    h
}

/// One call's state: candidates, their grid, scratch, and what was found; the
/// vectors and sets are the thread's, kept between calls ([`Buffers`]).
pub(super) struct Search<'a> {
    pub(super) table: &'a HashTable,
    pub(super) params: &'a HashParams,
    pub(super) cand: &'a Candidates,
    pub(super) grid: &'a Grid,
    pub(super) holes: usize,
    pub(super) template_class: [u8; MAX_TEMPLATE_HOLES],
    pub(super) min_score: usize,
    /// `used[i] == stamp`: candidate i is taken in the current scoring.
    pub(super) used: &'a mut Vec<u32>,
    pub(super) stamp: u32,
    /// Affine assignments already refined.
    pub(super) tried: &'a mut HashSet<u64>,
    /// Final assignments already accepted.
    pub(super) seen: &'a mut HashSet<u64>,
    /// Refined assignments with enough matches, `holes` entries each.
    pub(super) refined: &'a mut Vec<u32>,
    pub(super) accepted: &'a mut Vec<Accepted>,
    pub(super) accepted_assignments: &'a mut Vec<u32>,
    pub(super) hypotheses: usize,
    /// The template's half turn (see [`HashTable::half_turn`]).
    pub(super) half_turn: Option<(Point2<f64>, &'a [Option<usize>])>,
    /// Hypotheses implicitly tested: online bases times model bases of their
    /// class signature.
    pub(super) tests: usize,
}

/// Where `t` puts template point `h` and d(pixel)/d(template) there; `None`
/// where the point is not in front of the camera (NaN included).
fn local_map(t: &Matrix3<f64>, h: Point2<f64>) -> Option<(Point2<f64>, Matrix2<f64>)> {
    let w = t[(2, 0)] * h.x + t[(2, 1)] * h.y + t[(2, 2)];
    // Written so that NaN fails it.
    let in_front = w > 1e-12;
    if !in_front {
        return None;
    }
    let u = (t[(0, 0)] * h.x + t[(0, 1)] * h.y + t[(0, 2)]) / w;
    let v = (t[(1, 0)] * h.x + t[(1, 1)] * h.y + t[(1, 2)]) / w;
    let jac = Matrix2::new(
        (t[(0, 0)] - u * t[(2, 0)]) / w,
        (t[(0, 1)] - u * t[(2, 1)]) / w,
        (t[(1, 0)] - v * t[(2, 0)]) / w,
        (t[(1, 1)] - v * t[(2, 1)]) / w,
    );
    Some((Point2::new(u, v), jac))
}

impl<'a> Search<'a> {
    /// Transform's predicted positions and sizes, or `None` when the transform is
    /// implausible: a hole behind the camera, a mirror, degenerate, too oblique,
    /// or too much perspective.
    pub(super) fn project(&self, t: &Matrix3<f64>) -> Option<Projection> {
        let p = self.params;
        let mut out = Projection {
            pos: [Point2::origin(); MAX_TEMPLATE_HOLES],
            size: [0.0; MAX_TEMPLATE_HOLES],
            min_axis_ratio: 1.0,
        };
        let (mut smin, mut smax) = (f64::INFINITY, 0.0f64);
        for (j, h) in self.table.points.iter().enumerate() {
            let (at, jac) = local_map(t, *h)?;
            let det = jac.determinant();
            let ratio = view_axis_ratio(&jac, at, p.intrinsics.as_ref());
            let plausible =
                det > 0.0 && at.x.is_finite() && at.y.is_finite() && ratio >= p.min_axis_ratio - p.hole_axis_slack;
            if !plausible {
                return None;
            }
            out.min_axis_ratio = out.min_axis_ratio.min(ratio);
            let scale = det.sqrt();
            smin = smin.min(scale);
            smax = smax.max(scale);
            out.pos[j] = at;
            out.size[j] = p.hole_size * scale;
        }
        // The view's angle is the one at the outlet's centre; each hole may be a
        // little steeper (`HashParams::hole_axis_slack`).
        let (centre, jac) = local_map(t, self.table.centroid)?;
        // NaN fails it too.
        let within = view_axis_ratio(&jac, centre, p.intrinsics.as_ref()) >= p.min_axis_ratio;
        if !within {
            return None;
        }
        let bounded_perspective = smax <= p.max_scale_variation * smin;
        if !bounded_perspective {
            return None;
        }
        if let Some([lo, hi]) = p.scale_range
            && !(smin >= lo && smax <= hi)
        {
            return None;
        }
        Some(out)
    }

    pub(super) fn max_dist(&self, predicted_size: f64) -> f64 {
        (self.params.max_dist_ratio * predicted_size).max(self.params.min_max_dist_px)
    }

    pub(super) fn size_agrees(&self, candidate: f64, predicted: f64) -> bool {
        let tol = self.params.size_tolerance;
        candidate <= predicted * tol && candidate * tol >= predicted
    }

    /// A fresh mark for `used`.
    pub(super) fn next_stamp(&mut self) {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.used.fill(0);
            self.stamp = 1;
        }
    }

    /// Equation (2) with sizes: per template hole in order, the nearest unused
    /// candidate of its class within MaxDist whose size agrees.
    pub(super) fn score(&mut self, proj: &Projection, assignment: &mut Assignment) -> usize {
        self.next_stamp();
        let mut score = 0;
        for (j, matched) in assignment.iter_mut().enumerate().take(self.holes) {
            *matched = NONE;
            let class = self.template_class[j];
            if class == u8::MAX {
                continue;
            }
            let (centre, size) = (proj.pos[j], proj.size[j]);
            let r = self.max_dist(size);
            let Some([x0, x1, y0, y1]) = self.grid.cells_near(centre, r) else { continue };
            let (mut best, mut best_d2) = (NONE, r * r);
            for y in y0..y1 {
                for x in x0..x1 {
                    for &i in self.grid.cell_items(x, y) {
                        let i_ = i as usize;
                        if self.cand.class[i_] != class || self.used[i_] == self.stamp {
                            continue;
                        }
                        let d2 = (self.cand.pos[i_] - centre).norm_squared();
                        if d2 < best_d2 && self.size_agrees(self.cand.size[i_], size) {
                            best = i;
                            best_d2 = d2;
                        }
                    }
                }
            }
            if best != NONE {
                self.used[best as usize] = self.stamp;
                *matched = best;
                score += 1;
            }
        }
        score
    }

    /// Matched (template, image) pairs of an assignment.
    pub(super) fn pairs(
        &self,
        assignment: &Assignment,
    ) -> (usize, [Point2<f64>; MAX_TEMPLATE_HOLES], [Point2<f64>; MAX_TEMPLATE_HOLES]) {
        let mut src = [Point2::origin(); MAX_TEMPLATE_HOLES];
        let mut dst = [Point2::origin(); MAX_TEMPLATE_HOLES];
        let mut n = 0;
        for (j, &i) in assignment[..self.holes].iter().enumerate() {
            if i != NONE {
                src[n] = self.table.points[j];
                dst[n] = self.cand.pos[i as usize];
                n += 1;
            }
        }
        (n, src, dst)
    }

    /// Least-squares transform of an assignment's matches: a homography from
    /// `min_homography_matches` matches, otherwise affine, or a rigid plate's
    /// pose where the camera is known and the matches show the perspective: the
    /// affine fit leaves more than twice `position_precision_px` RMS and the
    /// pose at most half of it. Where they do not, the pose's tilt is barely
    /// determined (a small patch, far away: two tilts fit alike and extrapolate
    /// apart) and the affine map, its limit, is the safer guess; at one
    /// `position_precision_px` a blurred view at 29 cm took the pose and came
    /// out with sigmas far under its errors (BENCHMARKS.md, "Session 9").
    pub(super) fn fit(&self, assignment: &Assignment) -> Option<Matrix3<f64>> {
        let (n, src, dst) = self.pairs(assignment);
        let (src, dst) = (&src[..n], &dst[..n]);
        if n >= self.params.min_homography_matches.max(4) {
            return fit_homography(src, dst, self.table.centroid);
        }
        let affine = fit_affine(src, dst)?;
        let Some(k) = &self.params.intrinsics else { return Some(affine) };
        let sse = |t: &Matrix3<f64>| src.iter().zip(dst).map(|(s, d)| (apply(t, *s) - d).norm_squared()).sum::<f64>();
        let affine_sse = sse(&affine);
        let noise = 2.0 * self.params.position_precision_px;
        let shows_perspective = affine_sse > noise * noise * n as f64;
        if n < 4 || !shows_perspective {
            return Some(affine);
        }
        match fit_planar_pose(src, dst, k, self.table.centroid) {
            Some(pose) if sse(&pose) <= 0.25 * affine_sse => Some(pose),
            _ => Some(affine),
        }
    }

    /// Scores the affine transform of a model basis on an online basis, refines
    /// it and keeps it when it passes every check.
    pub(super) fn evaluate(&mut self, model: usize, online: [usize; 3]) {
        let table = self.table;
        let o = usize::from(table.bases[model][0]);
        let (h0, h1, h2) = (self.cand.pos[online[0]], self.cand.pos[online[1]], self.cand.pos[online[2]]);
        let linear = Matrix2::from_columns(&[h1 - h0, h2 - h0]) * table.basis_inverse[model];
        let det = linear.determinant();
        // A mirror (det < 0), degenerate or too oblique: no view of the front.
        let ratio = view_axis_ratio(&linear, h0, self.params.intrinsics.as_ref());
        let plausible = det > 0.0 && ratio >= self.params.min_axis_ratio;
        if !plausible {
            return;
        }
        if let Some([lo, hi]) = self.params.scale_range
            && !(det.sqrt() >= lo && det.sqrt() <= hi)
        {
            return;
        }
        // The basis candidates' sizes must agree with the scale they imply.
        let predicted = self.params.hole_size * det.sqrt();
        if !online.iter().all(|&i| self.size_agrees(self.cand.size[i], predicted)) {
            return;
        }
        let t0 = table.points[o];
        let shift = h0.coords - linear * t0.coords;
        let affine = Matrix3::new(
            linear[(0, 0)],
            linear[(0, 1)],
            shift.x,
            linear[(1, 0)],
            linear[(1, 1)],
            shift.y,
            0.0,
            0.0,
            1.0,
        );
        self.hypotheses += 1;
        let Some(proj) = self.project(&affine) else { return };
        let mut assignment = [NONE; MAX_TEMPLATE_HOLES];
        let mut score = self.score(&proj, &mut assignment);
        // Three are the basis; at least one more must agree before refining.
        if score < 4 || !self.tried.insert(assignment_hash(&assignment[..self.holes])) {
            return;
        }
        // Part of an outlet already refined: it would refine to the same.
        let n = self.holes;
        let part_of = |found: &[u32]| assignment[..n].iter().zip(found).all(|(&a, &f)| a == NONE || a == f);
        if self.refined.chunks_exact(n).any(part_of) {
            return;
        }
        for _ in 0..self.params.refine_iterations {
            let Some(t) = self.fit(&assignment) else { break };
            let Some(proj) = self.project(&t) else { break };
            let mut next = [NONE; MAX_TEMPLATE_HOLES];
            let next_score = self.score(&proj, &mut next);
            if next_score < score {
                break;
            }
            let changed = next[..self.holes] != assignment[..self.holes];
            assignment = next;
            score = next_score;
            if !changed {
                break;
            }
        }
        if score < self.min_score {
            return;
        }
        self.refined.extend_from_slice(&assignment[..n]);
        self.accept(assignment);
    }

    /// Verifies a hypothesis with enough matches and keeps it. Each match must be
    /// predicted by the others (a fit without it) within `max_loo_ratio` of its
    /// size; the worst offender is dropped until all are. A fit through a match
    /// absorbs part of its error, so chance matches pass an ordinary residual test
    /// far more often than this one.
    pub(super) fn accept(&mut self, mut assignment: Assignment) {
        let key = assignment_hash(&assignment[..self.holes]);
        if !self.seen.insert(key) {
            return;
        }
        let Some(mut transform) = self.fit(&assignment) else { return };
        let Some(mut projection) = self.project(&transform) else { return };
        let mut errors = [0.0f64; MAX_TEMPLATE_HOLES];
        loop {
            let mut n = 0;
            let mut worst = (0.0f64, NONE);
            for j in 0..self.holes {
                let i = assignment[j];
                if i == NONE {
                    continue;
                }
                n += 1;
                assignment[j] = NONE;
                let predicted = self.fit(&assignment).map(|t| apply(&t, self.table.points[j]));
                assignment[j] = i;
                errors[j] = predicted.map_or(f64::INFINITY, |p| (p - self.cand.pos[i as usize]).norm());
                let ratio = errors[j] / projection.size[j];
                // NaN is the worst of all.
                if ratio.is_nan() || ratio > worst.0 {
                    worst = (ratio, j as u32);
                }
            }
            if n < self.min_score {
                return;
            }
            if worst.0 <= self.params.max_loo_ratio {
                break;
            }
            if worst.1 == NONE {
                return; // only NaN limits: nothing to drop
            }
            assignment[worst.1 as usize] = NONE;
            if n - 1 < self.min_score {
                return;
            }
            let Some(t) = self.fit(&assignment) else { return };
            let Some(p) = self.project(&t) else { return };
            transform = t;
            projection = p;
        }
        let (mut sum, mut score) = (0.0, 0usize);
        for (j, &i) in assignment[..self.holes].iter().enumerate() {
            if i != NONE {
                let d = (self.cand.pos[i as usize] - projection.pos[j]).norm();
                let near = d < self.max_dist(projection.size[j]);
                if !near {
                    return;
                }
                sum += d * d;
                score += 1;
            }
        }
        // A steeper view is a larger family of transforms, so more room for a
        // coincidence: beyond the oblique limit, more holes are needed.
        if projection.min_axis_ratio < self.params.oblique_axis_ratio
            && score < self.min_score + self.params.oblique_extra_holes
        {
            return;
        }
        // A hole predicted outside the image cannot be checked: an outlet partly
        // out of view is not reported, but it still rivals other interpretations.
        let in_view = self.params.image_size.is_none_or(|[width, height]| {
            let inside = |p: &Point2<f64>| (-0.5..=width - 0.5).contains(&p.x) && (-0.5..=height - 0.5).contains(&p.y);
            projection.pos[..self.holes].iter().all(inside)
        });
        let key = assignment_hash(&assignment[..self.holes]);
        if self.accepted.iter().any(|a| a.key == key) {
            return;
        }
        let start = self.accepted_assignments.len();
        self.accepted_assignments.extend_from_slice(&assignment[..self.holes]);
        let rms_px = (sum / score as f64).sqrt();
        let log_nfa = self.log_nfa(&assignment, &projection, &errors);
        self.accepted.push(Accepted { score, rms_px, log_nfa, in_view, transform, projection, start, key });
    }
}

/// The voting state of the online stage.
pub(super) struct Online<'a> {
    /// Votes per model basis; zero outside `vote`.
    pub(super) votes: &'a mut Vec<u16>,
    /// Model bases with a vote, to reset.
    pub(super) touched: &'a mut Vec<u32>,
    pub(super) min_votes: u16,
}

/// The vectors and sets of a search, kept by each thread between calls: a
/// frame hashes once or a few times, each taking some thirty of them.
#[derive(Default)]
pub(super) struct Buffers {
    pub(super) cand: Candidates,
    pub(super) grid: Grid,
    pub(super) sorted_sizes: Vec<f64>,
    pub(super) used: Vec<u32>,
    pub(super) tried: HashSet<u64>,
    pub(super) seen: HashSet<u64>,
    pub(super) refined: Vec<u32>,
    pub(super) accepted: Vec<Accepted>,
    pub(super) accepted_assignments: Vec<u32>,
    pub(super) hood_start: Vec<u32>,
    pub(super) hood: Vec<u32>,
    pub(super) near: Vec<(f64, u32)>,
    pub(super) votes: Vec<u16>,
    pub(super) touched: Vec<u32>,
    pub(super) bases_seen: HashSet<u64>,
}

impl Online<'_> {
    /// Hashes the candidates `hashed` in the online basis `basis` (origin, a, b),
    /// counts the votes of the model bases and evaluates those with enough.
    pub(super) fn vote(&mut self, search: &mut Search, basis: [usize; 3], hashed: &[u32]) {
        let table = search.table;
        let [o, a, b] = basis;
        let cand = &search.cand;
        let signature = (cand.class[o] * 4 + cand.class[a] * 2 + cand.class[b]) as usize;
        if table.signature_bases[signature] == 0 {
            return;
        }
        // Every model basis of this signature is a hypothesis tested, voted for or
        // not: the votes select by the very evidence that is judged.
        search.tests += table.signature_bases[signature] as usize;
        let origin = cand.pos[o];
        let (u, v) = (cand.pos[a] - origin, cand.pos[b] - origin);
        // Affine coordinates (p, q) of d = p u + q v, straight in bins:
        // bin = (coordinate + range) * bins / (2 range).
        let per_unit = table.bins as f64 / (2.0 * table.range);
        let (scale, offset) = (per_unit / cross(u, v), table.range * per_unit);
        let limit = table.bins as f64;
        for &other in hashed {
            let other = other as usize;
            if other == a || other == b {
                continue;
            }
            let d = cand.pos[other] - origin;
            let x = cross(d, v) * scale + offset;
            let y = cross(u, d) * scale + offset;
            // NaN fails these comparisons too.
            if !(x >= 0.0 && x < limit && y >= 0.0 && y < limit) {
                continue;
            }
            let bucket = table.bucket(signature, cand.class[other] as usize, x as usize, y as usize);
            for &model in table.bucket_entries(bucket) {
                let count = &mut self.votes[model as usize];
                if *count == 0 {
                    self.touched.push(model);
                }
                *count = count.saturating_add(1);
            }
        }
        for &model in self.touched.iter() {
            let model = model as usize;
            if self.votes[model] >= self.min_votes {
                search.evaluate(model, basis);
            }
            self.votes[model] = 0;
        }
        self.touched.clear();
    }
}

/// The triangle's corners reordered from its widest angle, or `None` when it is
/// nearly flat (sine of that angle below `sin_min`).
pub(super) fn widest_corner(pos: &[Point2<f64>], corners: [usize; 3], sin_min: f64) -> Option<[usize; 3]> {
    let [c0, c1, c2] = corners;
    let (p0, p1, p2) = (pos[c0], pos[c1], pos[c2]);
    // The widest angle is opposite the longest side.
    let (l0, l1, l2) = ((p1 - p2).norm_squared(), (p0 - p2).norm_squared(), (p0 - p1).norm_squared());
    let [o, a, b] = if l0 >= l1 && l0 >= l2 {
        [c0, c1, c2]
    } else if l1 >= l2 {
        [c1, c0, c2]
    } else {
        [c2, c0, c1]
    };
    let (u, v) = (pos[a] - pos[o], pos[b] - pos[o]);
    if cross(u, v).abs() >= sin_min * u.norm() * v.norm() { Some([o, a, b]) } else { None }
}
