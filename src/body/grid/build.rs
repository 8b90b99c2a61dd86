//! Rebuilding the grid around a frame's points: their bounds, the counting sort of the points
//! into cells (the slot of every point) and one point per block.

use super::{fmax, fmin, PointGrid, BLOCK, BLOCK_CELLS, LANES, NONE};
use crate::error::{Error, Result};
use crate::math::finite3;

impl PointGrid {
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

/// Cell of a point, clamped into the grid, one point at a time: the scalar reference that tests
/// compare the rebuild's slot pass ([`SlotsOf::write`]) with.
#[cfg(test)]
#[inline(always)]
pub(in crate::body) fn cell_of(p: [f32; 3], lo: [f32; 3], inv_edge: [f32; 3], blocks: [usize; 3]) -> [usize; 3] {
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
pub(in crate::body) struct SlotsOf {
    pub(in crate::body) lo: [f32; 3],
    pub(in crate::body) inv_edge: [f32; 3],
    pub(in crate::body) blocks: [usize; 3],
}

impl SlotsOf {
    /// Writes the slot of every point into `out` (as long as `points`).
    ///
    /// Eight points (24 coordinates) at a time in independent lanes, each lane with its axis's
    /// constants, so that the loop vectorizes; the same clamp and truncation as the tests' scalar
    /// `cell_of`, so the same slots. The last partial group goes through the same lanes, padded.
    #[inline(always)]
    pub(in crate::body) fn write(&self, points: &[[f32; 3]], out: &mut [u32]) {
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
    pub(in crate::body) fn write_avx2(&self, points: &[[f32; 3]], out: &mut [u32]) {
        self.write(points, out)
    }
}
