//! Tiles: eight neighbouring queries searched together.
//!
//! A search of one query pays for its rows of cells (bounds, chords, loop set-up) about as much
//! as for the points it scans. Consecutive queries of a garment lie close together, so their balls
//! overlap: a tile scans the points of the box around all eight balls once, each point against
//! the eight queries in the lanes of one register. That is worth it while the box holds few
//! points per query; a tile whose queries are spread out (the box's rows or points exceed
//! [`TILE_MAX_ROWS`] or [`TILE_POINTS_PER_QUERY`] per query) is searched one query at a time.
//!
//! Exactness: each lane starts from its query's own `(index, squared distance)` bound, as the
//! single search does, and is offered every point of a box that holds the query's (padded) ball,
//! each through the same lexicographic minimum with the same arithmetic. The answer is therefore
//! the single search's, bit for bit, whether a tile is taken or not.

use super::{cell_of_clamped, fmax, fmin, sqrt, PointGrid, LANES, NONE};
use crate::math::finite3;

/// Queries per tile: one per lane.
pub(super) const TILE: usize = LANES;
/// A tile is searched as one box only while the box's rows of cells are at most this many ...
const TILE_MAX_ROWS: usize = 48;
/// ... and its points at most this many per query of the tile. A point costs a tile about
/// 2 ns and a single search about 200 ns (13k-vertex body, radius 3 cm, Zen 4); on a garment's
/// queries in mesh order the body-edge query measured fastest between 80 and 160.
const TILE_POINTS_PER_QUERY: u32 = 128;

/// A path forced by tests, to compare the two.
#[cfg(test)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum TileMode {
    /// Every tile as one box.
    Always,
    /// Every query on its own.
    Never,
}

/// The running answers of up to [`TILE`] queries: per lane, the lexicographic minimum
/// `(squared distance, index)` of its start and the points offered. Two implementations,
/// [`PortableTile`] and `x86::Avx2Tile`, give identical answers.
pub(super) trait TileBest {
    /// Lanes for `queries` (at most [`TILE`]) starting from `start[l] = (index, squared
    /// distance)`; unused lanes never take a point.
    fn new(queries: &[[f32; 3]], start: &[(u32, f32)]) -> Self;
    /// Offers the points `k0..k1` of the sorted arrays to every lane.
    fn scan(&mut self, sorted: (&[f32], &[f32], &[f32], &[u32]), k0: usize, k1: usize);
    /// The answers `(index, squared distance)` of the first `out.len()` lanes.
    fn answers(&self, out: &mut [(u32, f32)]);
}

/// The portable twin of `x86::Avx2Tile`: the same updates, one lane at a time.
pub(super) struct PortableTile {
    q: [[f32; 3]; TILE],
    d2: [f32; TILE],
    index: [u32; TILE],
}

impl TileBest for PortableTile {
    #[inline(always)]
    fn new(queries: &[[f32; 3]], start: &[(u32, f32)]) -> PortableTile {
        let mut t = PortableTile { q: [[f32::NAN; 3]; TILE], d2: [f32::NAN; TILE], index: [NONE; TILE] };
        for (l, (q, s)) in queries.iter().zip(start).enumerate().take(TILE) {
            t.q[l] = *q;
            (t.index[l], t.d2[l]) = *s;
        }
        t
    }

    #[inline(always)]
    fn scan(&mut self, (xs, ys, zs, idx): (&[f32], &[f32], &[f32], &[u32]), k0: usize, k1: usize) {
        for k in k0..k1 {
            let (p, i) = ([xs[k], ys[k], zs[k]], idx[k]);
            for l in 0..TILE {
                let q = self.q[l];
                // The same arithmetic as the single scans: `(dx² + dy²) + dz²`, `p - q`.
                let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
                let d2 = dx * dx + dy * dy + dz * dz;
                if d2 < self.d2[l] || (d2 == self.d2[l] && i < self.index[l]) {
                    self.d2[l] = d2;
                    self.index[l] = i;
                }
            }
        }
    }

    #[inline(always)]
    fn answers(&self, out: &mut [(u32, f32)]) {
        for (l, o) in out.iter_mut().enumerate().take(TILE) {
            *o = (self.index[l], self.d2[l]);
        }
    }
}

impl PointGrid {
    /// Searches `queries` (at most [`TILE`], finite) together, query `l` from `start[l]` (its
    /// guess and bound, as for a single search), writing `(index, squared distance)` into `out`.
    /// Returns false, writing nothing, when the tile is cheaper searched one query at a time.
    #[inline(always)]
    pub(super) fn search_tile<T: TileBest>(
        &self,
        queries: &[[f32; 3]],
        start: &[(u32, f32)],
        out: &mut [(u32, f32)],
    ) -> bool {
        #[cfg(test)]
        if self.tile_mode == Some(TileMode::Never) {
            return false;
        }
        if self.n_points == 0 {
            return false;
        }
        // The box around every query's padded ball.
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for (q, s) in queries.iter().zip(start) {
            let r = sqrt(self.padded(s.1));
            for a in 0..3 {
                lo[a] = fmin(lo[a], q[a] - r);
                hi[a] = fmax(hi[a], q[a] + r);
            }
        }
        if !finite3(lo) || !finite3(hi) {
            return false;
        }
        let clo = cell_of_clamped(lo, self.lo, self.inv_edge, self.blocks);
        let chi = cell_of_clamped(hi, self.lo, self.inv_edge, self.blocks);
        let rows = (chi[1] - clo[1] + 1) * (chi[2] - clo[2] + 1);
        let dims = self.cells();
        let row_range = |y: usize, z: usize| {
            let row = dims[0] * (y + dims[1] * z);
            (self.cell_start[row + clo[0]] as usize, self.cell_start[row + chi[0] + 1] as usize)
        };
        #[cfg(test)]
        let forced = self.tile_mode == Some(TileMode::Always);
        #[cfg(not(test))]
        let forced = false;
        if !forced {
            if rows > TILE_MAX_ROWS {
                return false;
            }
            let mut points = 0u32;
            for z in clo[2]..=chi[2] {
                for y in clo[1]..=chi[1] {
                    let (p0, p1) = row_range(y, z);
                    points += (p1 - p0) as u32;
                }
            }
            if points > TILE_POINTS_PER_QUERY * queries.len() as u32 {
                return false;
            }
        }
        let mut tile = T::new(queries, start);
        let [xs, ys, zs] = &self.sorted;
        let sorted = (&xs[..], &ys[..], &zs[..], &self.sorted_index[..]);
        for z in clo[2]..=chi[2] {
            for y in clo[1]..=chi[1] {
                let (p0, p1) = row_range(y, z);
                tile.scan(sorted, p0, p1);
            }
        }
        tile.answers(out);
        true
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod x86 {
    use super::super::x86::merge;
    use super::{TileBest, NONE, TILE};
    use core::arch::x86_64::*;

    /// [`super::PortableTile`] in AVX2 registers: the queries' coordinates and running answers,
    /// lane by lane. Only made inside functions compiled with AVX2, reached only when the CPU
    /// has it.
    pub(in super::super) struct Avx2Tile {
        q: [__m256; 3],
        d2: __m256,
        index: __m256i,
    }

    impl TileBest for Avx2Tile {
        #[inline(always)]
        fn new(queries: &[[f32; 3]], start: &[(u32, f32)]) -> Avx2Tile {
            let (mut q, mut d2, mut index) = ([[f32::NAN; TILE]; 3], [f32::NAN; TILE], [NONE; TILE]);
            for (l, (p, s)) in queries.iter().zip(start).enumerate().take(TILE) {
                for a in 0..3 {
                    q[a][l] = p[a];
                }
                (index[l], d2[l]) = *s;
            }
            // SAFETY: AVX2 loads of local arrays of eight, on a CPU that has AVX2.
            unsafe {
                let d = _mm256_loadu_ps(d2.as_ptr());
                let i = _mm256_loadu_si256(index.as_ptr().cast());
                Avx2Tile { q: q.map(|c| _mm256_loadu_ps(c.as_ptr())), d2: d, index: i }
            }
        }

        /// Distances are `(dx² + dy²) + dz²` without FMA, as in the portable twin.
        #[inline(always)]
        fn scan(&mut self, (xs, ys, zs, idx): (&[f32], &[f32], &[f32], &[u32]), k0: usize, k1: usize) {
            let k1 = k1.min(xs.len()).min(ys.len()).min(zs.len()).min(idx.len());
            // SAFETY: AVX2 on a CPU that has it; every load reads index `k < k1`, inside all four
            // slices.
            unsafe {
                let [qx, qy, qz] = self.q;
                let (mut bd, mut bi) = (self.d2, self.index);
                for k in k0..k1 {
                    let dx = _mm256_sub_ps(_mm256_broadcast_ss(&*xs.as_ptr().add(k)), qx);
                    let dy = _mm256_sub_ps(_mm256_broadcast_ss(&*ys.as_ptr().add(k)), qy);
                    let dz = _mm256_sub_ps(_mm256_broadcast_ss(&*zs.as_ptr().add(k)), qz);
                    let d = _mm256_add_ps(
                        _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                        _mm256_mul_ps(dz, dz),
                    );
                    // Most points improve no lane: one compare, no blend.
                    if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(d, bd)) != 0 {
                        let i = _mm256_set1_epi32(*idx.as_ptr().add(k) as i32);
                        (bd, bi) = merge(bd, bi, d, i);
                    }
                }
                (self.d2, self.index) = (bd, bi);
            }
        }

        #[inline(always)]
        fn answers(&self, out: &mut [(u32, f32)]) {
            let (mut d2, mut index) = ([0.0f32; TILE], [0u32; TILE]);
            // SAFETY: AVX2 on a CPU that has it; stores into local arrays of eight.
            unsafe {
                _mm256_storeu_ps(d2.as_mut_ptr(), self.d2);
                _mm256_storeu_si256(index.as_mut_ptr().cast(), self.index);
            }
            for (l, o) in out.iter_mut().enumerate().take(TILE) {
                *o = (index[l], d2[l]);
            }
        }
    }
}
