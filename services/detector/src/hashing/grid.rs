//! The candidates a search works on, and a uniform grid over them for radius
//! queries; both rebuilt in place each search.

use super::{MAX_CANDIDATES, class_index};
use crate::Class;
use nalgebra::Point2;

/// The candidates the search works on: non-background, finite centre and size.
#[derive(Default)]
pub(super) struct Candidates {
    pub(super) pos: Vec<Point2<f64>>,
    pub(super) class: Vec<u8>,
    pub(super) size: Vec<f64>,
    /// Index in the caller's slices.
    pub(super) index: Vec<usize>,
}

impl Candidates {
    /// Takes the usable ones of the caller's candidates, in the vectors of the
    /// last search.
    pub(super) fn fill(&mut self, points: &[Point2<f64>], classes: &[Class], sizes: &[f64]) {
        let n = points.len().min(classes.len()).min(sizes.len());
        let c = self;
        c.pos.clear();
        c.class.clear();
        c.size.clear();
        c.index.clear();
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
    }

    pub(super) fn len(&self) -> usize {
        self.pos.len()
    }
}

/// A uniform grid over the candidates for radius queries.
#[derive(Default)]
pub(super) struct Grid {
    pub(super) origin: Point2<f64>,
    pub(super) inv_cell: f64,
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) start: Vec<u32>,
    pub(super) items: Vec<u32>,
    /// Each candidate's cell, then each cell's next free slot: for `build`.
    cells: Vec<usize>,
    fill: Vec<u32>,
}

impl Grid {
    /// The grid of `pos` with cells of `cell` (at least 1/128 of the span), in
    /// the vectors of the last search.
    pub(super) fn build(&mut self, pos: &[Point2<f64>], cell: f64) {
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
        (self.origin, self.inv_cell, self.nx, self.ny) = (lo, inv_cell, nx, ny);
        self.start.clear();
        self.start.resize(nx * ny + 1, 0);
        self.items.clear();
        self.items.resize(pos.len(), 0);
        let mut cells = std::mem::take(&mut self.cells);
        cells.clear();
        cells.extend(pos.iter().map(|p| self.cell_of(p)));
        for &c in &cells {
            self.start[c + 1] += 1;
        }
        for c in 0..nx * ny {
            self.start[c + 1] += self.start[c];
        }
        self.fill.clear();
        self.fill.extend_from_slice(&self.start[..nx * ny]);
        for (i, &c) in cells.iter().enumerate() {
            self.items[self.fill[c] as usize] = i as u32;
            self.fill[c] += 1;
        }
        self.cells = cells;
    }

    pub(super) fn cell_of(&self, p: &Point2<f64>) -> usize {
        let x = (((p.x - self.origin.x) * self.inv_cell) as usize).min(self.nx - 1);
        let y = (((p.y - self.origin.y) * self.inv_cell) as usize).min(self.ny - 1);
        y * self.nx + x
    }

    /// Ranges of cells (x0..x1, y0..y1) that may hold points within `r` of `p`.
    pub(super) fn cells_near(&self, p: Point2<f64>, r: f64) -> Option<[usize; 4]> {
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

    pub(super) fn cell_items(&self, x: usize, y: usize) -> &[u32] {
        let c = y * self.nx + x;
        &self.items[self.start[c] as usize..self.start[c + 1] as usize]
    }
}
