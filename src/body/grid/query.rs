//! Single-point nearest queries, with and without a radius or a hint, and the search behind
//! every query: the rows of cells of a small ball, shells of blocks around a large one.

#[cfg(target_arch = "x86_64")]
use super::scan::x86;
use super::scan::{Best, Lanes};
use super::{cell_index, cell_of_clamped, dist2, fmax, slab_gap, Nearest, PointGrid, BLOCK, LANES, NONE};
use crate::math::sqrt_f32;

/// A radius search whose ball spans at most this many rows of cells scans them directly,
/// without visiting blocks.
const DIRECT_ROWS: usize = 100;
/// Queries farther than this many cells outside the point bounds start from one point per block.
const FAR_CELLS: f32 = 8.0;
/// Cells either side of the query's own cell that seed an unbounded nearest search.
const SEED_CELLS: usize = 1;

impl PointGrid {
    /// The nearest point within `radius` (metres) of `q`, distance `<= radius` inclusive (in
    /// squared `f32` distances), lowest index on ties; `None` when no point is that close.
    pub fn nearest_within_one(&self, q: [f32; 3], radius: f32) -> Option<Nearest> {
        self.nearest_within_one_hinted(q, radius, NONE)
    }

    /// As [`nearest_within_one`](Self::nearest_within_one), starting from a guess: the point
    /// `hint` (e.g. last frame's answer; any index `>= len()` means no guess). The result is the
    /// same whatever the hint; a good one makes the search faster.
    pub fn nearest_within_one_hinted(&self, q: [f32; 3], radius: f32, hint: u32) -> Option<Nearest> {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU has AVX2 (checked in `new`).
            return unsafe { self.within_one_avx2(q, radius, hint) };
        }
        self.within_one::<Lanes>(q, radius, hint)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn within_one_avx2(&self, q: [f32; 3], radius: f32, hint: u32) -> Option<Nearest> {
        self.within_one::<x86::Avx2Best>(q, radius, hint)
    }

    #[inline(always)]
    pub(super) fn within_one<B: Best>(&self, q: [f32; 3], radius: f32, hint: u32) -> Option<Nearest> {
        if self.n_points == 0 || radius.is_nan() || radius < 0.0 {
            return None;
        }
        let r2 = radius * radius;
        if box_dist2(q, self.lo, self.hi) > self.padded(r2) {
            return None;
        }
        let mut best = (NONE, r2);
        if let Some(p) = self.point(hint) {
            consider(&mut best, dist2(p, q), hint);
        }
        found(self.search::<B>(q, best))
    }

    /// The nearest point to `q`, lowest index on ties, with no distance limit; `None` only when
    /// the grid is empty.
    ///
    /// Runs radius searches with radii `d0 + c·2^k` (`d0` the distance from `q` to the point
    /// bounds, `c` the cell edge, k = 1, 2, ...) until one finds a point: that point is the
    /// nearest overall. A radius search whose ball spans few cells scans them all; a larger one
    /// visits blocks in shells around the query's block and stops by this rule: after the shells
    /// up to Chebyshev distance `k` have been visited, every unseen point lies in one of the (up
    /// to six) slabs of the point bounds beyond the faces of the visited box; the search ends once
    /// the nearest of those slabs is strictly farther than the best point found, or than the
    /// radius (or the box covers the grid). Blocks whose points' bounding box is farther are
    /// skipped, which keeps queries far outside the grid cheap.
    /// Coordinates beyond about 1e18 m overflow `f32` squared distances; such queries get a valid
    /// point index but not necessarily the nearest. A NaN coordinate gives `None`.
    pub fn nearest_one(&self, q: [f32; 3]) -> Option<Nearest> {
        self.nearest_one_hinted(q, NONE)
    }

    /// As [`nearest_one`](Self::nearest_one), starting from a guess: the point `hint` (e.g. last
    /// frame's answer; any index `>= len()` means no guess). The result is the same whatever the
    /// hint; a good one replaces the growing radii by a single search within the hint's distance.
    pub fn nearest_one_hinted(&self, q: [f32; 3], hint: u32) -> Option<Nearest> {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU has AVX2 (checked in `new`).
            return unsafe { self.nearest_one_avx2(q, hint) };
        }
        self.nearest_one_with::<Lanes>(q, hint)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn nearest_one_avx2(&self, q: [f32; 3], hint: u32) -> Option<Nearest> {
        self.nearest_one_with::<x86::Avx2Best>(q, hint)
    }

    #[inline(always)]
    pub(super) fn nearest_one_with<B: Best>(&self, q: [f32; 3], hint: u32) -> Option<Nearest> {
        if self.n_points == 0 {
            return None;
        }
        if let Some(p) = self.point(hint) {
            let d2 = dist2(p, q);
            if d2.is_finite() {
                return found(self.search::<B>(q, (hint, d2)));
            }
        }
        let lower = sqrt_f32(box_dist2(q, self.lo, self.hi));
        if lower > FAR_CELLS * self.cell {
            // Far outside: the nearest of one point per block bounds the answer within about a
            // block; the block boxes then prune most blocks.
            let mut guess = (NONE, f32::INFINITY);
            for &i in &self.block_any[..self.n_blocks()] {
                if let Some(p) = self.point(i) {
                    consider(&mut guess, dist2(p, q), i);
                }
            }
            if guess.1.is_finite() {
                return found(self.search::<B>(q, guess));
            }
        }
        if lower <= self.cell {
            // Near the points: the query's own row of cells, a few cells either side, usually
            // holds a point; its distance bounds one ball search.
            let c = cell_of_clamped(q, self.lo, self.inv_edge, self.blocks);
            let dims = self.cells();
            let row = dims[0] * (c[1] + dims[1] * c[2]);
            let (x0, x1) = (c[0].saturating_sub(SEED_CELLS), (c[0] + SEED_CELLS).min(dims[0] - 1));
            let mut seed = B::new(f32::INFINITY);
            let d2 =
                self.scan(q, self.cell_start[row + x0] as usize, self.cell_start[row + x1 + 1] as usize, &mut seed);
            if d2.is_finite() {
                return found(self.search::<B>(q, seed.best()));
            }
        }
        // Radius searches with a growing radius: the first that finds a point has found the
        // nearest.
        let ext = [self.hi[0] - self.lo[0], self.hi[1] - self.lo[1], self.hi[2] - self.lo[2]];
        let diag = sqrt_f32(ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]);
        let mut step = 2.0 * self.cell;
        loop {
            let r = lower + step;
            let best = self.search::<B>(q, (NONE, r * r));
            if best.0 != NONE {
                return found(best);
            }
            if step.is_nan() || step > 2.0 * diag + self.cell || !(r * r).is_finite() {
                // Every point is within `lower + diag`; only overflow or NaN ends up here.
                return found(self.search::<B>(q, (NONE, f32::INFINITY)));
            }
            step *= 2.0;
        }
    }

    /// The position of input point `i` of the last rebuild, if there is one.
    #[inline(always)]
    pub(super) fn point(&self, i: u32) -> Option<[f32; 3]> {
        self.input[..self.n_points].get(i as usize).copied()
    }

    /// A squared distance widened by the rounding slack, for pruning comparisons.
    #[inline(always)]
    pub(super) fn padded(&self, d2: f32) -> f32 {
        let d = sqrt_f32(d2) * (1.0 + 1e-5) + self.pad;
        d * d
    }

    /// The best `(index, squared distance)` among `best` (a guess, or `NONE` with the limit) and
    /// the points within `sqrt(best.1)` of `q`.
    #[inline(always)]
    fn search<B: Best>(&self, q: [f32; 3], best: (u32, f32)) -> (u32, f32) {
        let mut lanes = B::new(best.1);
        lanes.offer(best.1, best.0);
        let limit2 = best.1;
        let qcell = cell_of_clamped(q, self.lo, self.inv_edge, self.blocks);
        if limit2.is_finite() {
            // A small ball: scan its rows directly, the query's own row first.
            let (lo, hi) = self.cell_range(q, limit2);
            if (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1) <= DIRECT_ROWS {
                self.scan_ball(q, qcell, lo, hi, &mut lanes, best.0 != NONE);
                return lanes.best();
            }
        }
        let start = qcell.map(|c| c / BLOCK);
        let last = self.blocks.map(|b| b - 1);
        let mut k = 0usize;
        loop {
            let bound = lanes.bound();
            if k > 0 {
                let vlo = [0, 1, 2].map(|a| start[a].saturating_sub(k - 1));
                let vhi = [0, 1, 2].map(|a| (start[a] + k - 1).min(last[a]));
                if vlo == [0; 3] && vhi == last {
                    break;
                }
                if self.unseen_bound2(q, vlo, vhi) > self.padded(bound) {
                    break;
                }
            }
            let mut rlo = [0, 1, 2].map(|a| start[a].saturating_sub(k));
            let mut rhi = [0, 1, 2].map(|a| (start[a] + k).min(last[a]));
            if bound.is_finite() {
                let (alo, ahi) = self.cell_range(q, bound);
                for a in 0..3 {
                    rlo[a] = rlo[a].max(alo[a] / BLOCK);
                    rhi[a] = rhi[a].min(ahi[a] / BLOCK);
                }
            }
            self.visit_shell(q, qcell, k, rlo, rhi, &mut lanes);
            k += 1;
        }
        lanes.best()
    }

    /// Visits the blocks at Chebyshev distance exactly `k` from the block of `qcell` inside
    /// `[rlo, rhi]`.
    #[inline(always)]
    fn visit_shell<B: Best>(
        &self,
        q: [f32; 3],
        qcell: [usize; 3],
        k: usize,
        rlo: [usize; 3],
        rhi: [usize; 3],
        lanes: &mut B,
    ) {
        if (0..3).any(|a| rlo[a] > rhi[a]) {
            return;
        }
        let start = qcell.map(|c| c / BLOCK);
        for bz in rlo[2]..=rhi[2] {
            for by in rlo[1]..=rhi[1] {
                if bz.abs_diff(start[2]) == k || by.abs_diff(start[1]) == k {
                    for bx in rlo[0]..=rhi[0] {
                        self.visit_block(q, qcell, [bx, by, bz], lanes);
                    }
                } else {
                    // Only the two ends of the row are on the shell.
                    if let Some(bx) = start[0].checked_sub(k) {
                        if bx >= rlo[0] && bx <= rhi[0] {
                            self.visit_block(q, qcell, [bx, by, bz], lanes);
                        }
                    }
                    let bx = start[0] + k;
                    if k > 0 && bx >= rlo[0] && bx <= rhi[0] {
                        self.visit_block(q, qcell, [bx, by, bz], lanes);
                    }
                }
            }
        }
    }

    /// Scans the cells of block `b` that the current best ball reaches: the query's own cell
    /// first (a small ball early), then row by row, skipping rows beyond the ball and trimming
    /// each row to the ball's chord.
    #[inline(always)]
    fn visit_block<B: Best>(&self, q: [f32; 3], qcell: [usize; 3], b: [usize; 3], lanes: &mut B) {
        let bi = b[0] + self.blocks[0] * (b[1] + self.blocks[1] * b[2]);
        if self.block_any[bi] == NONE {
            return;
        }
        let (blo, bhi) = self.block_box(b);
        if box_dist2(q, blo, bhi) > self.padded(lanes.bound()) {
            return;
        }
        let dims = self.cells();
        let origin = b.map(|x| x * BLOCK);
        if qcell.map(|c| c / BLOCK) == b {
            let s = qcell[0] + dims[0] * (qcell[1] + dims[1] * qcell[2]);
            self.scan(q, self.cell_start[s] as usize, self.cell_start[s + 1] as usize, lanes);
        }
        let bound = lanes.bound();
        let (lo, hi, pb) = if bound.is_finite() {
            let (clo, chi) = self.cell_range(q, bound);
            let lo = [0, 1, 2].map(|a| clo[a].max(origin[a]));
            let hi = [0, 1, 2].map(|a| chi[a].min(origin[a] + BLOCK - 1));
            (lo, hi, self.padded(bound))
        } else {
            // Only for limits beyond f32 range: no ball to prune with.
            (origin, origin.map(|o| o + BLOCK - 1), f32::INFINITY)
        };
        let last = (origin[0] + BLOCK - 1) as f32;
        for z in lo[2]..=hi[2] {
            let dz = self.gap(q, 2, z);
            let dz2 = dz * dz;
            if dz2 > pb {
                continue;
            }
            for y in lo[1]..=hi[1] {
                let dy = self.gap(q, 1, y);
                let rest = pb - dz2 - dy * dy;
                if rest < 0.0 {
                    continue;
                }
                let r = sqrt_f32(rest);
                let x0 = cell_index((q[0] - r - self.lo[0]) * self.inv_edge[0], last).max(origin[0]);
                let x1 = cell_index((q[0] + r - self.lo[0]) * self.inv_edge[0], last);
                if x0 > x1 {
                    continue;
                }
                // Cells of one row are consecutive, so their points are contiguous.
                let row = dims[0] * (y + dims[1] * z);
                self.scan(q, self.cell_start[row + x0] as usize, self.cell_start[row + x1 + 1] as usize, lanes);
            }
        }
    }

    /// Scans the rows of cells in `[lo, hi]` (cell coordinates) that the best ball reaches,
    /// each row trimmed to the ball's chord. Rows are visited from the query's row outwards, so
    /// that the ball shrinks early.
    #[inline(always)]
    /// `seeded`: the search starts from a candidate, so its bound is already close.
    fn scan_ball<B: Best>(
        &self,
        q: [f32; 3],
        c: [usize; 3],
        lo: [usize; 3],
        hi: [usize; 3],
        lanes: &mut B,
        seeded: bool,
    ) {
        let mut tight = seeded;
        let dims = self.cells();
        let last = (dims[0] - 1) as f32;
        // The padded best, recomputed only when the best changes.
        let mut bound = lanes.bound();
        let mut pb = self.padded(bound);
        for z in CenterOut::new(c[2], lo[2], hi[2]) {
            let dz = self.gap(q, 2, z);
            let dz2 = dz * dz;
            if dz2 > pb {
                continue;
            }
            for y in CenterOut::new(c[1], lo[1], hi[1]) {
                let dy = self.gap(q, 1, y);
                let rest = pb - dz2 - dy * dy;
                if rest < 0.0 {
                    continue;
                }
                let r = sqrt_f32(rest);
                let x0 = cell_index((q[0] - r - self.lo[0]) * self.inv_edge[0], last);
                let x1 = cell_index((q[0] + r - self.lo[0]) * self.inv_edge[0], last);
                let row = dims[0] * (y + dims[1] * z);
                let (p0, p1) = (self.cell_start[row + x0] as usize, self.cell_start[row + x1 + 1] as usize);
                if p1 > p0 {
                    let b = self.scan_with(q, p0, p1, lanes, tight.then_some(bound));
                    // After the query's own row the bound is close to the answer.
                    tight = true;
                    if b < bound {
                        bound = b;
                        pb = self.padded(b);
                    }
                }
            }
        }
    }

    /// Distance along axis `a` from `q` to the slab of cells with coordinate `c` (0 inside).
    #[inline(always)]
    fn gap(&self, q: [f32; 3], a: usize, c: usize) -> f32 {
        slab_gap(q[a], self.slab(a, c))
    }

    /// The extent `[lo, hi]` along axis `a` of the slab of cells with coordinate `c` (metres).
    #[inline(always)]
    pub(super) fn slab(&self, a: usize, c: usize) -> [f32; 2] {
        let lo = self.lo[a] + c as f32 * self.edge[a];
        [lo, lo + self.edge[a]]
    }

    /// Offers the sorted points `p0..p1` (and up to `LANES - 1` after them, harmless: every
    /// point offered is a real candidate, or NaN padding) to `lanes`; returns the new bound.
    #[inline(always)]
    fn scan<B: Best>(&self, q: [f32; 3], p0: usize, p1: usize, best: &mut B) -> f32 {
        self.scan_with(q, p0, p1, best, None)
    }

    /// As [`scan`](Self::scan); `tight` is `best`'s current bound when it is already close to the
    /// answer.
    #[inline(always)]
    fn scan_with<B: Best>(&self, q: [f32; 3], p0: usize, p1: usize, best: &mut B, tight: Option<f32>) -> f32 {
        if p1 <= p0 {
            return best.bound();
        }
        let end = p0 + (p1 - p0).next_multiple_of(LANES);
        let [xs, ys, zs] = &self.sorted;
        let pts = (&xs[p0..end], &ys[p0..end], &zs[p0..end], &self.sorted_index[p0..end]);
        match tight {
            Some(bound) => best.scan_tight(pts, q, bound),
            None => best.scan(pts, q),
        }
    }

    /// Cell coordinates (clamped into the grid) of the box around `q` reaching `sqrt(d2)`.
    #[inline(always)]
    fn cell_range(&self, q: [f32; 3], d2: f32) -> ([usize; 3], [usize; 3]) {
        let r = sqrt_f32(self.padded(d2));
        let lo = cell_of_clamped([q[0] - r, q[1] - r, q[2] - r], self.lo, self.inv_edge, self.blocks);
        let hi = cell_of_clamped([q[0] + r, q[1] + r, q[2] + r], self.lo, self.inv_edge, self.blocks);
        (lo, hi)
    }

    /// Lower bound of the squared distance from `q` to any point outside the blocks `[vlo, vhi]`:
    /// such a point lies in the point bounds beyond one face of that box.
    fn unseen_bound2(&self, q: [f32; 3], vlo: [usize; 3], vhi: [usize; 3]) -> f32 {
        let mut bound = f32::INFINITY;
        for a in 0..3 {
            let edge = self.edge[a] * BLOCK as f32;
            if vlo[a] > 0 {
                let mut hi = self.hi;
                hi[a] = (self.lo[a] + vlo[a] as f32 * edge).max(self.lo[a]);
                bound = bound.min(box_dist2(q, self.lo, hi));
            }
            if vhi[a] < self.blocks[a] - 1 {
                // Clamped so that rounding in the cell assignment cannot make the slab empty.
                let mut lo = self.lo;
                lo[a] = (self.lo[a] + (vhi[a] + 1) as f32 * edge).min(self.hi[a]);
                bound = bound.min(box_dist2(q, lo, self.hi));
            }
        }
        bound
    }
}

/// `c, c - 1, c + 1, c - 2, c + 2, ...` within `[lo, hi]` (which holds `c`).
struct CenterOut {
    c: usize,
    lo: usize,
    hi: usize,
    k: usize,
    below: bool,
}

impl CenterOut {
    #[inline(always)]
    fn new(c: usize, lo: usize, hi: usize) -> CenterOut {
        CenterOut { c, lo, hi, k: 0, below: false }
    }
}

impl Iterator for CenterOut {
    type Item = usize;
    #[inline(always)]
    fn next(&mut self) -> Option<usize> {
        loop {
            if self.k == 0 {
                self.k = 1;
                self.below = true;
                return Some(self.c);
            }
            if self.c < self.lo + self.k && self.c + self.k > self.hi {
                return None;
            }
            let (k, below) = (self.k, self.below);
            if below {
                self.below = false;
            } else {
                self.below = true;
                self.k += 1;
            }
            if below && self.c >= self.lo + k {
                return Some(self.c - k);
            }
            if !below && self.c + k <= self.hi {
                return Some(self.c + k);
            }
        }
    }
}

/// A search result as a [`Nearest`].
#[inline(always)]
pub(super) fn found((i, d2): (u32, f32)) -> Option<Nearest> {
    (i != NONE).then(|| Nearest { index: i, distance: sqrt_f32(d2) })
}

/// Takes `(i, d2)` if it is nearer, or as near with a lower index.
#[inline(always)]
pub(super) fn consider(best: &mut (u32, f32), d2: f32, i: u32) {
    if d2 <= best.1 && (d2 < best.1 || i < best.0) {
        *best = (i, d2);
    }
}

/// Squared distance from `q` to the box `[lo, hi]` (infinite for an empty box, `lo > hi`).
#[inline(always)]
fn box_dist2(q: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let mut d2 = 0.0;
    for a in 0..3 {
        if lo[a] > hi[a] {
            return f32::INFINITY;
        }
        let d = fmax(fmax(lo[a] - q[a], q[a] - hi[a]), 0.0);
        d2 += d * d;
    }
    d2
}
