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
//!
//! The code: `build` (rebuild and binning), `query` (single-point queries and the search),
//! `batch` (batched and executor-parallel queries), `tile` (eight queries at once) and `scan`
//! (the eight-lane scans, portable and AVX2).

use crate::error::{Error, Result};
use alloc::vec;
use alloc::vec::Vec;
pub(super) use batch::{check_batch, check_queries, check_within, chunks_for, hint_range};
#[cfg(test)]
pub(super) use build::{cell_of, SlotsOf};
pub(super) use scan::has_avx2;
#[cfg(test)]
use tile::TileMode;

mod batch;
mod build;
mod query;
mod scan;
mod tile;

/// Cells per block edge.
pub(crate) const BLOCK: usize = 4;
const BLOCK_CELLS: usize = BLOCK * BLOCK * BLOCK;
const NONE: u32 = u32::MAX;
/// Points compared at once; the sorted arrays carry this many padding entries, so that a scan
/// may read a whole group past the end of its range.
const LANES: usize = 8;
/// Cells along x are this many times thinner than along y and z: a row of cells (along x) is one
/// contiguous range of points whatever its length, so thin x cells trim rows to the ball's chord
/// more tightly at no cost in rows visited.
pub(crate) const X_SPLIT: usize = 8;

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
    /// Cell edge of the last rebuild along y and z, metres (along x it is 8 times shorter).
    pub fn cell_size(&self) -> f32 {
        self.cell
    }
    /// Cells per axis of the last rebuild (multiples of 4, the blocks the search visits).
    pub fn cells(&self) -> [usize; 3] {
        self.blocks.map(|b| b * BLOCK)
    }
    /// Tight bounds `(min, max)` of the points of the last rebuild (metres).
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        (self.lo, self.hi)
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

#[inline(always)]
fn dist2(p: [f32; 3], q: [f32; 3]) -> f32 {
    let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
    dx * dx + dy * dy + dz * dz
}
