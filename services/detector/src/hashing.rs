//! Stage 3 of the detector, geometric filtering (paper, section III.C): among the
//! classified hole candidates, the one set of holes that the outlet template
//! explains, or none.
//!
//! Offline, [`HashTable::new`] takes every ordered triple of template holes with a
//! wide enough basis angle (a *model basis*), writes every other hole in the affine
//! frame of that triple and files the basis under the hole's quantised affine
//! coordinates. Buckets are also keyed by the classes of the three basis holes and
//! of the hashed hole, so a vote needs class agreement as well as position.
//!
//! Online, [`find_outlet`] takes each candidate with pairs of its nearest
//! neighbours as bases (enumerated, not drawn: the result is reproducible; each
//! triangle once, from its widest corner), hashes the candidates around it and
//! counts the votes of each model basis. Every model basis with enough votes gives
//! an affine transform, scored with the paper's equation (2): a template hole
//! counts when a candidate of its class lies within MaxDist of its projection,
//! each candidate used once.
//!
//! Beyond the paper:
//! - camera views are perspective, not affine: a hypothesis with 4 matches is
//!   refitted to them (least squares: affine below 6 matches, normalised DLT
//!   homography from 6), re-projected and re-scored until its matches settle;
//! - MaxDist and the size check scale with the hole's predicted apparent size;
//! - guards: orientation-preserving (the camera sees the front, never a mirror
//!   image), not degenerate, at most 60 degrees off-axis, bounded perspective,
//!   candidate sizes that agree with the transform's scale;
//! - verification: every match must be predicted by a fit to the others
//!   (leave-one-out), and the result must be unlikely as a coincidence among the
//!   candidates around it (a-contrario number of false alarms, [`HashParams::max_nfa`]):
//!   4 of 6 holes suffice among few candidates, among 150 random ones they do not;
//! - the answer is "none" when another interpretation of the candidates (another
//!   place, or the same holes relabelled, e.g. turned 180 degrees) scores as well.
//!
//! A false alarm costs far more than a miss: every doubt gives "none".

use crate::Class;
use nalgebra::{Matrix2, Matrix3, Point2, SMatrix, SVector, Vector2};
use std::collections::HashSet;

/// Most holes a template may have. The table holds every ordered triple of holes,
/// each hashing all other holes, so its size grows as n^4 (24 holes: about a
/// million entries).
pub const MAX_TEMPLATE_HOLES: usize = 24;

/// Most candidates looked at; those beyond (in input order) are ignored. The
/// detector gives 30-150.
pub const MAX_CANDIDATES: usize = 2048;

/// Fewest template holes: with 3, every triple of candidates would be an outlet.
pub const MIN_TEMPLATE_HOLES: usize = 4;

const NONE: u32 = u32::MAX;
const SIGNATURES: usize = 8;

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
    /// largest off-axis angle, 0.5 = 60 degrees (the paper's views are within 40;
    /// a chance 5-of-6 among clutter was at 0.46).
    pub min_axis_ratio: f64,
    /// Local scales (sqrt of the Jacobian's determinant, pixels per template unit)
    /// an outlet may have, when the caller knows them: focal length over the
    /// working distances, e.g. 525 px / (200..500 mm) = 1.05..2.6 px/mm for the
    /// paper's 20-50 cm, with a margin. `None`: any scale.
    pub scale_range: Option<[f64; 2]>,
    /// Image width and height (pixels), when known: every hole must be predicted
    /// inside the image (an outlet partly out of view cannot be checked), and
    /// clutter density is measured in the image only. `None`: no such checks.
    pub image_size: Option<[f64; 2]>,
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
            scale_range: None,
            image_size: None,
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

/// The offline half of geometric hashing: the template's bases, filed under the
/// quantised affine coordinates of the other holes.
#[derive(Debug, Clone)]
pub struct HashTable {
    points: Vec<Point2<f64>>,
    classes: Vec<Class>,
    /// Model bases: ordered triples of hole indices (origin, a, b).
    bases: Vec<[u8; 3]>,
    /// Inverse of [t_a - t_o, t_b - t_o] per basis.
    basis_inverse: Vec<Matrix2<f64>>,
    /// Bucket b holds `bucket_bases[bucket_start[b]..bucket_start[b + 1]]`.
    bucket_start: Vec<u32>,
    bucket_bases: Vec<u32>,
    /// Model bases per class signature of the basis.
    signature_bases: [u32; SIGNATURES],
    bins: usize,
    range: f64,
    /// Largest distance between two holes (template units).
    extent: f64,
    /// Smallest distance between two holes (template units).
    min_gap: f64,
    /// Mean of the holes (template units).
    centroid: Point2<f64>,
}

/// The one outlet found.
#[derive(Debug, Clone, PartialEq)]
pub struct OutletMatch {
    /// Template (its units, mm) to image (pixels), homogeneous: a homography, or an
    /// affine transform (last row 0 0 1) when fewer than
    /// [`HashParams::min_homography_matches`] holes matched.
    pub transform: Matrix3<f64>,
    /// Template holes matched by a candidate of their class (equation (2)).
    pub score: usize,
    /// Per template hole (template order), the index of its candidate in the input.
    pub assignment: Vec<Option<usize>>,
    /// Per template hole (template order), its position predicted by `transform`.
    pub projected: Vec<Point2<f64>>,
}

fn class_index(class: Class) -> Option<u8> {
    match class {
        Class::Power => Some(0),
        Class::Ground => Some(1),
        Class::Background => None,
    }
}

fn finite_or(value: f64, fallback: f64) -> f64 {
    if value.is_finite() { value } else { fallback }
}

/// 2D cross product (z of the 3D one).
fn cross(a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Ratio of the smaller to the larger singular value of a 2x2 matrix.
fn axis_ratio(j: &Matrix2<f64>) -> f64 {
    let e = (j[(0, 0)] + j[(1, 1)]) / 2.0;
    let f = (j[(0, 0)] - j[(1, 1)]) / 2.0;
    let g = (j[(1, 0)] + j[(0, 1)]) / 2.0;
    let h = (j[(1, 0)] - j[(0, 1)]) / 2.0;
    // Values are pixels per template unit: no overflow, and hypot is slow.
    let q = (e * e + h * h).sqrt();
    let r = (f * f + g * g).sqrt();
    if q + r > 0.0 { (q - r).abs() / (q + r) } else { 0.0 }
}

impl HashTable {
    /// Builds the table of a template: hole positions (any 2D coordinates, e.g. mm
    /// in the outlet frame) and classes (`Background` holes are never matched).
    /// A template that cannot be searched (fewer than 4 or more than
    /// [`MAX_TEMPLATE_HOLES`] holes, non-finite or coincident positions, all holes
    /// collinear) gives a table with no bases, in which nothing is ever found.
    pub fn new(points: &[Point2<f64>], classes: &[Class], params: &HashParams) -> HashTable {
        let n = points.len().min(classes.len());
        let bins = params.bins.clamp(1, 256);
        let range = finite_or(params.range, 0.0);
        let mut table = HashTable {
            points: points[..n].to_vec(),
            classes: classes[..n].to_vec(),
            bases: Vec::new(),
            basis_inverse: Vec::new(),
            bucket_start: vec![0; 1],
            bucket_bases: Vec::new(),
            signature_bases: [0; SIGNATURES],
            bins,
            range,
            extent: 0.0,
            min_gap: 0.0,
            centroid: Point2::origin(),
        };
        let finite = table.points.iter().all(|p| p.x.is_finite() && p.y.is_finite());
        if !(MIN_TEMPLATE_HOLES..=MAX_TEMPLATE_HOLES).contains(&n) || !finite || range <= 0.0 {
            return table;
        }
        let mut min_gap = f64::INFINITY;
        for (i, p) in table.points.iter().enumerate() {
            for q in &table.points[i + 1..] {
                let d = (p - q).norm();
                table.extent = table.extent.max(d);
                min_gap = min_gap.min(d);
            }
        }
        if min_gap <= 1e-9 * table.extent || table.extent <= 0.0 {
            return table;
        }
        table.min_gap = min_gap;
        table.centroid = Point2::from(table.points.iter().map(|p| p.coords).sum::<Vector2<f64>>() / n as f64);

        let sin_min = finite_or(params.min_basis_angle, 0.5).clamp(0.0, std::f64::consts::FRAC_PI_2).sin().max(1e-6);
        let tolerance = finite_or(params.vote_tolerance, 0.5).clamp(0.0, 3.0);
        let class: Vec<Option<u8>> = table.classes.iter().map(|&c| class_index(c)).collect();
        let mut entries: Vec<(u32, u32)> = Vec::new();
        for (o, po) in table.points.iter().enumerate() {
            let Some(co) = class[o] else { continue };
            for (a, pa) in table.points.iter().enumerate() {
                let Some(ca) = class[a] else { continue };
                for (b, pb) in table.points.iter().enumerate() {
                    let Some(cb) = class[b] else { continue };
                    if a == o || b == o || a == b {
                        continue;
                    }
                    let (va, vb) = (pa - po, pb - po);
                    let det = cross(va, vb);
                    if det.abs() < sin_min * va.norm() * vb.norm() {
                        continue;
                    }
                    let basis = table.bases.len() as u32;
                    let signature = (co * 4 + ca * 2 + cb) as usize;
                    table.bases.push([o as u8, a as u8, b as u8]);
                    table.basis_inverse.push(Matrix2::from_columns(&[va, vb]).try_inverse().unwrap_or_default());
                    table.signature_bases[signature] += 1;
                    for (l, pl) in table.points.iter().enumerate() {
                        let Some(cl) = class[l] else { continue };
                        if l == o || l == a || l == b {
                            continue;
                        }
                        let d = pl - po;
                        let (p, q) = (cross(d, vb) / det, cross(va, d) / det);
                        // Every bin that [p - t, p + t] x [q - t, q + t] touches (t in bins).
                        let Some([x0, x1]) = table.bin_span(p, tolerance) else { continue };
                        let Some([y0, y1]) = table.bin_span(q, tolerance) else { continue };
                        for y in y0..=y1 {
                            for x in x0..=x1 {
                                let key = table.bucket(signature, cl as usize, x, y);
                                entries.push((key as u32, basis));
                            }
                        }
                    }
                }
            }
        }
        entries.sort_unstable();
        entries.dedup();
        let buckets = SIGNATURES * 2 * bins * bins;
        let mut start = vec![0u32; buckets + 1];
        for &(key, _) in &entries {
            start[key as usize + 1] += 1;
        }
        for b in 0..buckets {
            start[b + 1] += start[b];
        }
        table.bucket_start = start;
        table.bucket_bases = entries.into_iter().map(|(_, basis)| basis).collect();
        table
    }

    /// Number of template holes.
    pub fn holes(&self) -> usize {
        self.points.len()
    }

    /// Number of model bases (0: nothing can be found with this table).
    pub fn bases(&self) -> usize {
        self.bases.len()
    }

    /// Template hole positions as given.
    pub fn points(&self) -> &[Point2<f64>] {
        &self.points
    }

    /// For a template whose power holes map onto themselves under a half turn
    /// about their centroid (every US duplex), that centroid and, per hole, the
    /// hole of its class the half turn takes it to (`None` for the ground holes,
    /// which land on the plate). `None` for any other template.
    pub fn half_turn(&self) -> Option<(Point2<f64>, Vec<Option<usize>>)> {
        let power: Vec<usize> = (0..self.points.len()).filter(|&i| self.classes[i] == Class::Power).collect();
        if power.is_empty() || power.len() == self.points.len() {
            return None;
        }
        let c = power.iter().fold(Vector2::zeros(), |s, &i| s + self.points[i].coords) / power.len() as f64;
        let turned = |i: usize| Point2::from(2.0 * c - self.points[i].coords);
        let image: Vec<Option<usize>> = (0..self.points.len())
            .map(|i| {
                (0..self.points.len())
                    .find(|&k| self.classes[k] == self.classes[i] && (self.points[k] - turned(i)).norm() < 1.0)
            })
            .collect();
        let symmetric = power.iter().all(|&i| image[i].is_some());
        let grounds_apart = image.iter().enumerate().all(|(i, k)| self.classes[i] == Class::Power || k.is_none());
        (symmetric && grounds_apart).then_some((Point2::from(c), image))
    }

    /// Template hole classes as given.
    pub fn classes(&self) -> &[Class] {
        &self.classes
    }

    /// First and last bin within `tolerance` bins of a coordinate, clipped to the
    /// grid; `None` when the coordinate is off the grid.
    fn bin_span(&self, coordinate: f64, tolerance: f64) -> Option<[usize; 2]> {
        let t = (coordinate + self.range) / (2.0 * self.range) * self.bins as f64;
        if !(t >= 0.0 && t < self.bins as f64) {
            return None;
        }
        let lo = (t - tolerance).max(0.0) as usize;
        let hi = ((t + tolerance).max(0.0) as usize).min(self.bins - 1);
        Some([lo, hi])
    }

    fn bucket(&self, signature: usize, class: usize, x: usize, y: usize) -> usize {
        ((signature * 2 + class) * self.bins + y) * self.bins + x
    }

    fn bucket_entries(&self, bucket: usize) -> &[u32] {
        let (s, e) = (self.bucket_start[bucket] as usize, self.bucket_start[bucket + 1] as usize);
        &self.bucket_bases[s..e]
    }
}

/// The candidates the search works on: non-background, finite centre and size.
struct Candidates {
    pos: Vec<Point2<f64>>,
    class: Vec<u8>,
    size: Vec<f64>,
    /// Index in the caller's slices.
    index: Vec<usize>,
}

impl Candidates {
    fn new(points: &[Point2<f64>], classes: &[Class], sizes: &[f64]) -> Candidates {
        let n = points.len().min(classes.len()).min(sizes.len());
        let mut c = Candidates { pos: Vec::new(), class: Vec::new(), size: Vec::new(), index: Vec::new() };
        for i in 0..n {
            let (p, s) = (points[i], sizes[i]);
            let Some(class) = class_index(classes[i]) else { continue };
            if !(p.x.is_finite() && p.y.is_finite() && s.is_finite() && s > 0.0) {
                continue;
            }
            c.pos.push(p);
            c.class.push(class);
            c.size.push(s);
            c.index.push(i);
            if c.pos.len() == MAX_CANDIDATES {
                break;
            }
        }
        c
    }

    fn len(&self) -> usize {
        self.pos.len()
    }
}

/// A uniform grid over the candidates for radius queries.
struct Grid {
    origin: Point2<f64>,
    inv_cell: f64,
    nx: usize,
    ny: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    fn new(pos: &[Point2<f64>], cell: f64) -> Grid {
        let (mut lo, mut hi) =
            (Point2::new(f64::INFINITY, f64::INFINITY), Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY));
        for p in pos {
            lo = Point2::new(lo.x.min(p.x), lo.y.min(p.y));
            hi = Point2::new(hi.x.max(p.x), hi.y.max(p.y));
        }
        if pos.is_empty() {
            lo = Point2::origin();
            hi = Point2::origin();
        }
        let span = (hi.x - lo.x).max(hi.y - lo.y);
        let cell = cell.max(span / 128.0).max(1e-6);
        let inv_cell = 1.0 / cell;
        let nx = ((hi.x - lo.x) * inv_cell) as usize + 1;
        let ny = ((hi.y - lo.y) * inv_cell) as usize + 1;
        let mut grid = Grid { origin: lo, inv_cell, nx, ny, start: vec![0; nx * ny + 1], items: vec![0; pos.len()] };
        let cells: Vec<usize> = pos.iter().map(|p| grid.cell_of(p)).collect();
        for &c in &cells {
            grid.start[c + 1] += 1;
        }
        for c in 0..nx * ny {
            grid.start[c + 1] += grid.start[c];
        }
        let mut fill: Vec<u32> = grid.start[..nx * ny].to_vec();
        for (i, &c) in cells.iter().enumerate() {
            grid.items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        grid
    }

    fn cell_of(&self, p: &Point2<f64>) -> usize {
        let x = (((p.x - self.origin.x) * self.inv_cell) as usize).min(self.nx - 1);
        let y = (((p.y - self.origin.y) * self.inv_cell) as usize).min(self.ny - 1);
        y * self.nx + x
    }

    /// Ranges of cells (x0..x1, y0..y1) that may hold points within `r` of `p`.
    fn cells_near(&self, p: Point2<f64>, r: f64) -> Option<[usize; 4]> {
        let lx = (p.x - r - self.origin.x) * self.inv_cell;
        let hx = (p.x + r - self.origin.x) * self.inv_cell;
        let ly = (p.y - r - self.origin.y) * self.inv_cell;
        let hy = (p.y + r - self.origin.y) * self.inv_cell;
        // NaN fails these comparisons too.
        if !(hx >= 0.0 && hy >= 0.0 && lx < self.nx as f64 && ly < self.ny as f64) {
            return None;
        }
        // Truncation is the floor for the non-negative values kept.
        let clamp = |v: f64, n: usize| (v.max(0.0) as usize).min(n - 1);
        Some([clamp(lx, self.nx), clamp(hx, self.nx) + 1, clamp(ly, self.ny), clamp(hy, self.ny) + 1])
    }

    fn cell_items(&self, x: usize, y: usize) -> &[u32] {
        let c = y * self.nx + x;
        &self.items[self.start[c] as usize..self.start[c + 1] as usize]
    }
}

/// Every template hole's predicted position and apparent size (pixels).
#[derive(Clone, Copy)]
struct Projection {
    pos: [Point2<f64>; MAX_TEMPLATE_HOLES],
    size: [f64; MAX_TEMPLATE_HOLES],
}

/// A hypothesis that passed every check.
struct Accepted {
    score: usize,
    rms_px: f64,
    /// See [`Search::log_nfa`].
    log_nfa: f64,
    /// Every hole predicted inside the image (true when its size is unknown).
    in_view: bool,
    transform: Matrix3<f64>,
    projection: Projection,
    /// Offset of its assignment in `Search::accepted_assignments`.
    start: usize,
    key: u64,
}

type Assignment = [u32; MAX_TEMPLATE_HOLES];

fn assignment_hash(a: &[u32]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for &x in a {
        h ^= x as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
        h ^= h >> 29;
    }
    h
}

/// One call's state: candidates, their grid, scratch, and what was found.
struct Search<'a> {
    table: &'a HashTable,
    params: &'a HashParams,
    cand: Candidates,
    grid: Grid,
    holes: usize,
    template_class: [u8; MAX_TEMPLATE_HOLES],
    min_score: usize,
    /// `used[i] == stamp`: candidate i is taken in the current scoring.
    used: Vec<u32>,
    stamp: u32,
    /// Affine assignments already refined.
    tried: HashSet<u64>,
    /// Final assignments already accepted.
    seen: HashSet<u64>,
    /// Refined assignments with enough matches, `holes` entries each.
    refined: Vec<u32>,
    accepted: Vec<Accepted>,
    accepted_assignments: Vec<u32>,
    hypotheses: usize,
    /// The template's half turn (see [`HashTable::half_turn`]).
    half_turn: Option<(Point2<f64>, Vec<Option<usize>>)>,
    /// Hypotheses implicitly tested: online bases times model bases of their
    /// class signature.
    tests: usize,
}

impl<'a> Search<'a> {
    /// Transform's predicted positions and sizes, or `None` when the transform is
    /// implausible: a hole behind the camera, a mirror, degenerate, too oblique,
    /// or too much perspective.
    fn project(&self, t: &Matrix3<f64>) -> Option<Projection> {
        let p = self.params;
        let mut out = Projection { pos: [Point2::origin(); MAX_TEMPLATE_HOLES], size: [0.0; MAX_TEMPLATE_HOLES] };
        let (mut smin, mut smax) = (f64::INFINITY, 0.0f64);
        for (j, h) in self.table.points.iter().enumerate() {
            let w = t[(2, 0)] * h.x + t[(2, 1)] * h.y + t[(2, 2)];
            // Comparisons are written so that NaN fails them.
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
            let det = jac.determinant();
            let plausible = det > 0.0 && u.is_finite() && v.is_finite() && axis_ratio(&jac) >= p.min_axis_ratio;
            if !plausible {
                return None;
            }
            let scale = det.sqrt();
            smin = smin.min(scale);
            smax = smax.max(scale);
            out.pos[j] = Point2::new(u, v);
            out.size[j] = p.hole_size * scale;
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

    fn max_dist(&self, predicted_size: f64) -> f64 {
        (self.params.max_dist_ratio * predicted_size).max(self.params.min_max_dist_px)
    }

    fn size_agrees(&self, candidate: f64, predicted: f64) -> bool {
        let tol = self.params.size_tolerance;
        candidate <= predicted * tol && candidate * tol >= predicted
    }

    /// A fresh mark for `used`.
    fn next_stamp(&mut self) {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.used.fill(0);
            self.stamp = 1;
        }
    }

    /// Equation (2) with sizes: per template hole in order, the nearest unused
    /// candidate of its class within MaxDist whose size agrees.
    fn score(&mut self, proj: &Projection, assignment: &mut Assignment) -> usize {
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
    fn pairs(
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
    /// `min_homography_matches` matches, otherwise affine.
    fn fit(&self, assignment: &Assignment) -> Option<Matrix3<f64>> {
        let (n, src, dst) = self.pairs(assignment);
        if n >= self.params.min_homography_matches.max(4) {
            fit_homography(&src[..n], &dst[..n], self.table.centroid)
        } else {
            fit_affine(&src[..n], &dst[..n])
        }
    }

    /// Scores the affine transform of a model basis on an online basis, refines
    /// it and keeps it when it passes every check.
    fn evaluate(&mut self, model: usize, online: [usize; 3]) {
        let table = self.table;
        let o = usize::from(table.bases[model][0]);
        let (h0, h1, h2) = (self.cand.pos[online[0]], self.cand.pos[online[1]], self.cand.pos[online[2]]);
        let linear = Matrix2::from_columns(&[h1 - h0, h2 - h0]) * table.basis_inverse[model];
        let det = linear.determinant();
        // A mirror (det < 0), degenerate or too oblique: no view of the front.
        let plausible = det > 0.0 && axis_ratio(&linear) >= self.params.min_axis_ratio;
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
    fn accept(&mut self, mut assignment: Assignment) {
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

    /// ln of the expected number of chance hypotheses as good as this one, per
    /// hypothesis tried (a-contrario, as AC-RANSAC): the candidates around the
    /// outlet that it does not use are taken as uniform clutter of their local
    /// density; a hole is matched by chance within radius r with probability
    /// alpha = density x pi r^2, r its leave-one-out error. Three matches fix the
    /// transform and are free (the three least significant); k of the other n - 3
    /// holes all within the k-th smallest radius: C(n - 3, k) alpha_k^k, the best k.
    fn log_nfa(&mut self, assignment: &Assignment, projection: &Projection, errors: &[f64]) -> f64 {
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

    fn assignment_of(&self, k: usize) -> &[u32] {
        let s = self.accepted[k].start;
        &self.accepted_assignments[s..s + self.holes]
    }

    /// True when `other` matches the candidates of `mine` to the half-turned
    /// holes: each power hole's candidate is the half-turned hole's in `other`.
    fn is_half_turn_twin(&self, mine: &[u32], other: &[u32]) -> bool {
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
    fn decide(&self) -> Option<usize> {
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
fn ln_binomial(n: usize, k: usize) -> f64 {
    (0..k.min(n)).map(|i| ((n - i) as f64 / (i + 1) as f64).ln()).sum()
}

/// `t` applied to a point (homogeneous division).
fn apply(t: &Matrix3<f64>, p: Point2<f64>) -> Point2<f64> {
    let w = t[(2, 0)] * p.x + t[(2, 1)] * p.y + t[(2, 2)];
    Point2::new(
        (t[(0, 0)] * p.x + t[(0, 1)] * p.y + t[(0, 2)]) / w,
        (t[(1, 0)] * p.x + t[(1, 1)] * p.y + t[(1, 2)]) / w,
    )
}

/// Similarity that moves `points` to their centroid and scales their mean
/// distance from it to sqrt(2) (Hartley), as (centroid, scale).
fn normaliser(points: &[Point2<f64>]) -> Option<(Vector2<f64>, f64)> {
    let n = points.len() as f64;
    let c = points.iter().map(|p| p.coords).sum::<Vector2<f64>>() / n;
    let mean = points.iter().map(|p| (p.coords - c).norm()).sum::<f64>() / n;
    if mean > 0.0 && mean.is_finite() { Some((c, std::f64::consts::SQRT_2 / mean)) } else { None }
}

/// Least-squares affine transform taking `src` to `dst` (at least 3 pairs).
fn fit_affine(src: &[Point2<f64>], dst: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    if src.len() < 3 {
        return None;
    }
    let (cs, ss) = normaliser(src)?;
    let (cd, sd) = normaliser(dst)?;
    let mut ata = SMatrix::<f64, 3, 3>::zeros();
    let mut atu = SVector::<f64, 3>::zeros();
    let mut atv = SVector::<f64, 3>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let x = (s.coords - cs) * ss;
        let y = (d.coords - cd) * sd;
        let row = SVector::<f64, 3>::new(x.x, x.y, 1.0);
        ata += row * row.transpose();
        atu += row * y.x;
        atv += row * y.y;
    }
    let chol = ata.cholesky()?;
    let (u, v) = (chol.solve(&atu), chol.solve(&atv));
    let normalised = Matrix3::new(u[0], u[1], u[2], v[0], v[1], v[2], 0.0, 0.0, 1.0);
    let t = denormalise(&normalised, cs, ss, cd, sd);
    if t.iter().all(|x| x.is_finite()) { Some(t) } else { None }
}

/// Normalised DLT homography taking `src` to `dst` (at least 4 pairs), scaled so
/// that w = 1 at `centre` (a point of the template).
fn fit_homography(src: &[Point2<f64>], dst: &[Point2<f64>], centre: Point2<f64>) -> Option<Matrix3<f64>> {
    if src.len() < 4 {
        return None;
    }
    let (cs, ss) = normaliser(src)?;
    let (cd, sd) = normaliser(dst)?;
    // h33 = 1 in normalised coordinates: the template's centroid, at the origin
    // there, maps to a finite image point.
    let mut ata = SMatrix::<f64, 8, 8>::zeros();
    let mut atb = SVector::<f64, 8>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let x = (s.coords - cs) * ss;
        let y = (d.coords - cd) * sd;
        let ru = SVector::<f64, 8>::from([x.x, x.y, 1.0, 0.0, 0.0, 0.0, -y.x * x.x, -y.x * x.y]);
        let rv = SVector::<f64, 8>::from([0.0, 0.0, 0.0, x.x, x.y, 1.0, -y.y * x.x, -y.y * x.y]);
        ata += ru * ru.transpose() + rv * rv.transpose();
        atb += ru * y.x + rv * y.y;
    }
    let h = ata.cholesky()?.solve(&atb);
    let normalised = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0);
    let t = denormalise(&normalised, cs, ss, cd, sd);
    let w = t[(2, 0)] * centre.x + t[(2, 1)] * centre.y + t[(2, 2)];
    let finite_centre = w.abs() > 1e-12;
    if !finite_centre {
        return None;
    }
    let t = t / w;
    if t.iter().all(|x| x.is_finite()) { Some(t) } else { None }
}

/// T_dst^-1 * normalised * T_src.
fn denormalise(normalised: &Matrix3<f64>, cs: Vector2<f64>, ss: f64, cd: Vector2<f64>, sd: f64) -> Matrix3<f64> {
    let t_src = Matrix3::new(ss, 0.0, -ss * cs.x, 0.0, ss, -ss * cs.y, 0.0, 0.0, 1.0);
    let t_dst_inv = Matrix3::new(1.0 / sd, 0.0, cd.x, 0.0, 1.0 / sd, cd.y, 0.0, 0.0, 1.0);
    t_dst_inv * normalised * t_src
}

/// The voting state of the online stage.
struct Online {
    /// Votes per model basis; zero outside `vote`.
    votes: Vec<u16>,
    /// Model bases with a vote, to reset.
    touched: Vec<u32>,
    min_votes: u16,
}

impl Online {
    /// Hashes the candidates `hashed` in the online basis `basis` (origin, a, b),
    /// counts the votes of the model bases and evaluates those with enough.
    fn vote(&mut self, search: &mut Search, basis: [usize; 3], hashed: &[u32]) {
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
        for &model in &self.touched {
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
fn widest_corner(pos: &[Point2<f64>], corners: [usize; 3], sin_min: f64) -> Option<[usize; 3]> {
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

/// Finds the one outlet of `table`'s template among classified candidates, or
/// `None` (no outlet, or more than one way to see one).
///
/// - `points`: candidate centres in undistorted image pixels;
/// - `classes`: the classifier's verdicts (`Background` candidates are ignored);
/// - `sizes`: each candidate's apparent hole size in pixels, measured as
///   [`HashParams::hole_size`] is on the template (e.g. the larger side of its
///   bounding box). Candidates with a non-finite centre or a size that is not
///   finite and positive are ignored, as are indices beyond the shortest slice.
///
/// Deterministic: the same input gives the same answer.
pub fn find_outlet(
    table: &HashTable,
    points: &[Point2<f64>],
    classes: &[Class],
    sizes: &[f64],
    params: &HashParams,
) -> Option<OutletMatch> {
    let _span = tracing::debug_span!("hashing").entered();
    let holes = table.holes();
    let usable = !table.bases.is_empty() && params.hole_size > 0.0 && params.size_tolerance >= 1.0;
    if !usable {
        return None;
    }
    let cand = Candidates::new(points, classes, sizes);
    let m = cand.len();
    if m < 3 {
        return None;
    }
    let mut sorted_sizes = cand.size.clone();
    sorted_sizes.sort_unstable_by(f64::total_cmp);
    let grid = Grid::new(&cand.pos, sorted_sizes[m / 2]);
    let mut template_class = [u8::MAX; MAX_TEMPLATE_HOLES];
    for (t, &c) in template_class.iter_mut().zip(&table.classes) {
        *t = class_index(c).unwrap_or(u8::MAX);
    }
    let mut search = Search {
        table,
        params,
        cand,
        grid,
        holes,
        template_class,
        min_score: params.min_score(holes),
        used: vec![0; m],
        stamp: 0,
        tried: HashSet::new(),
        seen: HashSet::new(),
        refined: Vec::new(),
        accepted: Vec::new(),
        accepted_assignments: Vec::new(),
        hypotheses: 0,
        half_turn: table.half_turn(),
        tests: 0,
    };
    if search.min_score > holes {
        return None;
    }

    // Each candidate's neighbourhood: candidates within the outlet's extent at the
    // largest scale its size allows, of compatible size; nearest first for the
    // first `k`, which make the online bases.
    let k_max = params.neighbours.max(2);
    let tol = params.size_tolerance;
    let mut hood_start = vec![0u32; m + 1];
    let mut hood: Vec<u32> = Vec::with_capacity(m * 16);
    let mut scratch: Vec<(f64, u32)> = Vec::with_capacity(m);
    for c in 0..m {
        let (pc, sc) = (search.cand.pos[c], search.cand.size[c]);
        let radius = table.extent * sc / params.hole_size * tol;
        scratch.clear();
        for (i, (p, &s)) in search.cand.pos.iter().zip(&search.cand.size).enumerate() {
            let d2 = (p - pc).norm_squared();
            if i != c && d2 <= radius * radius && s <= sc * tol * tol && s * tol * tol >= sc {
                scratch.push((d2, i as u32));
            }
        }
        let k = k_max.min(scratch.len());
        let by_distance = |a: &(f64, u32), b: &(f64, u32)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        if k > 0 && k < scratch.len() {
            scratch.select_nth_unstable_by(k - 1, by_distance);
        }
        scratch[..k].sort_unstable_by(by_distance);
        hood.extend(scratch.iter().map(|&(_, i)| i));
        hood_start[c + 1] = hood.len() as u32;
    }

    let mut online = Online {
        votes: vec![0u16; table.bases.len()],
        touched: Vec::with_capacity(table.bases.len()),
        min_votes: params.min_votes(holes).min(u16::MAX as usize) as u16,
    };
    let sin_online = finite_or(params.min_online_angle, 0.25).clamp(0.0, std::f64::consts::FRAC_PI_2).sin().max(1e-6);
    let mut bases_seen: HashSet<u64> = HashSet::with_capacity(m * 16);
    for c in 0..m {
        let list = &hood[hood_start[c] as usize..hood_start[c + 1] as usize];
        let k = k_max.min(list.len());
        for a in 0..k {
            for b in a + 1..k {
                // A triangle is one basis, from its widest corner: the model holds
                // every ordering, and the widest corner keeps its model angle wide.
                let Some([o, x, y]) =
                    widest_corner(&search.cand.pos, [c, list[a] as usize, list[b] as usize], sin_online)
                else {
                    continue;
                };
                let key = ((o as u64) << 42) | ((x.min(y) as u64) << 21) | x.max(y) as u64;
                if !bases_seen.insert(key) {
                    continue;
                }
                let hashed = &hood[hood_start[o] as usize..hood_start[o + 1] as usize];
                online.vote(&mut search, [o, x, y], hashed);
            }
        }
    }

    let found = search.decide();
    tracing::debug!(
        candidates = m,
        hypotheses = search.hypotheses,
        tests = search.tests,
        refined = search.tried.len(),
        verified = search.accepted.len(),
        found = found.is_some(),
        "geometric hashing"
    );
    let best = &search.accepted[found?];
    let assignment = search
        .assignment_of(found?)
        .iter()
        .map(|&i| if i == NONE { None } else { Some(search.cand.index[i as usize]) })
        .collect();
    Some(OutletMatch {
        transform: best.transform,
        score: best.score,
        assignment,
        projected: best.projection.pos[..holes].to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimum_scores_are_two_thirds_of_the_holes() {
        let p = HashParams::default();
        assert_eq!((p.min_score(6), p.min_votes(6)), (4, 1));
        assert_eq!((p.min_score(12), p.min_votes(12)), (8, 4));
        assert_eq!(p.min_score(4), 4);
    }

    #[test]
    fn axis_ratio_is_the_ratio_of_singular_values() {
        let r = |a: f64| Matrix2::new(a.cos(), -a.sin(), a.sin(), a.cos());
        let m = r(0.3) * Matrix2::new(4.0, 0.0, 0.0, 2.0) * r(-1.1);
        assert!((axis_ratio(&m) - 0.5).abs() < 1e-12);
        assert!((axis_ratio(&Matrix2::new(3.0, 0.0, 0.0, -3.0)) - 1.0).abs() < 1e-12);
        assert_eq!(axis_ratio(&Matrix2::zeros()), 0.0);
    }

    #[test]
    fn fits_recover_exact_transforms() {
        let src: Vec<Point2<f64>> = [(0.0, 0.0), (12.7, 0.0), (6.35, 11.9), (0.0, 38.1), (12.7, 38.1), (6.35, 50.0)]
            .iter()
            .map(|&(x, y)| Point2::new(x, y))
            .collect();
        let h = Matrix3::new(3.1, -0.4, 320.0, 0.7, 2.6, 200.0, 0.002, -0.001, 1.0);
        let dst: Vec<Point2<f64>> = src.iter().map(|&p| apply(&h, p)).collect();
        let fitted = fit_homography(&src, &dst, Point2::new(6.0, 20.0)).expect("homography");
        for (s, d) in src.iter().zip(&dst) {
            assert!((apply(&fitted, *s) - d).norm() < 1e-9);
        }
        let a = Matrix3::new(3.1, -0.4, 320.0, 0.7, 2.6, 200.0, 0.0, 0.0, 1.0);
        let dst: Vec<Point2<f64>> = src.iter().map(|&p| apply(&a, p)).collect();
        let fitted = fit_affine(&src[..3], &dst[..3]).expect("affine");
        assert!((fitted - a).norm() < 1e-9);
        // Degenerate: too few or coincident points.
        assert!(fit_homography(&src[..3], &dst[..3], Point2::origin()).is_none());
        assert!(fit_affine(&[Point2::origin(); 3], &dst[..3]).is_none());
    }

    #[test]
    fn a_triangle_is_based_at_its_widest_corner() {
        let pos = [Point2::new(0.0, 0.0), Point2::new(10.0, 0.0), Point2::new(5.0, 1.0), Point2::new(20.0, 0.0)];
        assert_eq!(widest_corner(&pos, [0, 1, 2], 0.1), Some([2, 0, 1]));
        assert_eq!(widest_corner(&pos, [0, 1, 3], 0.1), None);
    }

    #[test]
    fn binomials() {
        assert!((ln_binomial(9, 3) - 84f64.ln()).abs() < 1e-12);
        assert_eq!(ln_binomial(3, 0), 0.0);
    }
}
