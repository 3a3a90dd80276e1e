//! The exact nearest-neighbour search over the stored samples. Each class's samples
//! are ordered so that near ones share a block of 8 and a group of blocks (a k-d
//! split down to the group, then to the block), and each group keeps its bounding
//! box: a group whose box is already farther from the query than the best sample so
//! far cannot hold a nearer one and is skipped whole. The search starts in the group
//! whose box is nearest, so that the bound is tight early. Same distances as a brute
//! force search over every sample.

use super::{FAR, HEAD_DIMS, LANES};

/// Samples per group (a multiple of [`LANES`]).
const GROUP: usize = 16 * LANES;

/// Groups with their box, and the samples in search order.
#[derive(Debug, Clone, PartialEq, Default)]
pub(super) struct SampleIndex {
    dims: usize,
    /// Blocks of [`LANES`] samples, dimension-major (`[d * LANES + lane]` within a
    /// block), a class's last block padded with far-away samples.
    samples: Vec<f32>,
    /// Per group: its first block and its number of blocks.
    groups: Vec<(u32, u32)>,
    /// Per group: the lowest value of each dimension, then the highest.
    boxes: Vec<f32>,
    /// Per class (power, ground, background): its range of groups.
    classes: [(u32, u32); 3],
}

impl SampleIndex {
    /// The index of `dims`-dimensional samples stored as the descriptor stores them
    /// (`blocked`: per class, blocks of [`LANES`] dimension-major, padded), with
    /// `counts` real samples per class.
    pub(super) fn new(dims: usize, blocked: &[f32], counts: [usize; 3]) -> Self {
        let mut index = Self { dims, ..Self::default() };
        let mut first_block = 0;
        for (class, &count) in counts.iter().enumerate() {
            let sample = |i: usize| -> Vec<f32> {
                let (block, lane) = (first_block + i / LANES, i % LANES);
                (0..dims)
                    .map(|d| blocked.get(block * LANES * dims + d * LANES + lane).copied().unwrap_or(FAR))
                    .collect()
            };
            let points: Vec<Vec<f32>> = (0..count).map(sample).collect();
            let mut order: Vec<usize> = (0..count).collect();
            let first_group = index.groups.len() as u32;
            index.add_groups(&points, &mut order);
            index.classes[class] = (first_group, index.groups.len() as u32);
            first_block += count.div_ceil(LANES);
        }
        index
    }

    /// Splits `order` (indices into `points`) at the median of its widest dimension
    /// until a part fits a group, parts of whole blocks, and adds the groups.
    fn add_groups(&mut self, points: &[Vec<f32>], order: &mut [usize]) {
        if order.len() > GROUP {
            let left = (order.len() / 2).div_ceil(GROUP) * GROUP;
            split_at(points, order, left, self.dims);
            let (a, b) = order.split_at_mut(left);
            self.add_groups(points, a);
            self.add_groups(points, b);
            return;
        }
        if order.is_empty() {
            return;
        }
        // Within the group, blocks of near samples too: the partial distances
        // give up a block only when all its samples are too far.
        let mut rest: &mut [usize] = order;
        while rest.len() > LANES {
            split_at(points, rest, LANES, self.dims);
            let (_, b) = rest.split_at_mut(LANES);
            rest = b;
        }
        let first = (self.samples.len() / (LANES * self.dims.max(1))) as u32;
        let mut lo = vec![f32::INFINITY; self.dims];
        let mut hi = vec![f32::NEG_INFINITY; self.dims];
        for block in order.chunks(LANES) {
            let mut values = vec![FAR; LANES * self.dims];
            for (lane, &i) in block.iter().enumerate() {
                for (d, &v) in points[i].iter().enumerate() {
                    values[d * LANES + lane] = v;
                    lo[d] = lo[d].min(v);
                    hi[d] = hi[d].max(v);
                }
            }
            self.samples.extend_from_slice(&values);
        }
        self.groups.push((first, order.len().div_ceil(LANES) as u32));
        self.boxes.extend_from_slice(&lo);
        self.boxes.extend_from_slice(&hi);
    }

    /// Nearest squared distance per class (infinite for a class without samples).
    pub(super) fn nearest(&self, query: &[f32], bounds: &mut Vec<f32>) -> [f32; 3] {
        let dims = self.dims;
        let mut best = [f32::INFINITY; 3];
        if query.len() < dims {
            return best;
        }
        for (class, &(g0, g1)) in self.classes.iter().enumerate() {
            let groups = self.groups.get(g0 as usize..g1 as usize).unwrap_or_default();
            bounds.clear();
            bounds.extend((g0 as usize..g1 as usize).map(|g| self.box_distance(g, query)));
            let Some(first) = (0..bounds.len()).min_by(|&a, &b| bounds[a].total_cmp(&bounds[b])) else { continue };
            let mut lowest = self.search_group(groups[first], query, f32::INFINITY);
            for (k, &group) in groups.iter().enumerate() {
                // A box's distance is summed in another order than a sample's: a
                // hair of slack keeps the search exact under rounding.
                if k != first && bounds[k] * (1.0 - 1e-5) < lowest {
                    lowest = self.search_group(group, query, lowest);
                }
            }
            best[class] = lowest;
        }
        best
    }

    /// Squared distance from `query` to group `g`'s box.
    fn box_distance(&self, g: usize, query: &[f32]) -> f32 {
        let dims = self.dims;
        let Some(b) = self.boxes.get(2 * g * dims..2 * (g + 1) * dims) else { return f32::INFINITY };
        let (lo, hi) = b.split_at(dims);
        query.iter().zip(lo).zip(hi).map(|((&q, &l), &h)| (l - q).max(q - h).max(0.0).powi(2)).sum()
    }

    /// The lowest of `lowest` and the squared distances to the samples of `group`.
    fn search_group(&self, (first, blocks): (u32, u32), query: &[f32], mut lowest: f32) -> f32 {
        let dims = self.dims;
        let size = LANES * dims;
        let Some(samples) = self.samples.get(first as usize * size..(first + blocks) as usize * size) else {
            return lowest;
        };
        // Partial distances over the leading (largest-variance) dimensions
        // already exceed the best so far for most blocks: skip the rest then.
        let head = dims.min(HEAD_DIMS);
        let middle = dims.min(2 * HEAD_DIMS);
        for block in samples.chunks_exact(size) {
            let (front, rest) = block.split_at(head * LANES);
            let (second, rest) = rest.split_at((middle - head) * LANES);
            let mut acc = [0.0f32; LANES];
            accumulate(&mut acc, &query[..head], front);
            if acc.iter().all(|&a| a >= lowest) {
                continue;
            }
            accumulate(&mut acc, &query[head..middle], second);
            if acc.iter().all(|&a| a >= lowest) {
                continue;
            }
            accumulate(&mut acc, &query[middle..dims], rest);
            lowest = acc.iter().fold(lowest, |a, &b| a.min(b));
        }
        lowest
    }
}

/// Reorders `order` so that its first `at` points are those lowest along the
/// dimension in which the points spread most.
fn split_at(points: &[Vec<f32>], order: &mut [usize], at: usize, dims: usize) {
    if at == 0 || at >= order.len() {
        return;
    }
    let spread = |d: usize| {
        let (lo, hi) = order.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &i| {
            let v = points[i][d];
            (lo.min(v), hi.max(v))
        });
        hi - lo
    };
    let Some(widest) = (0..dims).max_by(|&a, &b| spread(a).total_cmp(&spread(b))) else { return };
    order.select_nth_unstable_by(at, |&a, &b| points[a][widest].total_cmp(&points[b][widest]).then(a.cmp(&b)));
}

/// Adds the squared differences between `query` and 8 samples stored
/// dimension-major (`samples[d * 8 + lane]`) to `acc`.
#[inline]
fn accumulate(acc: &mut [f32; LANES], query: &[f32], samples: &[f32]) {
    for (&q, s) in query.iter().zip(samples.chunks_exact(LANES)) {
        for l in 0..LANES {
            let d = s[l] - q;
            acc[l] += d * d;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force over the points of each class.
    fn brute(points: &[Vec<Vec<f32>>; 3], q: &[f32]) -> [f32; 3] {
        let mut out = [f32::INFINITY; 3];
        for (c, class) in points.iter().enumerate() {
            for p in class {
                let d: f32 = p.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
                out[c] = out[c].min(d);
            }
        }
        out
    }

    #[test]
    fn the_grouped_search_finds_what_brute_force_finds() {
        let dims = 11;
        // A deterministic cloud with clusters, class sizes not multiples of 8.
        let mut state = 12345u64;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        let counts = [203usize, 1, 517];
        let points: [Vec<Vec<f32>>; 3] = counts.map(|n| {
            (0..n)
                .map(|i| (0..dims).map(|d| next() * 0.2 + if (i / 40 + d) % 3 == 0 { 0.5 } else { 0.0 }).collect())
                .collect()
        });
        let mut blocked = Vec::new();
        for class in &points {
            for block in class.chunks(LANES) {
                let mut values = vec![FAR; LANES * dims];
                for (lane, p) in block.iter().enumerate() {
                    for (d, &v) in p.iter().enumerate() {
                        values[d * LANES + lane] = v;
                    }
                }
                blocked.extend(values);
            }
        }
        let index = SampleIndex::new(dims, &blocked, counts);
        assert_eq!(index.classes[1].1 - index.classes[1].0, 1, "one sample, one group");
        let mut bounds = Vec::new();
        for _ in 0..300 {
            let q: Vec<f32> = (0..dims).map(|_| next() * 1.5).collect();
            let got = index.nearest(&q, &mut bounds);
            let want = brute(&points, &q);
            for c in 0..3 {
                assert!((got[c] - want[c]).abs() <= 1e-6 * want[c].max(1e-6), "class {c}: {} vs {}", got[c], want[c]);
            }
        }
        // A class without samples stays infinitely far.
        let empty = SampleIndex::new(dims, &blocked[..203usize.div_ceil(8) * 8 * dims], [203, 0, 0]);
        assert_eq!(empty.nearest(&vec![0.0; dims], &mut bounds)[2], f32::INFINITY);
    }
}
