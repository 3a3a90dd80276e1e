//! Stage 1, hole candidates (paper section III.A): small dark connected components
//! of the image thresholded at several levels, kept when their centre is darker
//! than four pixels around them by the contrast ratio r_C of equation (1).

use crate::Candidate;
use image::GrayImage;
use nalgebra::Point2;

/// Parameters of the hole candidate stage (paper section III.A).
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateParams {
    /// Threshold levels: components of {pixel < level}. Paper: 30 to 150 step 20.
    pub levels: Vec<u8>,
    /// Minimum contrast ratio r_C (eq. 1). Paper: 1.5.
    pub min_contrast: f32,
    /// Bounding box sides (pixels) a component must have: both sides >= min_side, both <= max_side.
    pub min_side: u32,
    pub max_side: u32,
    // Experimental knobs.
    pub corners: bool,
    pub eight: bool,
    pub bbox_centre: bool,
    pub dedup_radius: f64,
    pub dedup: u8,
    pub smoothing: u8,
}

impl Default for CandidateParams {
    fn default() -> Self {
        Self {
            levels: (30..=150).step_by(20).collect(),
            min_contrast: 1.5,
            min_side: 1,
            max_side: 80,
            corners: false,
            eight: false,
            bbox_centre: false,
            dedup_radius: 2.0,
            dedup: 0,
            smoothing: 1,
        }
    }
}

const NONE: u32 = u32::MAX;

/// A component of the tree: bounding box, area and coordinate sums (wrapping: only
/// read for components small enough to be candidates).
#[derive(Debug, Clone, Copy)]
struct Blob {
    x0: u16,
    y0: u16,
    x1: u16,
    y1: u16,
    area: u32,
    sum_x: u32,
    sum_y: u32,
}

impl Blob {
    fn pixel(x: u16, y: u16) -> Self {
        Self { x0: x, y0: y, x1: x, y1: y, area: 1, sum_x: x as u32, sum_y: y as u32 }
    }
    fn merge(&mut self, o: &Blob) {
        self.x0 = self.x0.min(o.x0);
        self.y0 = self.y0.min(o.y0);
        self.x1 = self.x1.max(o.x1);
        self.y1 = self.y1.max(o.y1);
        self.area += o.area;
        self.sum_x = self.sum_x.wrapping_add(o.sum_x);
        self.sum_y = self.sum_y.wrapping_add(o.sum_y);
    }
    fn size(&self) -> [u32; 2] {
        [(self.x1 - self.x0) as u32 + 1, (self.y1 - self.y0) as u32 + 1]
    }
}

#[inline]
fn find(parent: &mut [u32], mut n: u32) -> u32 {
    while parent[n as usize] != n {
        let up = parent[parent[n as usize] as usize];
        parent[n as usize] = up;
        n = up;
    }
    n
}

pub fn smooth_with(grey: &GrayImage, kind: u8) -> GrayImage {
    match kind {
        0 => grey.clone(),
        1 => gauss3(grey),
        _ => smooth3(grey),
    }
}

/// 3x3 binomial filter, borders replicated.
pub fn gauss3(grey: &GrayImage) -> GrayImage {
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    let src = grey.as_raw();
    let mut rows = vec![0u16; w * h];
    for (s, r) in src.chunks_exact(w.max(1)).zip(rows.chunks_exact_mut(w.max(1))) {
        for x in 0..w {
            r[x] = s[x.saturating_sub(1)] as u16 + 2 * s[x] as u16 + s[(x + 1).min(w - 1)] as u16;
        }
    }
    let mut out = vec![0u8; w * h];
    for y in 0..h {
        let (a, b, c) = (y.saturating_sub(1) * w, y * w, (y + 1).min(h - 1) * w);
        for x in 0..w {
            out[b + x] = ((rows[a + x] + 2 * rows[b + x] + rows[c + x] + 8) / 16) as u8;
        }
    }
    GrayImage::from_raw(w as u32, h as u32, out).unwrap_or_default()
}

/// 3x3 box filter, borders replicated.
pub fn smooth3(grey: &GrayImage) -> GrayImage {
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    let src = grey.as_raw();
    let mut rows = vec![0u16; w * h];
    for (s, r) in src.chunks_exact(w.max(1)).zip(rows.chunks_exact_mut(w.max(1))) {
        for x in 0..w {
            r[x] = s[x.saturating_sub(1)] as u16 + s[x] as u16 + s[(x + 1).min(w - 1)] as u16;
        }
    }
    let mut out = vec![0u8; w * h];
    for y in 0..h {
        let (a, b, c) = (y.saturating_sub(1) * w, y * w, (y + 1).min(h - 1) * w);
        for x in 0..w {
            out[b + x] = ((rows[a + x] + rows[b + x] + rows[c + x] + 4) / 9) as u8;
        }
    }
    GrayImage::from_raw(w as u32, h as u32, out).unwrap_or_default()
}

/// Hole candidates of a grey image (see [`crate::grey_of`]).
pub fn find_candidates(grey: &GrayImage, params: &CandidateParams) -> Vec<Candidate> {
    let (w, h) = (grey.width() as usize, grey.height() as usize);
    if w == 0 || h == 0 || w > u16::MAX as usize || h > u16::MAX as usize {
        return Vec::new();
    }
    let smooth = smooth_with(grey, params.smoothing);
    let pix = smooth.as_raw();
    let mut is_level = [false; 257];
    for &l in &params.levels {
        is_level[l as usize] = true;
    }
    let top = (1..=255).rev().find(|&l| is_level[l]).unwrap_or(0);
    // Counting sort of the pixels darker than the top level.
    let mut start = [0u32; 257];
    for &v in pix {
        start[v as usize + 1] += 1;
    }
    for v in 1..257 {
        start[v] += start[v - 1];
    }
    let n = start[top] as usize;
    let mut order = vec![0u32; n];
    let mut next = start;
    for (i, &v) in pix.iter().enumerate() {
        if (v as usize) < top {
            order[next[v as usize] as usize] = i as u32;
            next[v as usize] += 1;
        }
    }
    // Node k is the k-th pixel in intensity order; label maps pixels to nodes.
    let mut label = vec![NONE; w * h];
    let mut parent: Vec<u32> = Vec::with_capacity(n);
    let mut blobs: Vec<Blob> = Vec::with_capacity(n);
    // Roots that may still be candidates, with the area they had when last looked at.
    let mut alive: Vec<(u32, u32)> = Vec::new();
    let mut found = Vec::new();
    let max_side = params.max_side.min(255);
    for v in 0..=top {
        if is_level[v] {
            alive.retain_mut(|(a, seen)| {
                if parent[*a as usize] != *a {
                    return false;
                }
                let b = &blobs[*a as usize];
                let [sw, sh] = b.size();
                if sw > max_side || sh > max_side {
                    return false;
                }
                if sw >= params.min_side && sh >= params.min_side && *seen != b.area {
                    *seen = b.area;
                    if let Some(c) = candidate(b, pix, w, h, v as u8, params) {
                        found.push(c);
                    }
                }
                true
            });
        }
        if v == top {
            break;
        }
        for &i in &order[start[v] as usize..start[v + 1] as usize] {
            let i = i as usize;
            let (x, y) = (i % w, i / w);
            let node = parent.len() as u32;
            label[i] = node;
            parent.push(node);
            blobs.push(Blob::pixel(x as u16, y as u16));
            alive.push((node, 0));
            let mut root = node;
            let mut join = |j: usize| {
                let l = label[j];
                if l == NONE {
                    return;
                }
                let r = find(&mut parent, l);
                if r == root {
                    return;
                }
                let (big, small) =
                    if blobs[r as usize].area >= blobs[root as usize].area { (r, root) } else { (root, r) };
                parent[small as usize] = big;
                let s = blobs[small as usize];
                blobs[big as usize].merge(&s);
                root = big;
            };
            if x > 0 {
                join(i - 1);
            }
            if x + 1 < w {
                join(i + 1);
            }
            if y > 0 {
                join(i - w);
            }
            if y + 1 < h {
                join(i + w);
            }
            if params.eight {
                if y > 0 && x > 0 {
                    join(i - w - 1);
                }
                if y > 0 && x + 1 < w {
                    join(i - w + 1);
                }
                if y + 1 < h && x > 0 {
                    join(i + w - 1);
                }
                if y + 1 < h && x + 1 < w {
                    join(i + w + 1);
                }
            }
        }
    }
    suppress_duplicates(found, params)
}

fn candidate(b: &Blob, pix: &[u8], w: usize, h: usize, level: u8, params: &CandidateParams) -> Option<Candidate> {
    let [sw, sh] = b.size();
    let (cx, cy) = if params.bbox_centre {
        ((b.x0 as f64 + b.x1 as f64) / 2.0, (b.y0 as f64 + b.y1 as f64) / 2.0)
    } else {
        (b.sum_x as f64 / b.area as f64, b.sum_y as f64 / b.area as f64)
    };
    let (px, py) = (cx.round() as i64, cy.round() as i64);
    let at = |x: i64, y: i64| -> Option<f32> {
        (x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h).then(|| pix[y as usize * w + x as usize] as f32)
    };
    let centre = at(px, py)?;
    let probes: [(i64, i64); 4] = if params.corners {
        let d = (0.75 * sw.max(sh) as f64).round() as i64;
        [(d, d), (-d, d), (d, -d), (-d, -d)]
    } else {
        let (dx, dy) = (sw as i64, sh as i64);
        [(dx, 0), (-dx, 0), (0, dy), (0, -dy)]
    };
    let (mut sum, mut count) = (0.0, 0);
    for (dx, dy) in probes {
        if let Some(v) = at(px + dx, py + dy) {
            sum += v;
            count += 1;
        }
    }
    if count == 0 {
        return None;
    }
    let contrast = sum / count as f32 / centre.max(1.0);
    (contrast >= params.min_contrast).then(|| Candidate {
        centre: Point2::new(cx, cy),
        size: [sw, sh],
        area: b.area,
        contrast,
        level,
    })
}

fn suppress_duplicates(mut found: Vec<Candidate>, params: &CandidateParams) -> Vec<Candidate> {
    if params.dedup_radius < 0.0 {
        return found;
    }
    found.sort_by(|a, b| b.contrast.total_cmp(&a.contrast));
    let mut kept: Vec<Candidate> = Vec::with_capacity(found.len());
    let inside = |c: &Candidate, k: &Candidate| {
        (c.centre.x - k.centre.x).abs() <= k.size[0] as f64 / 2.0
            && (c.centre.y - k.centre.y).abs() <= k.size[1] as f64 / 2.0
    };
    for c in found {
        let dup = |k: &Candidate| match params.dedup {
            0 => (k.centre - c.centre).norm() <= params.dedup_radius,
            1 => inside(&c, k) && inside(k, &c),
            _ => {
                (k.centre - c.centre).norm()
                    <= params.dedup_radius.max(0.25 * k.size[0].min(k.size[1]).max(c.size[0].min(c.size[1])) as f64)
            }
        };
        if !kept.iter().any(dup) {
            kept.push(c);
        }
    }
    kept
}
