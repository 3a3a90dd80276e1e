//! Stage 1, hole candidates (paper section III.A): small dark connected components of
//! the image thresholded at several levels, kept when their centre is darker than four
//! pixels around them by the contrast ratio r_C of the paper's equation (1).
//!
//! All levels are done in one pass, a component tree: the pixels are grouped into runs
//! (stretches of one threshold band along a row, each knowing the runs it touches in
//! the rows above and below), counting-sorted by band and added band after band to a
//! union-find over 8-connected runs that keeps each component's bounding box, area
//! and coordinate sums. After each band, i.e. at each level, the
//! components that grew and still fit the size range are scored. A component that
//! outgrows `max_side` is marked dead once, so the large bright regions cost next to
//! nothing. The same hole shows at several levels: of candidates closer than
//! [`DUPLICATE_RADIUS_PX`] the highest contrast one is kept.

use crate::Candidate;
use image::GrayImage;
use nalgebra::Point2;

/// Parameters of the hole candidate stage (paper section III.A).
///
/// `Default` is the paper's setting; [`CandidateParams::high_recall`] is what the
/// rendered test set needs to miss no hole (see there).
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateParams {
    /// Threshold levels: the components of {pixel < level} are examined at each.
    /// Paper: 30 to 150 step 20 (its code: 30 to 160 step 10). Any order; 0 is ignored.
    pub levels: Vec<u8>,
    /// Minimum contrast ratio r_C (eq. 1) of a candidate. Paper: 1.5 (its code: 1.5
    /// for white outlets, 1.3 for orange).
    pub min_contrast: f32,
    /// Smallest bounding box side of a candidate (pixels). Paper's code: 1.
    pub min_side: u32,
    /// Largest bounding box side of a candidate (pixels); at most 255 is used. The
    /// paper's code used 20 (its camera: 640x480). 80 keeps the longest opening, the
    /// 8.7 mm neutral slot, at 20 cm in front of a 1920x1080 camera (f = 1575 px,
    /// ~70 px plus blur); scale it with the focal length for larger images.
    pub max_side: u32,
    /// Smallest area of a candidate (pixels). Not in the paper (1 = no limit).
    pub min_area: u32,
}

impl Default for CandidateParams {
    fn default() -> Self {
        Self { levels: (30..=150).step_by(20).collect(), min_contrast: 1.5, min_side: 1, max_side: 80, min_area: 1 }
    }
}

impl CandidateParams {
    /// Settings under which no visible hole of the rendered scenarios is missed at
    /// 640x480 (see `tests/candidates.rs`), at ~30 candidates per image:
    /// - levels 10 to 240 step 10: over-exposed plates leave slots at grey 160-200, dark
    ///   frames leave holes below 30, and with steps of 20 a hole is missed when it
    ///   merges with a shadow between two levels;
    /// - contrast 1.1: a 2 mm slot 45-50 cm away, seen at an angle, is under 2 px wide,
    ///   and sensor blur and the 3x3 smoothing leave its centre at only 1.14-1.2 times
    ///   the face around it. From 1280x960 on, holes are wider than the blur: 1.3 still
    ///   keeps them all and halves the count (a quarter in dark, noisy frames);
    /// - area >= 8 px: drops sensor-noise specks; the smallest hole (a slot at 50 cm,
    ///   640x480) covers ~15-20 px.
    pub fn high_recall() -> Self {
        Self { levels: (10..=240).step_by(10).collect(), min_contrast: 1.1, min_area: 8, ..Self::default() }
    }
}

/// Candidates closer than this (pixels) are one blob seen at several levels.
pub const DUPLICATE_RADIUS_PX: f64 = 2.0;

/// Set in a node's `seen` area while it is in the band's touched list: a live
/// component's area is at most 255 x 255, far below it.
const PUSHED: u32 = 1 << 31;

/// Label of a pixel not yet added.
const NONE: u32 = u32::MAX;
/// Label of a pixel (or parent of a root) in a component too large to be a hole.
const DEAD: u32 = u32::MAX - 1;

/// A component's bounding box, area and coordinate sums.
#[derive(Debug, Clone, Copy)]
struct Blob {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    area: u32,
    sum_x: u64,
    sum_y: u64,
}

impl Blob {
    /// The pixels x..x + len of row y.
    fn run(x: u32, y: u32, len: u32) -> Self {
        let (x, y, n) = (x as u64, y as u64, len as u64);
        Self {
            x0: x as u32,
            y0: y as u32,
            x1: (x + n - 1) as u32,
            y1: y as u32,
            area: len,
            sum_x: n * x + n * (n - 1) / 2,
            sum_y: n * y,
        }
    }

    fn merge(&mut self, o: &Blob) {
        self.x0 = self.x0.min(o.x0);
        self.y0 = self.y0.min(o.y0);
        self.x1 = self.x1.max(o.x1);
        self.y1 = self.y1.max(o.y1);
        self.area += o.area;
        self.sum_x += o.sum_x;
        self.sum_y += o.sum_y;
    }

    fn size(&self) -> [u32; 2] {
        [self.x1 - self.x0 + 1, self.y1 - self.y0 + 1]
    }
}

/// Components as a union-find over nodes (one per component start), with the blob
/// of each root. A root whose parent is `DEAD` has outgrown `max_side`, and so has
/// everything merged into it.
struct Forest {
    parent: Vec<u32>,
    blobs: Vec<Blob>,
    max_side: u32,
}

impl Forest {
    /// Root of node `n`, or `None` if its component is dead (path halving).
    fn find(&mut self, mut n: u32) -> Option<u32> {
        let parent = &mut self.parent;
        loop {
            let p = parent[n as usize];
            if p == n {
                return Some(n);
            }
            if p == DEAD {
                return None;
            }
            let g = parent[p as usize];
            parent[n as usize] = g;
            if g == DEAD {
                return None;
            }
            n = g;
        }
    }

    /// Merges roots `a` and `b` (the smaller into the larger), returns the new root.
    fn union(&mut self, a: u32, b: u32) -> u32 {
        if a == b {
            return a;
        }
        let (keep, gone) = if self.blobs[a as usize].area >= self.blobs[b as usize].area { (a, b) } else { (b, a) };
        self.parent[gone as usize] = keep;
        let other = self.blobs[gone as usize];
        self.blobs[keep as usize].merge(&other);
        keep
    }

    /// Adds a run touching the live component `root` (or a dead one if `dead`): returns
    /// the label of its pixels (the component's root, a new one's node, or DEAD).
    fn add(&mut self, run: Blob, root: Option<u32>, dead: bool) -> u32 {
        let root = match (dead, root) {
            (true, root) => {
                if let Some(r) = root {
                    self.parent[r as usize] = DEAD;
                }
                return DEAD;
            }
            (false, Some(r)) => {
                self.blobs[r as usize].merge(&run);
                r
            }
            (false, None) => {
                let node = self.parent.len() as u32;
                self.parent.push(node);
                self.blobs.push(run);
                node
            }
        };
        if self.blobs[root as usize].size().into_iter().any(|s| s > self.max_side) {
            self.parent[root as usize] = DEAD;
            return DEAD;
        }
        root
    }
}

/// The components a run touches: their union so far, and whether one is dead.
struct Touch {
    root: Option<u32>,
    dead: bool,
    /// The label looked at last.
    last: u32,
}

impl Touch {
    #[inline(always)]
    fn label(&mut self, forest: &mut Forest, l: u32) {
        // Neighbouring runs mostly carry the same label: one look is enough.
        if l == NONE || l == self.last {
            return;
        }
        self.last = l;
        match if l == DEAD { None } else { forest.find(l) } {
            // Once dead, every live component touched dies too: no need to merge it first.
            Some(r) if self.dead => forest.parent[r as usize] = DEAD,
            Some(r) => self.root = Some(self.root.map_or(r, |t| forest.union(t, r))),
            None => {
                if let Some(r) = self.root.take() {
                    forest.parent[r as usize] = DEAD;
                }
                self.dead = true;
            }
        }
    }
}

/// A run: pixels x..x + len of row y, all in one threshold band.
#[derive(Debug, Clone, Copy, Default)]
struct Run {
    x: u32,
    y: u32,
    len: u32,
    /// The runs of the rows above and below that touch this one (8-connected), as
    /// index ranges into the raster-ordered runs: runs of a row are sorted by x.
    above: [u32; 2],
    below: [u32; 2],
}

/// Hole candidates of a grey image (see [`crate::grey_of`]), highest contrast first.
/// Never panics; an empty image or one without levels gives none.
pub fn find_candidates(grey: &GrayImage, params: &CandidateParams) -> Vec<Candidate> {
    let mut found = Vec::new();
    find_candidates_into(grey, params, params.min_contrast, &mut found);
    found
}

/// [`find_candidates`] into `out` (cleared first), with `min_contrast` in place
/// of the parameters' own: the detector reuses one vector per frame and raises
/// the contrast for large images without copying the parameters.
pub(crate) fn find_candidates_into(
    grey: &GrayImage,
    params: &CandidateParams,
    min_contrast: f32,
    out: &mut Vec<Candidate>,
) {
    out.clear();
    crate::with_scratch(&SCRATCH, |scratch| find_with(grey, params, min_contrast, scratch, out));
}

/// The buffers of one search, kept by each thread between frames, so that a
/// frame takes nothing from the allocator once the sizes have settled.
#[derive(Default)]
struct Scratch {
    levels: Vec<u8>,
    rows: Vec<u16>,
    smooth: Vec<u8>,
    runs: Vec<Run>,
    bands: Vec<u8>,
    row_start: Vec<u32>,
    band_row: Vec<u8>,
    at: Vec<u32>,
    start: Vec<u32>,
    order: Vec<u32>,
    label: Vec<u32>,
    parent: Vec<u32>,
    blobs: Vec<Blob>,
    touched: Vec<u32>,
    seen: Vec<u32>,
    found: Vec<Candidate>,
    grid: Vec<u32>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

fn find_with(
    grey: &GrayImage,
    params: &CandidateParams,
    min_contrast: f32,
    scratch: &mut Scratch,
    out: &mut Vec<Candidate>,
) {
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    let _span = tracing::debug_span!("candidates", w, h).entered();
    let Scratch {
        levels,
        rows,
        smooth,
        runs,
        bands,
        row_start,
        band_row,
        at,
        start,
        order,
        label,
        parent,
        blobs,
        touched,
        seen,
        found,
        grid,
    } = scratch;
    levels.clear();
    levels.extend(params.levels.iter().copied().filter(|&l| l > 0));
    levels.sort_unstable();
    levels.dedup();
    let padded = (w + 2).checked_mul(h + 2).filter(|&n| n < DEAD as usize);
    let pixels = grey.as_raw().get(..w * h).filter(|p| !p.is_empty());
    let (Some(&top), Some(padded), Some(pixels)) = (levels.last(), padded, pixels) else { return };
    smooth_3x3(pixels, w, h, rows, smooth);
    let smooth: &[u8] = smooth;

    runs_of_rows(smooth, w, levels, top, runs, bands, row_start, band_row, at);
    if runs.len() >= DEAD as usize {
        return;
    }
    order_by_band(bands, levels.len(), start, order);
    // The label of each run: its component's node (any node of it: `find` gives
    // the root), DEAD, or NONE while its band is not reached.
    label.clear();
    label.resize(runs.len(), NONE);
    parent.clear();
    blobs.clear();
    let mut forest =
        Forest { parent: std::mem::take(parent), blobs: std::mem::take(blobs), max_side: params.max_side.min(255) };
    // The roots that runs of the band joined, and each node's area when last
    // scored: only a component that grew at a level can give a new candidate, so
    // only those are looked at (not every live one, band after band).
    touched.clear();
    seen.clear();
    found.clear();
    let runs: &[Run] = runs;
    for (b, &level) in levels.iter().enumerate() {
        for &i in &order[start[b] as usize..start[b + 1] as usize] {
            let run = runs[i as usize];
            // Union with every live component around; any dead one kills the lot.
            // The order (above, below, left, right) is the pixels' raster order
            // around the run, so the forest grows as a pixel-wise labelling would.
            let mut touch = Touch { root: None, dead: false, last: NONE };
            for &l in label[run.above[0] as usize..run.above[1] as usize]
                .iter()
                .chain(&label[run.below[0] as usize..run.below[1] as usize])
            {
                touch.label(&mut forest, l);
            }
            let i = i as usize;
            // A row's runs cover it in order: a run not at the row's start has its
            // left neighbour just before it, one not at its end its right one after.
            if run.x > 0 {
                touch.label(&mut forest, label[i - 1]);
            }
            if ((run.x + run.len) as usize) < w {
                touch.label(&mut forest, label[i + 1]);
            }
            let Touch { root, dead, .. } = touch;
            let fill = forest.add(Blob::run(run.x, run.y, run.len), root, dead);
            // Each root once a band (the neighbouring runs of a component
            // mostly share it): `seen`'s spare high bit marks it pushed.
            if fill != DEAD {
                if seen.len() < forest.parent.len() {
                    seen.resize(forest.parent.len(), 0);
                }
                let mark = &mut seen[fill as usize];
                if *mark & PUSHED == 0 {
                    *mark |= PUSHED;
                    touched.push(fill);
                }
            }
            label[i] = fill;
        }
        // In node order, as the components were made: candidates of equal
        // contrast keep that order through the duplicate suppression.
        touched.sort_unstable();
        for &node in touched.iter() {
            seen[node as usize] &= !PUSHED;
            if forest.parent[node as usize] != node {
                continue;
            }
            let blob = &forest.blobs[node as usize];
            if blob.area != seen[node as usize] {
                seen[node as usize] = blob.area;
                found.extend(score(blob, smooth, w, h, level, params, min_contrast));
            }
        }
        touched.clear();
    }
    *parent = forest.parent;
    *blobs = forest.blobs;
    // The grid is all NONE between calls (each call clears what it marked), so
    // it is only ever grown, never cleared as a whole.
    if grid.len() < padded {
        grid.resize(padded, NONE);
    }
    suppress_duplicates(found, &mut grid[..padded], w + 2, h + 2, out);
    tracing::debug!(candidates = out.len());
}

/// The runs of the image in raster order (maximal stretches of one band along a row;
/// band b holds the grey values in [levels[b-1], levels[b]), values from `top` on are
/// band `levels.len()`, in no component), each run's band, where each row's runs
/// start, and which runs of the rows above and below each run touches. The runs of
/// a row cover it, so the runs touching pixels x0 - 1..=x1 of a neighbouring row are
/// the index range from the run at x0 - 1 to the run at x1. `band_row` holds one
/// row's bands, `at` the run index of every pixel of the last two rows.
#[allow(clippy::too_many_arguments)]
fn runs_of_rows(
    smooth: &[u8],
    w: usize,
    levels: &[u8],
    top: u8,
    runs: &mut Vec<Run>,
    bands: &mut Vec<u8>,
    row_start: &mut Vec<u32>,
    band_row: &mut Vec<u8>,
    at: &mut Vec<u32>,
) {
    let band_of = band_table(levels, top);
    let uniform = UniformBands::of(levels, &band_of);
    runs.clear();
    bands.clear();
    row_start.clear();
    band_row.clear();
    band_row.resize(w, 0);
    at.clear();
    at.resize(2 * w, 0);
    let (mut prev, mut cur) = at.split_at_mut(w);
    for (y, row) in smooth.chunks_exact(w).enumerate() {
        let first = runs.len();
        row_start.push(first as u32);
        // Evenly spaced levels (the usual case) by arithmetic, which the
        // compiler does 8-16 pixels at a time; a table look-up is one at a time.
        match uniform {
            Some(u) => {
                for (b, &v) in band_row.iter_mut().zip(row) {
                    *b = u.band(v);
                }
            }
            None => {
                for (b, &v) in band_row.iter_mut().zip(row) {
                    *b = band_of[v as usize];
                }
            }
        }
        let mut x0 = 0;
        let mut push = |x0: usize, x1: usize| {
            runs.push(Run { x: x0 as u32, y: y as u32, len: (x1 - x0) as u32, ..Run::default() });
            bands.push(band_row[x0]);
        };
        // Where the band changes, eight pixels at a time: a run is ten pixels on
        // average, so a branch per pixel mispredicts at every run's end.
        // The run index of every pixel of this row (`cur`) comes from the same
        // change masks: a byte-wise prefix count of the changes, eight pixels a
        // step, instead of a chain of one addition per pixel.
        let mut k = first as u32;
        cur[0] = k;
        let mut x = 1;
        while x + 8 <= w {
            let word = |at: usize| {
                let mut b = [0u8; 8];
                b.copy_from_slice(&band_row[at..at + 8]);
                u64::from_le_bytes(b)
            };
            let mut changed = nonzero_bytes(word(x) ^ word(x - 1));
            // Byte j: the changes at pixels x..=x + j (at most 8, no carry).
            let prefix = (changed >> 7).wrapping_mul(0x0101_0101_0101_0101);
            for (j, c) in cur[x..x + 8].iter_mut().enumerate() {
                *c = k + ((prefix >> (8 * j)) & 0xff) as u32;
            }
            k += (prefix >> 56) as u32;
            while changed != 0 {
                let t = x + (changed.trailing_zeros() / 8) as usize;
                push(x0, t);
                x0 = t;
                changed &= changed - 1;
            }
            x += 8;
        }
        for x in x..w {
            if band_row[x] != band_row[x - 1] {
                push(x0, x);
                x0 = x;
                k += 1;
            }
            cur[x] = k;
        }
        push(x0, w);
        if y > 0 {
            let reach = |row: &[u32], run: &Run| {
                let (x0, x1) = (run.x as usize, (run.x + run.len) as usize);
                [row[x0.saturating_sub(1)], row[x1.min(w - 1)] + 1]
            };
            let before = row_start[y - 1] as usize;
            let (older, this) = runs.split_at_mut(first);
            for run in this.iter_mut() {
                run.above = reach(prev, run);
            }
            for run in older[before..].iter_mut() {
                run.below = reach(cur, run);
            }
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    row_start.push(runs.len() as u32);
}

/// The band of every grey value: how many of `levels` (sorted) lie at or below
/// it, and `levels.len()` from `top` (the last level) on.
fn band_table(levels: &[u8], top: u8) -> [u8; 256] {
    let mut band_of = [levels.len() as u8; 256];
    for (v, band) in band_of.iter_mut().enumerate().take(top as usize) {
        *band = levels.partition_point(|&l| l as usize <= v) as u8;
    }
    band_of
}

/// Threshold bands of evenly spaced levels `first, first + step, ...` by
/// arithmetic: band = min(count, (v + step - first) / step), the division a
/// multiply-high checked against the table for every grey value.
#[derive(Debug, Clone, Copy)]
struct UniformBands {
    step: u16,
    first: u16,
    reciprocal: u16,
    count: u16,
}

impl UniformBands {
    /// `None` where the levels are not evenly spaced or the arithmetic would
    /// differ from `table` anywhere.
    fn of(levels: &[u8], table: &[u8; 256]) -> Option<Self> {
        let (&first, &second) = (levels.first()?, levels.get(1)?);
        let step = second.checked_sub(first).filter(|&s| s > 0)? as u16;
        let reciprocal = u16::try_from(65536u32.div_ceil(step as u32)).ok()?;
        let bands = Self { step, first: first as u16, reciprocal, count: levels.len() as u16 };
        (0..=255u8).all(|v| bands.band(v) == table[v as usize]).then_some(bands)
    }

    #[inline(always)]
    fn band(self, v: u8) -> u8 {
        let x = (v as u16 + self.step).saturating_sub(self.first);
        let quotient = ((x as u32 * self.reciprocal as u32) >> 16) as u16;
        quotient.min(self.count) as u8
    }
}

/// The high bit of each byte of `d` that is not zero, the others clear.
#[inline]
fn nonzero_bytes(d: u64) -> u64 {
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    (((d & LOW7) + LOW7) | d) & !LOW7
}

/// The runs' indices grouped by band (a counting sort, raster order within a band
/// to keep the union-find's memory accesses local), and where each band starts.
fn order_by_band(bands: &[u8], count: usize, start: &mut Vec<u32>, order: &mut Vec<u32>) {
    start.clear();
    start.resize(count + 1, 0);
    // Band `count` (grey from the top level on) joins no component.
    for &band in bands.iter().filter(|&&b| (b as usize) < count) {
        start[band as usize + 1] += 1;
    }
    for b in 1..=count {
        start[b] += start[b - 1];
    }
    order.clear();
    let mut next = [0u32; 256];
    next[..count].copy_from_slice(&start[..count]);
    order.resize(start[count] as usize, 0);
    for (i, &band) in bands.iter().enumerate().filter(|(_, b)| (**b as usize) < count) {
        order[next[band as usize] as usize] = i as u32;
        next[band as usize] += 1;
    }
}

/// The candidate of a component at a level, if its size and contrast qualify.
fn score(
    blob: &Blob,
    smooth: &[u8],
    w: usize,
    h: usize,
    level: u8,
    params: &CandidateParams,
    min_contrast: f32,
) -> Option<Candidate> {
    let [sw, sh] = blob.size();
    if sw.min(sh) < params.min_side || blob.area < params.min_area {
        return None;
    }
    let centre = Point2::new(blob.sum_x as f64 / blob.area as f64, blob.sum_y as f64 / blob.area as f64);
    let (x0, y0) = (centre.x.round() as i64, centre.y.round() as i64);
    let at = |x: i64, y: i64| {
        (x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h).then(|| smooth[y as usize * w + x as usize] as f32)
    };
    let inside = at(x0, y0)?;
    // Eq. (1): p0 +- s_x x and p0 +- s_y y; probes outside the image are left out.
    let (dx, dy) = (sw as i64, sh as i64);
    let (sum, n) = [(dx, 0), (-dx, 0), (0, dy), (0, -dy)]
        .into_iter()
        .filter_map(|(ox, oy)| at(x0 + ox, y0 + oy))
        .fold((0.0, 0), |(s, n), v| (s + v, n + 1));
    if n == 0 {
        return None;
    }
    // A black centre counts as grey 1: any brighter surround is then high contrast.
    let contrast = sum / n as f32 / inside.max(1.0);
    (contrast >= min_contrast).then_some(Candidate { centre, size: [sw, sh], area: blob.area, contrast, level })
}

/// Keeps the highest contrast candidate of each group closer than
/// [`DUPLICATE_RADIUS_PX`], into `kept` (empty); `grid` (padded image size, all
/// NONE, left so) marks kept centres.
fn suppress_duplicates(
    found: &mut [Candidate],
    grid: &mut [u32],
    stride: usize,
    rows: usize,
    kept: &mut Vec<Candidate>,
) {
    found.sort_by(|a, b| b.contrast.total_cmp(&a.contrast));
    let reach = DUPLICATE_RADIUS_PX.ceil() as usize + 1;
    kept.reserve(found.len());
    for &c in found.iter() {
        let (cx, cy) = (c.centre.x.round() as usize + 1, c.centre.y.round() as usize + 1);
        let near = (cy.saturating_sub(reach)..(cy + reach + 1).min(rows)).any(|y| {
            (cx.saturating_sub(reach)..(cx + reach + 1).min(stride)).any(|x| {
                let k = grid[y * stride + x];
                k != NONE && (kept[k as usize].centre - c.centre).norm() <= DUPLICATE_RADIUS_PX
            })
        });
        if !near {
            grid[cy * stride + cx] = kept.len() as u32;
            kept.push(c);
        }
    }
    for c in kept.iter() {
        grid[(c.centre.y.round() as usize + 1) * stride + c.centre.x.round() as usize + 1] = NONE;
    }
}

/// 3x3 binomial smoothing ([1 2 1] / 4 each way), borders replicated.
fn smooth_3x3(src: &[u8], w: usize, h: usize, rows: &mut Vec<u16>, out: &mut Vec<u8>) {
    rows.clear();
    rows.resize(w * h, 0);
    for (s, r) in src.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        if w == 1 {
            r[0] = 4 * s[0] as u16;
            continue;
        }
        r[0] = 3 * s[0] as u16 + s[1] as u16;
        r[w - 1] = s[w - 2] as u16 + 3 * s[w - 1] as u16;
        for (o, t) in r[1..w - 1].iter_mut().zip(s.windows(3)) {
            *o = t[0] as u16 + 2 * t[1] as u16 + t[2] as u16;
        }
    }
    out.clear();
    out.resize(w * h, 0);
    for (y, o) in out.chunks_exact_mut(w).enumerate() {
        let row = |y: usize| &rows[y * w..(y + 1) * w];
        let (a, b, c) = (row(y.saturating_sub(1)), row(y), row((y + 1).min(h - 1)));
        for (((o, &a), &b), &c) in o.iter_mut().zip(a).zip(b).zip(c) {
            *o = ((a + 2 * b + c + 8) >> 4) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(levels: &[u8]) -> [u8; 256] {
        band_table(levels, *levels.last().expect("levels"))
    }

    #[test]
    fn evenly_spaced_levels_are_banded_by_arithmetic_as_the_table_bands_them() {
        for levels in [
            CandidateParams::high_recall().levels,
            CandidateParams::default().levels,
            (1..=255).step_by(2).collect(),
            (3..=250).step_by(127).collect(),
            vec![200, 203],
        ] {
            let t = table(&levels);
            let bands = UniformBands::of(&levels, &t).unwrap_or_else(|| panic!("{levels:?} not taken as even"));
            assert!((0..=255u8).all(|v| bands.band(v) == t[v as usize]), "{levels:?}");
        }
        // Uneven levels, or a step of 1 (no 16-bit reciprocal), take the table.
        assert!(UniformBands::of(&[10, 20, 40], &table(&[10, 20, 40])).is_none());
        let ones: Vec<u8> = (100..=110).collect();
        assert!(UniformBands::of(&ones, &table(&ones)).is_none());
    }

    #[test]
    fn candidates_are_the_same_whether_the_bands_come_by_arithmetic_or_by_table() {
        // A noisy ramp with dark blobs: many runs, every level crossed, an odd
        // width (the rows' last pixels outside the eight-pixel steps).
        let (w, h) = (203, 97);
        let mut state = 12345u32;
        let grey = GrayImage::from_fn(w, h, |x, y| {
            state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
            let noise = (state >> 16) % 9;
            let blob = ((x % 23) as i32 - 11).pow(2) + ((y % 19) as i32 - 9).pow(2) < 20;
            let v = 45 + x * 200 / w + noise - if blob { 35 } else { 0 };
            image::Luma([v.min(255) as u8])
        });
        let even = CandidateParams::high_recall();
        // Level 9 added: uneven, so banded by the table. No pixel is below 9
        // (the darkest is 10), so every level's components are the same.
        let mut uneven = even.clone();
        uneven.levels.insert(0, 9);
        let a = find_candidates(&grey, &even);
        let b: Vec<Candidate> = find_candidates(&grey, &uneven).into_iter().filter(|c| c.level != 9).collect();
        assert!(a.len() > 20, "only {} candidates", a.len());
        let key = |c: &Candidate| (c.centre.x.to_bits(), c.centre.y.to_bits(), c.size, c.area, c.level);
        let mut ka: Vec<_> = a.iter().map(key).collect();
        let mut kb: Vec<_> = b.iter().map(key).collect();
        ka.sort_unstable();
        kb.sort_unstable();
        assert_eq!(ka, kb);
    }
}
