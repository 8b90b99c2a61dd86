//! A uniform grid over a point set (body vertices or face centroids), rebuilt every frame without
//! allocation, answering exact nearest-point queries.
//!
//! Layout: cells are numbered x fastest, then y, then z, so that the points of a row of cells
//! along x are one contiguous range after the counting sort; cells are [`X_SPLIT`] times thinner
//! along x (edge [`PointGrid::cell_size`] along y and z, metres), which trims each row to the
//! search ball's chord at no cost in rows. Coordinates are stored one array per axis, padded, and
//! scanned eight points at a time (AVX2 where the kernels' tier allows it, read when the grid is made; a
//! portable twin otherwise), each lane keeping its lexicographically lowest `(squared distance, index)`.
//!
//! A search with a bound (a radius, a hint's distance or a seed's) that spans few rows scans them
//! from the query's row outwards, trimming each row to the chord of the shrinking ball. A larger
//! one visits blocks of [`BLOCK`]³ cells in shells (Chebyshev rings) around the query's block
//! (clamped into the grid), skipping empty blocks and blocks whose box is farther than the best
//! so far, and stops when every point not yet seen lies, by a lower bound, strictly farther than
//! the best found (see [`PointGrid::nearest_one`]), so results are exact, also for queries far
//! outside the grid.
//!
//! The batch queries take eight consecutive queries at a time and, where their balls overlap
//! enough (a garment's neighbouring vertices), scan the rows around all eight once, each row
//! trimmed to the union of their chords, each point against the eight queries in one register
//! (see [`tile`]); the answers are the single searches', bit for bit.
//!
//! Ties: among points at the same squared distance (computed in `f32` as `dx² + dy² + dz²`) the
//! lowest point index wins. Results do not depend on the grid resolution.

use crate::error::{Error, Result};
use crate::exec::par::{split, Disjoint};
use crate::exec::Executor;
use crate::kernels::{Kernels, Tier};
use crate::math::{finite3, sqrt_f32};
use alloc::vec;
use alloc::vec::Vec;
use core::ops::Range;
use core::sync::atomic::{AtomicUsize, Ordering};
#[cfg(test)]
use tile::TileMode;
use tile::{PortableTile, TileBest, TILE};

mod tile;

/// Cells per block edge.
pub const BLOCK: usize = 4;
const BLOCK_CELLS: usize = BLOCK * BLOCK * BLOCK;
const NONE: u32 = u32::MAX;
/// Points compared at once; the sorted arrays carry this many padding entries, so that a scan
/// may read a whole group past the end of its range.
const LANES: usize = 8;
/// A radius search whose ball spans at most this many rows of cells scans them directly,
/// without visiting blocks.
const DIRECT_ROWS: usize = 100;
/// Queries farther than this many cells outside the point bounds start from one point per block.
const FAR_CELLS: f32 = 8.0;
/// Cells along x are this many times thinner than along y and z: a row of cells (along x) is one
/// contiguous range of points whatever its length, so thin x cells trim rows to the ball's chord
/// more tightly at no cost in rows visited.
pub const X_SPLIT: usize = 8;
/// Cells either side of the query's own cell that seed an unbounded nearest search.
const SEED_CELLS: usize = 1;

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
    /// Cell edge along y and z (metres); along x cells are `X_SPLIT` times thinner.
    cell: f32,
    /// Cell edge per axis and its inverse.
    edge: [f32; 3],
    inv_edge: [f32; 3],
    /// Blocks per axis; cells per axis are `BLOCK` times as many.
    blocks: [usize; 3],
    /// Slack added to every pruning bound, so that rounding in cell assignment never prunes a
    /// point that could win.
    pad: f32,
    /// Whether the scans use AVX2 (checked once at creation; never on other architectures).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    avx2: bool,
    /// `cell_start[s]..cell_start[s + 1]` are the sorted points of cell `s` (x fastest, then y,
    /// then z), so that a row of cells is one contiguous range.
    cell_start: Vec<u32>,
    /// Scratch: the cell of every input point.
    point_slot: Vec<u32>,
    /// Scratch: the sorted points as records `x, y, z, index bits`, so that the counting sort
    /// writes one record per point at a random place rather than four values.
    records: Vec<[f32; 4]>,
    /// Sorted point coordinates, one array per axis, `LANES` padding entries after the points
    /// (NaN, so that they never win).
    sorted: [Vec<f32>; 3],
    sorted_index: Vec<u32>,
    /// The points of the last rebuild in input order (to read a hint's position): a sequential
    /// copy is cheaper than recording where each point was sorted to.
    input: Vec<[f32; 3]>,
    /// One point (input index) of every block of `BLOCK`³ cells, `NONE` for an empty block:
    /// empty blocks are skipped, and these points seed queries far outside.
    block_any: Vec<u32>,
    /// Tests force the batch queries to search every tile as one box, or none.
    #[cfg(test)]
    tile_mode: Option<TileMode>,
}

impl PointGrid {
    /// A grid for up to `capacity` points using at most `max_cells` cells (memory: about
    /// `4·max_cells + 48·capacity` bytes).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] when `max_cells` is below one block (`BLOCK³ = 64` cells) or above
    /// `i32::MAX`, or when `capacity` does not fit in `u32`.
    pub fn new(capacity: usize, max_cells: usize) -> Result<PointGrid> {
        if max_cells < BLOCK_CELLS || max_cells > i32::MAX as usize {
            return Err(Error::OutOfRange { what: "grid max_cells", index: max_cells });
        }
        if capacity >= u32::MAX as usize - LANES {
            return Err(Error::OutOfRange { what: "grid capacity", index: capacity });
        }
        let max_blocks = max_cells / BLOCK_CELLS;
        let padded = capacity + LANES;
        Ok(PointGrid {
            capacity,
            max_cells,
            cells_per_point: DEFAULT_CELLS_PER_POINT,
            n_points: 0,
            lo: [0.0; 3],
            hi: [0.0; 3],
            cell: 1.0,
            edge: [1.0; 3],
            inv_edge: [1.0; 3],
            blocks: [1; 3],
            pad: 0.0,
            avx2: has_avx2(),
            cell_start: vec![0; max_blocks * BLOCK_CELLS + 1],
            point_slot: vec![0; capacity],
            records: vec![[0.0; 4]; capacity],
            sorted: [vec![f32::NAN; padded], vec![f32::NAN; padded], vec![f32::NAN; padded]],
            sorted_index: vec![NONE; padded],
            input: vec![[0.0; 3]; capacity],
            block_any: vec![NONE; max_blocks],
            #[cfg(test)]
            tile_mode: None,
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

    /// Whether the scans use AVX2.
    #[cfg(test)]
    pub(super) fn uses_avx2(&self) -> bool {
        self.avx2
    }

    /// Uses the portable scans even where AVX2 exists (to test the two against each other).
    #[cfg(test)]
    pub(super) fn force_portable(&mut self) {
        self.avx2 = false;
    }

    /// Makes the batch queries search every tile as one box, or none (to test the two paths
    /// against each other).
    #[cfg(test)]
    pub(super) fn force_tiles(&mut self, always: bool) {
        self.tile_mode = Some(if always { TileMode::Always } else { TileMode::Never });
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
    /// Cell edge of the last rebuild along y and z, metres (along x it is [`X_SPLIT`] times
    /// shorter).
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
    /// picks the cell size, counting-sorts the points into cells and picks one point per block.
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
        self.input[..n].copy_from_slice(points);
        let (lo, hi, nan) = bounds(points);
        if nan || !finite3(lo) || !finite3(hi) {
            let i = points.iter().position(|p| !finite3(*p)).unwrap_or(0);
            return Err(Error::NonFinite { what: "grid point", index: i });
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

        let n_blocks = self.n_blocks();
        let slots = n_blocks * BLOCK_CELLS;
        let start = &mut self.cell_start[..slots + 1];
        start.fill(0);
        // Counts into start[s], inclusive prefix sums (start[s] = end of slot s), then a reverse
        // scatter that decrements start[s] down to the beginning of s: stable, no extra pass.
        let slots_of = SlotsOf { lo, inv_edge: self.inv_edge, blocks: self.blocks };
        let point_slot = &mut self.point_slot[..n];
        slots_of.write_dispatched(self.avx2, points, point_slot);
        for &slot in point_slot.iter() {
            start[slot as usize] += 1;
        }
        for s in 1..slots {
            start[s] += start[s - 1];
        }
        start[slots] = n as u32;
        for (i, (p, &slot)) in points.iter().zip(point_slot.iter()).enumerate().rev() {
            start[slot as usize] -= 1;
            self.records[start[slot as usize] as usize] = [p[0], p[1], p[2], f32::from_bits(i as u32)];
        }
        let [xs, ys, zs] = &mut self.sorted;
        let sorted = xs.iter_mut().zip(ys.iter_mut()).zip(zs.iter_mut()).zip(self.sorted_index.iter_mut());
        for (r, (((x, y), z), i)) in self.records[..n].iter().zip(sorted) {
            (*x, *y, *z, *i) = (r[0], r[1], r[2], r[3].to_bits());
        }
        // The padding after the points: NaN never wins (and stale points of a larger earlier
        // rebuild must not be read).
        for axis in self.sorted.iter_mut() {
            axis[n..n + LANES].fill(f32::NAN);
        }
        self.sorted_index[n..n + LANES].fill(NONE);
        self.block_points(n_blocks);
        self.n_points = n;
        Ok(())
    }

    /// One point of every block: the first of its first non-empty row of cells (each row is
    /// contiguous), without reading the points.
    fn block_points(&mut self, n_blocks: usize) {
        let dims = self.cells();
        for b in 0..n_blocks {
            let (bx, rest) = (b % self.blocks[0], b / self.blocks[0]);
            let (by, bz) = (rest % self.blocks[1], rest / self.blocks[1]);
            let rows = (bz * BLOCK..(bz + 1) * BLOCK).flat_map(|z| (by * BLOCK..(by + 1) * BLOCK).map(move |y| (y, z)));
            self.block_any[b] = rows
                .map(|(y, z)| bx * BLOCK + dims[0] * (y + dims[1] * z))
                .find(|&row| self.cell_start[row] < self.cell_start[row + BLOCK])
                .map_or(NONE, |row| self.sorted_index[self.cell_start[row] as usize]);
        }
    }

    /// The box of block `b`: its cells, clipped to the point bounds. Cell assignment rounds, so a
    /// point may lie outside by a rounding error; [`padded`](Self::padded) bounds cover that.
    #[inline(always)]
    fn block_box(&self, b: [usize; 3]) -> ([f32; 3], [f32; 3]) {
        let edge = self.edge.map(|e| e * BLOCK as f32);
        let lo = [0, 1, 2].map(|a| fmax(self.lo[a] + b[a] as f32 * edge[a], self.lo[a]));
        let hi = [0, 1, 2].map(|a| fmin(self.lo[a] + (b[a] + 1) as f32 * edge[a], self.hi[a]));
        (lo, hi)
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
            self.edge = [1.0; 3];
            self.inv_edge = [1.0; 3];
            self.blocks = [1; 3];
            return;
        }
        let target = (self.cells_per_point as f64 * n as f64).clamp(1.0, self.max_cells as f64);
        // Flat or thin point sets: treat the thin axes as 1/1000 of the widest for the volume.
        let vol: f64 = ext.iter().map(|&e| e.max(emax * 1e-3) as f64).product();
        let split = X_SPLIT as f64;
        let mut cell = libm::cbrt(split * vol / target).max(emax as f64 * 1e-6);
        loop {
            let per_axis = [split, 1.0, 1.0];
            let blocks = [0, 1, 2].map(|a| ((ext[a] as f64 * per_axis[a] / cell) as usize + 1).div_ceil(BLOCK));
            if blocks[0].saturating_mul(blocks[1]).saturating_mul(blocks[2]) <= max_blocks {
                self.blocks = blocks;
                break;
            }
            cell *= 1.25;
        }
        self.cell = cell as f32;
        self.edge = [(cell / split) as f32, cell as f32, cell as f32];
        self.inv_edge = [(split / cell) as f32, (1.0 / cell) as f32, (1.0 / cell) as f32];
    }

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
    fn within_one<B: Best>(&self, q: [f32; 3], radius: f32, hint: u32) -> Option<Nearest> {
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
    fn nearest_one_with<B: Best>(&self, q: [f32; 3], hint: u32) -> Option<Nearest> {
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
    fn point(&self, i: u32) -> Option<[f32; 3]> {
        self.input[..self.n_points].get(i as usize).copied()
    }

    /// For every query point (metres), the nearest point within `radius`, see
    /// [`nearest_within_one`](Self::nearest_within_one). Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is not as long as `queries`; [`Error::OutOfRange`] for a
    /// negative or non-finite radius; [`Error::NonFinite`] for a NaN/Inf query coordinate (`out`
    /// is then partly written).
    pub fn nearest_within(&self, queries: &[[f32; 3]], radius: f32, out: &mut [Option<Nearest>]) -> Result<()> {
        self.nearest_within_hinted(queries, radius, &[], out)
    }

    /// As [`nearest_within`](Self::nearest_within) with one hint per query (see
    /// [`nearest_within_one_hinted`](Self::nearest_within_one_hinted)), or `hints` empty for none.
    ///
    /// # Errors
    /// As [`nearest_within`](Self::nearest_within); [`Error::SizeMismatch`] for hints neither
    /// empty nor one per query.
    pub fn nearest_within_hinted(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        check_within(queries.len(), hints.len(), out.len(), radius)?;
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU has AVX2 (checked in `new`).
            return unsafe { self.within_batch_avx2(queries, radius, hints, out) };
        }
        self.within_batch::<Lanes, PortableTile>(queries, radius, hints, out)
    }

    /// The batch loop compiled with AVX2, so that the whole search inlines around the scans.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn within_batch_avx2(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        self.within_batch::<x86::Avx2Best, tile::x86::Avx2Tile>(queries, radius, hints, out)
    }

    /// The radius queries tile by tile: each query's start is the single search's (the limit,
    /// or the hint where it is within it); a tile not worth searching as one box is searched
    /// query by query.
    #[inline(always)]
    fn within_batch<B: Best, T: TileBest>(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        let r2 = radius * radius;
        for (t, (qs, os)) in queries.chunks(TILE).zip(out.chunks_mut(TILE)).enumerate() {
            let first = t * TILE;
            if let Some(k) = qs.iter().position(|q| !finite3(*q)) {
                return Err(Error::NonFinite { what: "query point", index: first + k });
            }
            let hint = |k: usize| hints.get(first + k).copied().unwrap_or(NONE);
            let mut start = [(NONE, r2); TILE];
            for (k, (q, s)) in qs.iter().zip(start.iter_mut()).enumerate() {
                if let Some(p) = self.point(hint(k)) {
                    consider(s, dist2(p, *q), hint(k));
                }
            }
            let mut answers = [(NONE, 0.0); TILE];
            if self.search_tile::<T>(qs, &start[..qs.len()], &mut answers[..qs.len()]) {
                for (o, f) in os.iter_mut().zip(answers) {
                    *o = found(f);
                }
            } else {
                for (k, (q, o)) in qs.iter().zip(os.iter_mut()).enumerate() {
                    *o = self.within_one::<B>(*q, radius, hint(k));
                }
            }
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
        self.nearest_hinted(queries, &[], out)
    }

    /// As [`nearest`](Self::nearest) with one hint per query (see
    /// [`nearest_one_hinted`](Self::nearest_one_hinted)), or `hints` empty for none. Last
    /// frame's answers make good hints.
    ///
    /// # Errors
    /// As [`nearest`](Self::nearest); [`Error::SizeMismatch`] for hints neither empty nor one per
    /// query.
    pub fn nearest_hinted(&self, queries: &[[f32; 3]], hints: &[u32], out: &mut [Nearest]) -> Result<()> {
        check_batch(queries.len(), hints.len(), out.len())?;
        if self.n_points == 0 {
            return Err(Error::Empty { what: "point grid" });
        }
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is only set when the CPU has AVX2 (checked in `new`).
            return unsafe { self.nearest_batch_avx2(queries, hints, out) };
        }
        self.nearest_batch::<Lanes, PortableTile>(queries, hints, out)
    }

    /// The batch loop compiled with AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn nearest_batch_avx2(&self, queries: &[[f32; 3]], hints: &[u32], out: &mut [Nearest]) -> Result<()> {
        self.nearest_batch::<x86::Avx2Best, tile::x86::Avx2Tile>(queries, hints, out)
    }

    /// The unbounded queries tile by tile where every query of the tile has a hint (its
    /// distance bounds the search); otherwise, or when the tile is not worth searching as one
    /// box, query by query.
    #[inline(always)]
    fn nearest_batch<B: Best, T: TileBest>(
        &self,
        queries: &[[f32; 3]],
        hints: &[u32],
        out: &mut [Nearest],
    ) -> Result<()> {
        // Non-empty grid and finite query: a search always returns a point.
        let missing = Nearest { index: 0, distance: f32::INFINITY };
        for (t, (qs, os)) in queries.chunks(TILE).zip(out.chunks_mut(TILE)).enumerate() {
            let first = t * TILE;
            if let Some(k) = qs.iter().position(|q| !finite3(*q)) {
                return Err(Error::NonFinite { what: "query point", index: first + k });
            }
            let hint = |k: usize| hints.get(first + k).copied().unwrap_or(NONE);
            let mut start = [(NONE, f32::INFINITY); TILE];
            let mut bounded = true;
            for (k, (q, s)) in qs.iter().zip(start.iter_mut()).enumerate() {
                match self.point(hint(k)).map(|p| dist2(p, *q)) {
                    Some(d2) if d2.is_finite() => *s = (hint(k), d2),
                    _ => bounded = false,
                }
            }
            let mut answers = [(NONE, 0.0); TILE];
            if bounded && self.search_tile::<T>(qs, &start[..qs.len()], &mut answers[..qs.len()]) {
                for (o, f) in os.iter_mut().zip(answers) {
                    *o = found(f).unwrap_or(missing);
                }
            } else {
                for (k, (q, o)) in qs.iter().zip(os.iter_mut()).enumerate() {
                    *o = self.nearest_one_with::<B>(*q, hint(k)).unwrap_or(missing);
                }
            }
        }
        Ok(())
    }

    /// As [`nearest_within_hinted`](Self::nearest_within_hinted), with the queries split into
    /// contiguous chunks run as tasks of `exec` (all its threads search the same grid). Same
    /// results as the serial call for any executor. Allocates nothing.
    ///
    /// # Errors
    /// As [`nearest_within_hinted`](Self::nearest_within_hinted); every query is checked before
    /// any is searched, so on error `out` is untouched.
    pub fn nearest_within_on(
        &self,
        exec: &dyn Executor,
        queries: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<()> {
        check_within(queries.len(), hints.len(), out.len(), radius)?;
        check_queries(queries)?;
        in_chunks(exec, queries.len(), out, |r, o| {
            self.nearest_within_hinted(&queries[r.clone()], radius, hint_range(hints, r), o)
        })
    }

    /// As [`nearest_hinted`](Self::nearest_hinted), with the queries split into contiguous
    /// chunks run as tasks of `exec`. Same results as the serial call for any executor.
    /// Allocates nothing.
    ///
    /// # Errors
    /// As [`nearest_hinted`](Self::nearest_hinted); every query is checked before any is
    /// searched, so on error `out` is untouched.
    pub fn nearest_on(
        &self,
        exec: &dyn Executor,
        queries: &[[f32; 3]],
        hints: &[u32],
        out: &mut [Nearest],
    ) -> Result<()> {
        check_batch(queries.len(), hints.len(), out.len())?;
        if self.n_points == 0 {
            return Err(Error::Empty { what: "point grid" });
        }
        check_queries(queries)?;
        in_chunks(exec, queries.len(), out, |r, o| self.nearest_hinted(&queries[r.clone()], hint_range(hints, r), o))
    }

    /// A squared distance widened by the rounding slack, for pruning comparisons.
    #[inline(always)]
    fn padded(&self, d2: f32) -> f32 {
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
    fn slab(&self, a: usize, c: usize) -> [f32; 2] {
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

/// The bounds of `points` and whether any coordinate is NaN (infinities show in the bounds).
/// Eight points (24 coordinates) at a time in independent lanes, so that the loop vectorizes
/// (the point layout repeats every 24 coordinates).
fn bounds(points: &[[f32; 3]]) -> ([f32; 3], [f32; 3], bool) {
    const W: usize = 24;
    let flat: &[f32] = bytemuck::cast_slice(points);
    let (mut lo, mut hi, mut nan) = ([f32::INFINITY; W], [f32::NEG_INFINITY; W], [false; W]);
    let mut chunks = flat.chunks_exact(W);
    for c in &mut chunks {
        for k in 0..W {
            lo[k] = fmin(lo[k], c[k]);
            hi[k] = fmax(hi[k], c[k]);
            nan[k] |= c[k].is_nan();
        }
    }
    for (k, &x) in chunks.remainder().iter().enumerate() {
        lo[k] = fmin(lo[k], x);
        hi[k] = fmax(hi[k], x);
        nan[k] |= x.is_nan();
    }
    let (mut lo3, mut hi3) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for k in 0..W {
        lo3[k % 3] = fmin(lo3[k % 3], lo[k]);
        hi3[k % 3] = fmax(hi3[k % 3], hi[k]);
    }
    (lo3, hi3, nan.iter().any(|&b| b))
}

/// `min` as one `minss` (no NaN care: inputs are finite where it matters).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `max` as one `maxss`.
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Distance from the coordinate `t` to the slab `[lo, hi]` (0 inside).
#[inline(always)]
fn slab_gap(t: f32, [lo, hi]: [f32; 2]) -> f32 {
    fmax(fmax(lo - t, t - hi), 0.0)
}

/// The cell coordinate `t` clamped to `[0, last]` (NaN gives `last`), truncated.
#[inline(always)]
fn cell_index(t: f32, last: f32) -> usize {
    fmax(fmin(t, last), 0.0) as usize
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

pub(super) fn check_batch(queries: usize, hints: usize, out: usize) -> Result<()> {
    if out != queries {
        return Err(Error::SizeMismatch { what: "query output", expected: queries, got: out });
    }
    if hints != 0 && hints != queries {
        return Err(Error::SizeMismatch { what: "query hints", expected: queries, got: hints });
    }
    Ok(())
}

/// [`check_batch`] and a finite, non-negative radius.
pub(super) fn check_within(queries: usize, hints: usize, out: usize, radius: f32) -> Result<()> {
    check_batch(queries, hints, out)?;
    if !(radius >= 0.0 && radius.is_finite()) {
        return Err(Error::OutOfRange { what: "query radius", index: 0 });
    }
    Ok(())
}

/// The first query with a NaN/Inf coordinate, as an error.
pub(super) fn check_queries(queries: &[[f32; 3]]) -> Result<()> {
    match queries.iter().position(|q| !finite3(*q)) {
        Some(i) => Err(Error::NonFinite { what: "query point", index: i }),
        None => Ok(()),
    }
}

/// The hints of the queries `r` (empty when there are none).
pub(super) fn hint_range(hints: &[u32], r: Range<usize>) -> &[u32] {
    hints.get(r).unwrap_or(&[])
}

/// Queries per task below which splitting costs more than it saves (a search takes 0.1-0.5 µs,
/// handing out a task about 1 µs).
const MIN_CHUNK: usize = 256;

/// How many chunks `n` queries are split into on `threads` threads: eight per thread, since
/// queries differ in cost (on the body-query bench at 2 threads, eight rather than four per thread
/// took the runtime's query from 0.52 to 0.44 ms and the whole query in one job from 1.14 to
/// 1.06 ms; sixteen gained nothing), but none below [`MIN_CHUNK`] queries (1 on one thread).
pub(super) fn chunks_for(threads: usize, n: usize) -> usize {
    if threads <= 1 {
        1
    } else {
        (8 * threads).min(n / MIN_CHUNK).max(1)
    }
}

/// Runs `f(range, out[range])` over contiguous chunks of `0..n` as tasks of `exec`: a few
/// chunks per thread, since queries differ in cost. Returns the first error of a chunk.
fn in_chunks<T: Send>(
    exec: &dyn Executor,
    n: usize,
    out: &mut [T],
    f: impl Fn(Range<usize>, &mut [T]) -> Result<()> + Sync,
) -> Result<()> {
    let tasks = chunks_for(exec.parallelism(), n);
    if tasks == 1 {
        return f(0..n, out);
    }
    let out = Disjoint::new(out);
    // The lowest failing chunk, `usize::MAX` for none (the callers validate their input first,
    // so this only guards against a broken invariant).
    let failed = AtomicUsize::new(usize::MAX);
    exec.run(tasks, &|t| {
        let r = split(n, tasks, t);
        // SAFETY: the chunks of `split` are disjoint.
        let o = unsafe { out.range(r.clone()) };
        if f(r, o).is_err() {
            failed.fetch_min(t, Ordering::Relaxed);
        }
    });
    match failed.load(Ordering::Relaxed) {
        usize::MAX => Ok(()),
        t => {
            let r = split(n, tasks, t);
            // Rerun the failing chunk on its own to return its error.
            // SAFETY: no task is running any more.
            f(r.clone(), unsafe { out.range(r) })
        }
    }
}

/// A search result as a [`Nearest`].
#[inline(always)]
fn found((i, d2): (u32, f32)) -> Option<Nearest> {
    (i != NONE).then(|| Nearest { index: i, distance: sqrt_f32(d2) })
}

/// Takes `(i, d2)` if it is nearer, or as near with a lower index.
#[inline(always)]
fn consider(best: &mut (u32, f32), d2: f32, i: u32) {
    if d2 <= best.1 && (d2 < best.1 || i < best.0) {
        *best = (i, d2);
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
        let d = fmax(fmax(lo[a] - q[a], q[a] - hi[a]), 0.0);
        d2 += d * d;
    }
    d2
}

/// Cell of a point, clamped into the grid, one point at a time: the scalar reference that tests
/// compare the rebuild's slot pass ([`SlotsOf::write`]) with.
#[cfg(test)]
#[inline(always)]
pub(super) fn cell_of(p: [f32; 3], lo: [f32; 3], inv_edge: [f32; 3], blocks: [usize; 3]) -> [usize; 3] {
    // The slot pass's conversion: a truncation of a clamped value.
    #[inline(always)]
    fn axis(p: f32, lo: f32, inv_edge: f32, blocks: usize) -> usize {
        let c = fmax(fmin((p - lo) * inv_edge, (blocks * BLOCK - 1) as f32), 0.0);
        // SAFETY: `c` is finite (NaN and infinities are clamped) and within `[0, cells - 1]`,
        // which fits in `u32` (the cell count is bounded by `max_cells <= i32::MAX`).
        unsafe { c.to_int_unchecked::<u32>() as usize }
    }
    [
        axis(p[0], lo[0], inv_edge[0], blocks[0]),
        axis(p[1], lo[1], inv_edge[1], blocks[1]),
        axis(p[2], lo[2], inv_edge[2], blocks[2]),
    ]
}

/// The rebuild's cell numbering: the slot `cx + nx·(cy + ny·cz)` of every point, as
/// the scalar `cell_of` of the tests assigns cells.
pub(super) struct SlotsOf {
    pub(super) lo: [f32; 3],
    pub(super) inv_edge: [f32; 3],
    pub(super) blocks: [usize; 3],
}

impl SlotsOf {
    /// Writes the slot of every point into `out` (as long as `points`).
    ///
    /// Eight points (24 coordinates) at a time in independent lanes, each lane with its axis's
    /// constants, so that the loop vectorizes; the same clamp and truncation as the tests' scalar
    /// `cell_of`, so the same slots. The last partial group goes through the same lanes, padded.
    #[inline(always)]
    pub(super) fn write(&self, points: &[[f32; 3]], out: &mut [u32]) {
        const W: usize = 24;
        debug_assert_eq!(points.len(), out.len());
        let dims = self.blocks.map(|b| b * BLOCK);
        let stride = [1, dims[0], dims[0] * dims[1]].map(|s| s as u32);
        let lane = |v: [f32; 3]| -> [f32; W] { core::array::from_fn(|k| v[k % 3]) };
        let (lo, inv) = (lane(self.lo), lane(self.inv_edge));
        let last = lane(dims.map(|d| (d - 1) as f32));
        let stride: [u32; W] = core::array::from_fn(|k| stride[k % 3]);
        let group = |c: &[f32], o: &mut [u32]| {
            let mut part = [0u32; W];
            for k in 0..W {
                let t = fmax(fmin((c[k] - lo[k]) * inv[k], last[k]), 0.0);
                // SAFETY: `t` is finite (NaN and infinities are clamped) and within
                // `[0, cells - 1]`, which fits in `i32` (`max_cells <= i32::MAX`); so does the
                // slot, the sum of the three products.
                part[k] = unsafe { t.to_int_unchecked::<i32>() } as u32 * stride[k];
            }
            for (j, o) in o.iter_mut().enumerate() {
                *o = part[3 * j] + part[3 * j + 1] + part[3 * j + 2];
            }
        };
        let flat: &[f32] = bytemuck::cast_slice(points);
        let mut chunks = flat.chunks_exact(W);
        let mut outs = out.chunks_exact_mut(W / 3);
        for (c, o) in (&mut chunks).zip(&mut outs) {
            group(c, o);
        }
        let rest = chunks.remainder();
        if !rest.is_empty() {
            let mut padded = lo;
            padded[..rest.len()].copy_from_slice(rest);
            group(&padded, outs.into_remainder());
        }
    }

    /// [`write`](Self::write) with AVX2 where `avx2` says the CPU has it.
    #[inline(always)]
    fn write_dispatched(&self, avx2: bool, points: &[[f32; 3]], out: &mut [u32]) {
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: callers pass `avx2` only when the CPU has AVX2 (the grid checks in `new`).
            return unsafe { self.write_avx2(points, out) };
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = avx2;
        self.write(points, out)
    }

    /// [`write`](Self::write) compiled with AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) fn write_avx2(&self, points: &[[f32; 3]], out: &mut [u32]) {
        self.write(points, out)
    }
}

/// Cell of any point, clamped into the grid. Monotonic in every coordinate.
#[inline(always)]
fn cell_of_clamped(p: [f32; 3], lo: [f32; 3], inv_edge: [f32; 3], blocks: [usize; 3]) -> [usize; 3] {
    #[inline(always)]
    fn axis(p: f32, lo: f32, inv_cell: f32, blocks: usize) -> usize {
        let last = (blocks * BLOCK - 1) as f32;
        cell_index((p - lo) * inv_cell, last)
    }
    [
        axis(p[0], lo[0], inv_edge[0], blocks[0]),
        axis(p[1], lo[1], inv_edge[1], blocks[1]),
        axis(p[2], lo[2], inv_edge[2], blocks[2]),
    ]
}

/// Eight candidate `(squared distance, index)` pairs, one per lane, each the lexicographic
/// minimum of the points offered to its lane; the answer is the minimum over the lanes. A lane
/// starts at `(limit², NONE)`, so that a point exactly at the limit is taken (inclusive).
#[derive(Clone, Copy)]
struct Lanes {
    d2: [f32; LANES],
    index: [u32; LANES],
}

/// The running answer of one search: candidates `(squared distance, index)` whose lexicographic
/// minimum is the answer, starting at `(limit², NONE)` (a point exactly at the limit is taken).
/// Two implementations, [`Lanes`] (portable) and `x86::Avx2Best`, give identical answers.
trait Best {
    fn new(limit2: f32) -> Self;
    /// Offers one point.
    fn offer(&mut self, d2: f32, i: u32);
    /// Offers every point of `pts` (a multiple of `LANES` long); returns the new bound.
    fn scan(&mut self, pts: ScanPoints<'_>, q: [f32; 3]) -> f32;
    /// As [`scan`](Self::scan), faster when few points beat the bound (a tight bound); `bound` is
    /// the current [`bound`](Self::bound), which the caller already holds.
    fn scan_tight(&mut self, pts: ScanPoints<'_>, q: [f32; 3], _bound: f32) -> f32 {
        self.scan(pts, q)
    }
    /// The smallest squared distance held: no farther point can win.
    fn bound(&self) -> f32;
    /// The winner `(index, squared distance)`: lowest distance, then lowest index.
    fn best(&self) -> (u32, f32);
}

impl Best for Lanes {
    #[inline(always)]
    fn new(limit2: f32) -> Lanes {
        Lanes { d2: [limit2; LANES], index: [NONE; LANES] }
    }
    #[inline(always)]
    fn offer(&mut self, d2: f32, i: u32) {
        self.take(0, d2, i);
    }
    #[inline(always)]
    fn scan(&mut self, pts: ScanPoints<'_>, q: [f32; 3]) -> f32 {
        scan_portable(pts, q, self)
    }
    #[inline(always)]
    fn bound(&self) -> f32 {
        self.d2.iter().fold(f32::INFINITY, |m, &d| fmin(m, d))
    }
    #[inline(always)]
    fn best(&self) -> (u32, f32) {
        lexicographic_min(&self.d2, &self.index)
    }
}

/// The lowest `(d2, index)` over eight lanes.
#[inline(always)]
fn lexicographic_min(d2: &[f32; LANES], index: &[u32; LANES]) -> (u32, f32) {
    let mut best = (index[0], d2[0]);
    for l in 1..LANES {
        if d2[l] < best.1 || (d2[l] == best.1 && index[l] < best.0) {
            best = (index[l], d2[l]);
        }
    }
    best
}

impl Lanes {
    /// Offers one point to lane `l`.
    #[inline(always)]
    fn take(&mut self, l: usize, d2: f32, i: u32) {
        if d2 < self.d2[l] || (d2 == self.d2[l] && i < self.index[l]) {
            self.d2[l] = d2;
            self.index[l] = i;
        }
    }
}

/// Sorted coordinates `x, y, z` and point indices of one scan, a multiple of `LANES` long.
type ScanPoints<'a> = (&'a [f32], &'a [f32], &'a [f32], &'a [u32]);

/// The portable twin of the AVX2 scan (`x86::Avx2Best`): the same lane updates, one lane at a
/// time.
#[inline(always)]
fn scan_portable((xs, ys, zs, idx): ScanPoints<'_>, q: [f32; 3], lanes: &mut Lanes) -> f32 {
    let groups = xs.chunks_exact(LANES).zip(ys.chunks_exact(LANES)).zip(zs.chunks_exact(LANES));
    for (((x, y), z), i) in groups.zip(idx.chunks_exact(LANES)) {
        for l in 0..LANES {
            lanes.take(l, dist2([x[l], y[l], z[l]], q), i[l]);
        }
    }
    lanes.bound()
}

/// Whether the scans may use AVX2: when the kernels' tier ([`Kernels::best`], probed once and
/// capped by `HOOD_KERNEL_TIER` / [`force_tier`](crate::kernels::force_tier)) is AVX2 or above,
/// so one setting picks the SIMD paths of the whole library.
pub(super) fn has_avx2() -> bool {
    Kernels::best().tier() >= Tier::Avx2Fma
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Best, ScanPoints, LANES, NONE};
    use core::arch::x86_64::*;

    /// [`super::Lanes`] in two AVX2 registers. Only made inside functions compiled with AVX2
    /// (the `*_avx2` entry points of the grid, reached only when the CPU has it), into which all
    /// of its methods inline.
    #[derive(Clone, Copy)]
    pub(super) struct Avx2Best {
        d2: __m256,
        index: __m256i,
    }

    impl Best for Avx2Best {
        #[inline(always)]
        fn new(limit2: f32) -> Avx2Best {
            // SAFETY (every `unsafe` of this impl): AVX2 instructions, executed only on a CPU
            // that has them (see the type's comment); loads and stores as commented.
            unsafe { Avx2Best { d2: _mm256_set1_ps(limit2), index: _mm256_set1_epi32(NONE as i32) } }
        }

        #[inline(always)]
        fn offer(&mut self, d2: f32, i: u32) {
            // Every lane takes the point if it is better: the minimum over lanes is the same.
            unsafe {
                (self.d2, self.index) = merge(self.d2, self.index, _mm256_set1_ps(d2), _mm256_set1_epi32(i as i32));
            }
        }

        /// [`super::scan_portable`] eight points at a time. Distances are `(dx² + dy²) + dz²` in
        /// that order, without FMA, so they equal the scalar ones bit for bit.
        #[inline(always)]
        fn scan(&mut self, (xs, ys, zs, idx): ScanPoints<'_>, q: [f32; 3]) -> f32 {
            let n = xs.len().min(ys.len()).min(zs.len()).min(idx.len()) / LANES * LANES;
            // Loads read `k..k + 8` with `k + 8 <= n`, inside all four slices.
            unsafe {
                let (qx, qy, qz) = (_mm256_set1_ps(q[0]), _mm256_set1_ps(q[1]), _mm256_set1_ps(q[2]));
                // A macro rather than a closure: closures do not inline into the AVX2 callers.
                macro_rules! group {
                    ($k:expr) => {{
                        let k = $k;
                        let dx = _mm256_sub_ps(_mm256_loadu_ps(xs.as_ptr().add(k)), qx);
                        let dy = _mm256_sub_ps(_mm256_loadu_ps(ys.as_ptr().add(k)), qy);
                        let dz = _mm256_sub_ps(_mm256_loadu_ps(zs.as_ptr().add(k)), qz);
                        let d = _mm256_add_ps(
                            _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                            _mm256_mul_ps(dz, dz),
                        );
                        (d, _mm256_loadu_si256(idx.as_ptr().add(k).cast()))
                    }};
                }
                let (mut bd, mut bi) = (self.d2, self.index);
                // Two accumulators, so that consecutive groups do not wait on each other's blends.
                let (mut bd1, mut bi1) = (bd, bi);
                let mut k = 0;
                while k + 2 * LANES <= n {
                    let (d, i) = group!(k);
                    (bd, bi) = merge(bd, bi, d, i);
                    let (d, i) = group!(k + LANES);
                    (bd1, bi1) = merge(bd1, bi1, d, i);
                    k += 2 * LANES;
                }
                if k < n {
                    let (d, i) = group!(k);
                    (bd, bi) = merge(bd, bi, d, i);
                }
                (self.d2, self.index) = merge(bd, bi, bd1, bi1);
            }
            self.bound()
        }

        /// Groups with no point within the bound cost one compare; only the others are merged
        /// into the lanes (a point beyond the lowest lane can never be the answer).
        #[inline(always)]
        fn scan_tight(&mut self, (xs, ys, zs, idx): ScanPoints<'_>, q: [f32; 3], bound: f32) -> f32 {
            let n = xs.len().min(ys.len()).min(zs.len()).min(idx.len()) / LANES * LANES;
            // Loads read `k..k + 8` with `k + 8 <= n`, inside all four slices.
            unsafe {
                let (qx, qy, qz) = (_mm256_set1_ps(q[0]), _mm256_set1_ps(q[1]), _mm256_set1_ps(q[2]));
                // The caller's copy of the bound: no horizontal minimum before the first group.
                let mut bound = _mm256_set1_ps(bound);
                let mut k = 0;
                while k < n {
                    let dx = _mm256_sub_ps(_mm256_loadu_ps(xs.as_ptr().add(k)), qx);
                    let dy = _mm256_sub_ps(_mm256_loadu_ps(ys.as_ptr().add(k)), qy);
                    let dz = _mm256_sub_ps(_mm256_loadu_ps(zs.as_ptr().add(k)), qz);
                    let d = _mm256_add_ps(
                        _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                        _mm256_mul_ps(dz, dz),
                    );
                    if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(d, bound)) != 0 {
                        let i = _mm256_loadu_si256(idx.as_ptr().add(k).cast());
                        (self.d2, self.index) = merge(self.d2, self.index, d, i);
                        bound = _mm256_set1_ps(self.bound());
                    }
                    k += LANES;
                }
                _mm256_cvtss_f32(bound)
            }
        }

        #[inline(always)]
        fn bound(&self) -> f32 {
            unsafe {
                let d = self.d2;
                let m = _mm_min_ps(_mm256_castps256_ps128(d), _mm256_extractf128_ps::<1>(d));
                let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
                _mm_cvtss_f32(_mm_min_ss(m, _mm_shuffle_ps::<1>(m, m)))
            }
        }

        /// Merges the lanes with themselves permuted (halves, pairs, neighbours swapped): every
        /// lane then holds the minimum, without branches.
        #[inline(always)]
        fn best(&self) -> (u32, f32) {
            unsafe {
                let (mut d, mut i) = (self.d2, self.index);
                (d, i) = merge(d, i, _mm256_permute2f128_ps::<0x01>(d, d), _mm256_permute2f128_si256::<0x01>(i, i));
                (d, i) = merge(d, i, _mm256_permute_ps::<0x4E>(d), _mm256_shuffle_epi32::<0x4E>(i));
                (d, i) = merge(d, i, _mm256_permute_ps::<0xB1>(d), _mm256_shuffle_epi32::<0xB1>(i));
                (_mm256_extract_epi32::<0>(i) as u32, _mm256_cvtss_f32(d))
            }
        }
    }

    /// Lane-wise lexicographic minimum of `(bd, bi)` and `(d, i)`.
    #[inline(always)]
    pub(super) unsafe fn merge(bd: __m256, bi: __m256i, d: __m256, i: __m256i) -> (__m256, __m256i) {
        // SAFETY: AVX2 instructions, only reached on a CPU that has them.
        unsafe {
            let sign = _mm256_set1_epi32(i32::MIN);
            let lt = _mm256_cmp_ps::<_CMP_LT_OQ>(d, bd);
            let eq = _mm256_cmp_ps::<_CMP_EQ_OQ>(d, bd);
            // Unsigned `i < bi` as a signed compare of sign-flipped values.
            let lower = _mm256_cmpgt_epi32(_mm256_xor_si256(bi, sign), _mm256_xor_si256(i, sign));
            let take = _mm256_or_ps(lt, _mm256_and_ps(eq, _mm256_castsi256_ps(lower)));
            let bd = _mm256_blendv_ps(bd, d, take);
            let bi = _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(bi), _mm256_castsi256_ps(i), take));
            (bd, bi)
        }
    }
}
