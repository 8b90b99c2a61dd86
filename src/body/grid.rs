//! A uniform grid over a point set (body vertices or face centroids), rebuilt every frame without
//! allocation, answering exact nearest-point queries.
//!
//! Layout: the cells (edge [`PointGrid::cell_size`], metres) are grouped in blocks of
//! [`BLOCK`]³ cells and numbered block by block, so that the points of one block, and of one row
//! of cells inside a block, are contiguous after the counting sort. Each block also keeps the tight
//! bounding box of its points. A query visits blocks in shells (Chebyshev rings) around the block
//! of the query (clamped into the grid), skips blocks whose box is farther than the best distance
//! so far, and inside a block scans only the rows of cells that the current best-distance ball
//! reaches. It stops when every point not yet seen lies, by a lower bound, strictly farther than
//! the best found (see [`PointGrid::nearest_one`]), so results are exact, also for queries far
//! outside the grid, where the per-block boxes keep the number of points scanned small.
//!
//! Ties: among points at the same squared distance (computed in `f32` as `dx² + dy² + dz²`) the
//! lowest point index wins. Results do not depend on the grid resolution.

use crate::error::{Error, Result};
use crate::math::finite3;
use alloc::vec;
use alloc::vec::Vec;

/// Cells per block edge.
pub const BLOCK: usize = 4;
const BLOCK_CELLS: usize = BLOCK * BLOCK * BLOCK;
const NONE: u32 = u32::MAX;

/// Default number of cells per point the grid aims for (see [`PointGrid::set_cells_per_point`]).
pub const DEFAULT_CELLS_PER_POINT: f32 = 2.0;

/// A nearest point: its index in the point set and its distance (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// Index of the point in the slice given to [`PointGrid::rebuild`].
    pub index: u32,
    /// Euclidean distance from the query, metres.
    pub distance: f32,
}

/// A uniform grid over at most `capacity` points, at most `max_cells` cells (both fixed at
/// creation). [`rebuild`](Self::rebuild) refits the bounds to the points of the frame; the queries
/// write into caller slices. Neither allocates.
#[derive(Clone, Debug)]
pub struct PointGrid {
    capacity: usize,
    max_cells: usize,
    cells_per_point: f32,
    n_points: usize,
    /// Tight bounds of the points of the frame.
    lo: [f32; 3],
    hi: [f32; 3],
    cell: f32,
    inv_cell: f32,
    /// Blocks per axis; cells per axis are `BLOCK` times as many.
    blocks: [usize; 3],
    /// Slack added to every pruning bound, so that rounding in cell assignment never prunes a
    /// point that could win.
    pad: f32,
    /// `cell_start[s]..cell_start[s + 1]` are the sorted points of cell slot `s`.
    cell_start: Vec<u32>,
    /// Scratch: the cell slot of every input point.
    point_slot: Vec<u32>,
    sorted: Vec<[f32; 3]>,
    sorted_index: Vec<u32>,
    block_lo: Vec<[f32; 3]>,
    block_hi: Vec<[f32; 3]>,
}

impl PointGrid {
    /// A grid for up to `capacity` points using at most `max_cells` cells (memory: about
    /// `4·max_cells + 32·capacity` bytes).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] when `max_cells` is below one block (`BLOCK³ = 64` cells) or when
    /// `capacity` does not fit in `u32`.
    pub fn new(capacity: usize, max_cells: usize) -> Result<PointGrid> {
        if max_cells < BLOCK_CELLS || max_cells > u32::MAX as usize {
            return Err(Error::OutOfRange { what: "grid max_cells", index: max_cells });
        }
        if capacity >= u32::MAX as usize {
            return Err(Error::OutOfRange { what: "grid capacity", index: capacity });
        }
        let max_blocks = max_cells / BLOCK_CELLS;
        Ok(PointGrid {
            capacity,
            max_cells,
            cells_per_point: DEFAULT_CELLS_PER_POINT,
            n_points: 0,
            lo: [0.0; 3],
            hi: [0.0; 3],
            cell: 1.0,
            inv_cell: 1.0,
            blocks: [1; 3],
            pad: 0.0,
            cell_start: vec![0; max_blocks * BLOCK_CELLS + 1],
            point_slot: vec![0; capacity],
            sorted: vec![[0.0; 3]; capacity],
            sorted_index: vec![0; capacity],
            block_lo: vec![[0.0; 3]; max_blocks],
            block_hi: vec![[0.0; 3]; max_blocks],
        })
    }

    /// Sets how many cells per point the next [`rebuild`](Self::rebuild)s aim for (still bounded
    /// by `max_cells`); default [`DEFAULT_CELLS_PER_POINT`]. Only speed depends on it.
    pub fn set_cells_per_point(&mut self, cells_per_point: f32) -> Result<()> {
        if !(cells_per_point > 0.0 && cells_per_point.is_finite()) {
            return Err(Error::OutOfRange { what: "cells per point", index: 0 });
        }
        self.cells_per_point = cells_per_point;
        Ok(())
    }

    /// Maximum number of points.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    /// Maximum number of cells.
    pub fn max_cells(&self) -> usize {
        self.max_cells
    }
    /// Number of points of the last rebuild.
    pub fn len(&self) -> usize {
        self.n_points
    }
    /// True when the last rebuild had no point.
    pub fn is_empty(&self) -> bool {
        self.n_points == 0
    }
    /// Cell edge of the last rebuild, metres.
    pub fn cell_size(&self) -> f32 {
        self.cell
    }
    /// Cells per axis of the last rebuild (multiples of [`BLOCK`]).
    pub fn cells(&self) -> [usize; 3] {
        self.blocks.map(|b| b * BLOCK)
    }
    /// Tight bounds `(min, max)` of the points of the last rebuild (metres).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        (self.lo, self.hi)
    }

    /// Re-sorts the grid around `points` (the frame's positions, metres): refits the bounds,
    /// picks the cell size, counting-sorts the points into cells and computes the block boxes.
    /// Allocates nothing.
    ///
    /// # Errors
    /// [`Error::CapacityExceeded`] for more than `capacity` points; [`Error::NonFinite`] for a
    /// NaN/Inf coordinate (or a spread that overflows `f32`). The grid is left empty on error.
    pub fn rebuild(&mut self, points: &[[f32; 3]]) -> Result<()> {
        self.n_points = 0;
        let n = points.len();
        if n > self.capacity {
            return Err(Error::CapacityExceeded { what: "grid points", capacity: self.capacity, needed: n });
        }
        if n == 0 {
            return Ok(());
        }
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for (i, p) in points.iter().enumerate() {
            if !finite3(*p) {
                return Err(Error::NonFinite { what: "grid point", index: i });
            }
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        if !finite3(ext) {
            return Err(Error::NonFinite { what: "grid point spread", index: 0 });
        }
        self.choose_cells(n, ext);
        self.lo = lo;
        self.hi = hi;
        let scale = ext.iter().chain(lo.iter()).chain(hi.iter()).fold(0.0f32, |m, &v| m.max(v.abs()));
        self.pad = 1e-5 * scale + f32::MIN_POSITIVE;

        let slots = self.n_blocks() * BLOCK_CELLS;
        let start = &mut self.cell_start[..slots + 1];
        start.fill(0);
        for (p, slot) in points.iter().zip(self.point_slot.iter_mut()) {
            let c = cell_of(*p, lo, self.inv_cell, self.blocks);
            *slot = slot_of(c, self.blocks) as u32;
            start[*slot as usize + 1] += 1;
        }
        for s in 0..slots {
            start[s + 1] += start[s];
        }
        // Scatter with start[s] as the cursor of slot s; afterwards start[s] is the end of s,
        // i.e. the beginning of s + 1, so shift back by one.
        for (i, (p, &slot)) in points.iter().zip(self.point_slot.iter()).enumerate() {
            let at = start[slot as usize] as usize;
            start[slot as usize] += 1;
            self.sorted[at] = *p;
            self.sorted_index[at] = i as u32;
        }
        for s in (1..=slots).rev() {
            start[s] = start[s - 1];
        }
        start[0] = 0;

        for b in 0..slots / BLOCK_CELLS {
            let (p0, p1) = (start[b * BLOCK_CELLS] as usize, start[(b + 1) * BLOCK_CELLS] as usize);
            let (mut blo, mut bhi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for p in &self.sorted[p0..p1] {
                for a in 0..3 {
                    blo[a] = blo[a].min(p[a]);
                    bhi[a] = bhi[a].max(p[a]);
                }
            }
            self.block_lo[b] = blo;
            self.block_hi[b] = bhi;
        }
        self.n_points = n;
        Ok(())
    }

    fn n_blocks(&self) -> usize {
        self.blocks[0] * self.blocks[1] * self.blocks[2]
    }

    /// Cell edge so that the grid has about `cells_per_point · n` cells, never more than
    /// `max_cells` (block padding included).
    fn choose_cells(&mut self, n: usize, ext: [f32; 3]) {
        let emax = ext[0].max(ext[1]).max(ext[2]);
        let max_blocks = self.max_cells / BLOCK_CELLS;
        if emax <= 0.0 {
            self.cell = 1.0;
            self.inv_cell = 1.0;
            self.blocks = [1; 3];
            return;
        }
        let target = (self.cells_per_point as f64 * n as f64).clamp(1.0, self.max_cells as f64);
        // Flat or thin point sets: treat the thin axes as 1/1000 of the widest for the volume.
        let vol: f64 = ext.iter().map(|&e| e.max(emax * 1e-3) as f64).product();
        let mut cell = libm::cbrt(vol / target).max(emax as f64 * 1e-6);
        loop {
            let blocks = ext.map(|e| ((e as f64 / cell) as usize + 1).div_ceil(BLOCK));
            if blocks[0].saturating_mul(blocks[1]).saturating_mul(blocks[2]) <= max_blocks {
                self.blocks = blocks;
                break;
            }
            cell *= 1.25;
        }
        self.cell = cell as f32;
        self.inv_cell = (1.0 / cell) as f32;
    }

    /// The nearest point within `radius` (metres) of `q`, distance `<= radius` inclusive (in
    /// squared `f32` distances), lowest index on ties; `None` when no point is that close.
    pub fn nearest_within_one(&self, q: [f32; 3], radius: f32) -> Option<Nearest> {
        if self.n_points == 0 || !(radius >= 0.0) {
            return None;
        }
        let r2 = radius * radius;
        if box_dist2(q, self.lo, self.hi) > self.padded(r2) {
            return None;
        }
        let (i, d2) = self.search(q, r2);
        (i != NONE).then(|| Nearest { index: i, distance: libm::sqrtf(d2) })
    }

    /// The nearest point to `q`, lowest index on ties, with no distance limit; `None` only when
    /// the grid is empty.
    ///
    /// Stopping rule: after the shells of blocks up to Chebyshev distance `k` around the start
    /// block have been visited, every unseen point lies in one of the (up to six) slabs of the
    /// point bounds beyond the faces of that visited box; the search ends once the nearest of those
    /// slabs is strictly farther than the best point found (or the box covers the grid).
    /// Coordinates beyond about 1e18 m overflow `f32` squared distances; such queries get a valid
    /// point index but not necessarily the nearest.
    pub fn nearest_one(&self, q: [f32; 3]) -> Option<Nearest> {
        if self.n_points == 0 {
            return None;
        }
        let (i, d2) = self.search(q, f32::INFINITY);
        (i != NONE).then(|| Nearest { index: i, distance: libm::sqrtf(d2) })
    }

    /// For every query point (metres), the nearest point within `radius`, see
    /// [`nearest_within_one`](Self::nearest_within_one). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is not as long as `queries`; [`Error::OutOfRange`] for a
    /// negative or non-finite radius; [`Error::NonFinite`] for a NaN/Inf query coordinate (`out`
    /// is then partly written).
    pub fn nearest_within(&self, queries: &[[f32; 3]], radius: f32, out: &mut [Option<Nearest>]) -> Result<()> {
        if out.len() != queries.len() {
            return Err(Error::SizeMismatch { what: "nearest-within output", expected: queries.len(), got: out.len() });
        }
        if !(radius >= 0.0 && radius.is_finite()) {
            return Err(Error::OutOfRange { what: "query radius", index: 0 });
        }
        for (i, (q, o)) in queries.iter().zip(out.iter_mut()).enumerate() {
            if !finite3(*q) {
                return Err(Error::NonFinite { what: "query point", index: i });
            }
            *o = self.nearest_within_one(*q, radius);
        }
        Ok(())
    }

    /// For every query point (metres), the nearest point with no distance limit, see
    /// [`nearest_one`](Self::nearest_one). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::Empty`] when the grid holds no point; [`Error::SizeMismatch`] when `out` is not as
    /// long as `queries`; [`Error::NonFinite`] for a NaN/Inf query coordinate (`out` is then
    /// partly written).
    pub fn nearest(&self, queries: &[[f32; 3]], out: &mut [Nearest]) -> Result<()> {
        if out.len() != queries.len() {
            return Err(Error::SizeMismatch { what: "nearest output", expected: queries.len(), got: out.len() });
        }
        if self.n_points == 0 {
            return Err(Error::Empty { what: "point grid" });
        }
        for (i, (q, o)) in queries.iter().zip(out.iter_mut()).enumerate() {
            if !finite3(*q) {
                return Err(Error::NonFinite { what: "query point", index: i });
            }
            // Non-empty grid: the search always returns a point.
            *o = self.nearest_one(*q).unwrap_or(Nearest { index: 0, distance: f32::INFINITY });
        }
        Ok(())
    }

    /// A squared distance widened by the rounding slack, for pruning comparisons.
    #[inline(always)]
    fn padded(&self, d2: f32) -> f32 {
        let d = libm::sqrtf(d2) * (1.0 + 1e-5) + self.pad;
        d * d
    }

    /// Best `(index, squared distance)` with squared distance `<= limit2` (or `NONE`).
    fn search(&self, q: [f32; 3], limit2: f32) -> (u32, f32) {
        let mut best = (NONE, limit2);
        let start = cell_of_clamped(q, self.lo, self.inv_cell, self.blocks).map(|c| c / BLOCK);
        let last = self.blocks.map(|b| b - 1);
        let mut k = 0usize;
        loop {
            if k > 0 {
                let vlo = [0, 1, 2].map(|a| start[a].saturating_sub(k - 1));
                let vhi = [0, 1, 2].map(|a| (start[a] + k - 1).min(last[a]));
                if vlo == [0; 3] && vhi == last {
                    break;
                }
                if self.unseen_bound2(q, vlo, vhi) > self.padded(best.1) {
                    break;
                }
            }
            let mut rlo = [0, 1, 2].map(|a| start[a].saturating_sub(k));
            let mut rhi = [0, 1, 2].map(|a| (start[a] + k).min(last[a]));
            if best.1.is_finite() {
                let (alo, ahi) = self.cell_range(q, best.1);
                for a in 0..3 {
                    rlo[a] = rlo[a].max(alo[a] / BLOCK);
                    rhi[a] = rhi[a].min(ahi[a] / BLOCK);
                }
            }
            self.visit_shell(q, start, k, rlo, rhi, &mut best);
            k += 1;
        }
        best
    }

    /// Visits the blocks at Chebyshev distance exactly `k` from `start` inside `[rlo, rhi]`.
    fn visit_shell(&self, q: [f32; 3], start: [usize; 3], k: usize, rlo: [usize; 3], rhi: [usize; 3], best: &mut (u32, f32)) {
        if (0..3).any(|a| rlo[a] > rhi[a]) {
            return;
        }
        for bz in rlo[2]..=rhi[2] {
            for by in rlo[1]..=rhi[1] {
                let on_shell = bz.abs_diff(start[2]) == k || by.abs_diff(start[1]) == k;
                if on_shell {
                    for bx in rlo[0]..=rhi[0] {
                        self.visit_block(q, [bx, by, bz], best);
                    }
                } else {
                    // Only the two ends of the row are on the shell.
                    if let Some(bx) = start[0].checked_sub(k) {
                        if bx >= rlo[0] && bx <= rhi[0] {
                            self.visit_block(q, [bx, by, bz], best);
                        }
                    }
                    let bx = start[0] + k;
                    if k > 0 && bx >= rlo[0] && bx <= rhi[0] {
                        self.visit_block(q, [bx, by, bz], best);
                    }
                }
            }
        }
    }

    fn visit_block(&self, q: [f32; 3], b: [usize; 3], best: &mut (u32, f32)) {
        let bi = b[0] + self.blocks[0] * (b[1] + self.blocks[1] * b[2]);
        let base = bi * BLOCK_CELLS;
        let (p0, p1) = (self.cell_start[base] as usize, self.cell_start[base + BLOCK_CELLS] as usize);
        if p0 == p1 || box_dist2(q, self.block_lo[bi], self.block_hi[bi]) > self.padded(best.1) {
            return;
        }
        if !best.1.is_finite() {
            // Nothing found yet: first the cell of the query if it is in this block, to get a
            // small search ball quickly, else the whole block.
            let c = cell_of_clamped(q, self.lo, self.inv_cell, self.blocks);
            if c.map(|x| x / BLOCK) == b {
                let s = base + local_of(c);
                self.scan(q, self.cell_start[s] as usize, self.cell_start[s + 1] as usize, best);
            }
            if !best.1.is_finite() {
                self.scan(q, p0, p1, best);
                return;
            }
        }
        let (clo, chi) = self.cell_range(q, best.1);
        let lo = [0, 1, 2].map(|a| clo[a].max(b[a] * BLOCK) - b[a] * BLOCK);
        let hi = [0, 1, 2].map(|a| chi[a].min(b[a] * BLOCK + BLOCK - 1) as isize - (b[a] * BLOCK) as isize);
        if (0..3).any(|a| (lo[a] as isize) > hi[a]) {
            return;
        }
        let hi = hi.map(|h| h as usize);
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                // Cells of one row are consecutive slots, so their points are contiguous.
                let s0 = base + local_of([lo[0], y, z]);
                let s1 = base + local_of([hi[0], y, z]) + 1;
                self.scan(q, self.cell_start[s0] as usize, self.cell_start[s1] as usize, best);
            }
        }
    }

    #[inline(always)]
    fn scan(&self, q: [f32; 3], p0: usize, p1: usize, best: &mut (u32, f32)) {
        for (p, &i) in self.sorted[p0..p1].iter().zip(&self.sorted_index[p0..p1]) {
            let d2 = dist2(*p, q);
            if d2 <= best.1 && (d2 < best.1 || i < best.0) {
                *best = (i, d2);
            }
        }
    }

    /// Cell coordinates (clamped into the grid) of the box around `q` reaching `sqrt(d2)`.
    fn cell_range(&self, q: [f32; 3], d2: f32) -> ([usize; 3], [usize; 3]) {
        let r = libm::sqrtf(self.padded(d2));
        let lo = cell_of_clamped([q[0] - r, q[1] - r, q[2] - r], self.lo, self.inv_cell, self.blocks);
        let hi = cell_of_clamped([q[0] + r, q[1] + r, q[2] + r], self.lo, self.inv_cell, self.blocks);
        (lo, hi)
    }

    /// Lower bound of the squared distance from `q` to any point outside the blocks `[vlo, vhi]`:
    /// such a point lies in the point bounds beyond one face of that box.
    fn unseen_bound2(&self, q: [f32; 3], vlo: [usize; 3], vhi: [usize; 3]) -> f32 {
        let edge = self.cell * BLOCK as f32;
        let mut bound = f32::INFINITY;
        for a in 0..3 {
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

#[inline(always)]
fn dist2(p: [f32; 3], q: [f32; 3]) -> f32 {
    let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
    dx * dx + dy * dy + dz * dz
}

/// Squared distance from `q` to the box `[lo, hi]` (infinite for an empty box, `lo > hi`).
#[inline(always)]
fn box_dist2(q: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let mut d2 = 0.0;
    for a in 0..3 {
        if lo[a] > hi[a] {
            return f32::INFINITY;
        }
        let d = (lo[a] - q[a]).max(q[a] - hi[a]).max(0.0);
        d2 += d * d;
    }
    d2
}

/// Cell of a point inside the bounds (its coordinates are at least `lo`).
#[inline(always)]
fn cell_of(p: [f32; 3], lo: [f32; 3], inv_cell: f32, blocks: [usize; 3]) -> [usize; 3] {
    cell_of_clamped(p, lo, inv_cell, blocks)
}

/// Cell of any point, clamped into the grid. Monotonic in every coordinate.
#[inline(always)]
fn cell_of_clamped(p: [f32; 3], lo: [f32; 3], inv_cell: f32, blocks: [usize; 3]) -> [usize; 3] {
    [0, 1, 2].map(|a| {
        let last = (blocks[a] * BLOCK - 1) as f32;
        let t = ((p[a] - lo[a]) * inv_cell).clamp(0.0, last);
        t as usize
    })
}

#[inline(always)]
fn local_of(c: [usize; 3]) -> usize {
    (c[0] % BLOCK) + BLOCK * ((c[1] % BLOCK) + BLOCK * (c[2] % BLOCK))
}

#[inline(always)]
fn slot_of(c: [usize; 3], blocks: [usize; 3]) -> usize {
    let b = [c[0] / BLOCK, c[1] / BLOCK, c[2] / BLOCK];
    (b[0] + blocks[0] * (b[1] + blocks[1] * b[2])) * BLOCK_CELLS + local_of(c)
}
