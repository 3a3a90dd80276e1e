//! The offline half: the template's model bases, filed under the quantised affine
//! coordinates of the other holes, and the template's half-turn symmetry.

use super::{HashParams, MAX_TEMPLATE_HOLES, MIN_TEMPLATE_HOLES, class_index, cross, finite_or};
use crate::Class;
use nalgebra::{Matrix2, Point2, Vector2};

/// Class signatures of a basis: three holes, each power or ground.
pub(super) const SIGNATURES: usize = 8;

/// The offline half of geometric hashing: the template's bases, filed under the
/// quantised affine coordinates of the other holes.
#[derive(Debug, Clone)]
pub struct HashTable {
    pub(super) points: Vec<Point2<f64>>,
    pub(super) classes: Vec<Class>,
    /// Model bases: ordered triples of hole indices (origin, a, b).
    pub(super) bases: Vec<[u8; 3]>,
    /// Inverse of [t_a - t_o, t_b - t_o] per basis.
    pub(super) basis_inverse: Vec<Matrix2<f64>>,
    /// Bucket b holds `bucket_bases[bucket_start[b]..bucket_start[b + 1]]`.
    pub(super) bucket_start: Vec<u32>,
    pub(super) bucket_bases: Vec<u32>,
    /// Model bases per class signature of the basis.
    pub(super) signature_bases: [u32; SIGNATURES],
    pub(super) bins: usize,
    pub(super) range: f64,
    /// Largest distance between two holes (template units).
    pub(super) extent: f64,
    /// Smallest distance between two holes (template units).
    pub(super) min_gap: f64,
    /// Mean of the holes (template units).
    pub(super) centroid: Point2<f64>,
    /// See [`Self::half_turn`]: found once here, as every search asks for it.
    half_turn: Option<(Point2<f64>, Vec<Option<usize>>)>,
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
            half_turn: None,
        };
        table.half_turn = half_turn_of(&table.points, &table.classes);
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
    pub fn half_turn(&self) -> Option<(Point2<f64>, &[Option<usize>])> {
        self.half_turn.as_ref().map(|(c, image)| (*c, image.as_slice()))
    }

    /// Template hole classes as given.
    pub fn classes(&self) -> &[Class] {
        &self.classes
    }

    /// First and last bin within `tolerance` bins of a coordinate, clipped to the
    /// grid; `None` when the coordinate is off the grid.
    pub(super) fn bin_span(&self, coordinate: f64, tolerance: f64) -> Option<[usize; 2]> {
        let t = (coordinate + self.range) / (2.0 * self.range) * self.bins as f64;
        if !(t >= 0.0 && t < self.bins as f64) {
            return None;
        }
        let lo = (t - tolerance).max(0.0) as usize;
        let hi = ((t + tolerance).max(0.0) as usize).min(self.bins - 1);
        Some([lo, hi])
    }

    pub(super) fn bucket(&self, signature: usize, class: usize, x: usize, y: usize) -> usize {
        ((signature * 2 + class) * self.bins + y) * self.bins + x
    }

    pub(super) fn bucket_entries(&self, bucket: usize) -> &[u32] {
        let (s, e) = (self.bucket_start[bucket] as usize, self.bucket_start[bucket + 1] as usize);
        &self.bucket_bases[s..e]
    }
}

/// [`HashTable::half_turn`] of holes at `points` of `classes`.
fn half_turn_of(points: &[Point2<f64>], classes: &[Class]) -> Option<(Point2<f64>, Vec<Option<usize>>)> {
    let power: Vec<usize> = (0..points.len()).filter(|&i| classes[i] == Class::Power).collect();
    if power.is_empty() || power.len() == points.len() {
        return None;
    }
    let c = power.iter().fold(Vector2::zeros(), |s, &i| s + points[i].coords) / power.len() as f64;
    let turned = |i: usize| Point2::from(2.0 * c - points[i].coords);
    let image: Vec<Option<usize>> = (0..points.len())
        .map(|i| (0..points.len()).find(|&k| classes[k] == classes[i] && (points[k] - turned(i)).norm() < 1.0))
        .collect();
    let symmetric = power.iter().all(|&i| image[i].is_some());
    let grounds_apart = image.iter().enumerate().all(|(i, k)| classes[i] == Class::Power || k.is_none());
    (symmetric && grounds_apart).then_some((Point2::from(c), image))
}
