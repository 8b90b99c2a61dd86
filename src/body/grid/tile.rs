//! Tiles: eight neighbouring queries searched together.
//!
//! A search of one query pays for its rows of cells (bounds, chords, loop set-up) about as much
//! as for the points it scans. Consecutive queries of a garment lie close together, so their balls
//! overlap: a tile scans the rows of cells around all eight balls once, each row trimmed to the
//! union of the eight chords, each point against the eight queries in the lanes of one register.
//! The chords are sized once, from the start bounds: re-trimming each row with the shrinking
//! bounds puts a chain of square roots between every two rows and measured 6–10 % slower. That is
//! worth it while the rows hold few points per query; a tile whose queries are spread out (the
//! box around the balls spans more than [`TILE_MAX_ROWS`] rows, or the chords hold more than
//! [`TILE_POINTS_PER_QUERY`] points per query) is searched one query at a time.
//!
//! Exactness: each lane starts from its query's own `(index, squared distance)` bound, as the
//! single search does, and is offered every point of its row's chord of the query's padded
//! start ball (which holds every ball the single search prunes with), with the same arithmetic
//! for the chord and the distance, each point through the same lexicographic minimum. The answer is therefore the single search's, bit for bit,
//! whether a tile is taken or not.

use super::{cell_index, cell_of_clamped, fmax, fmin, slab_gap, PointGrid, LANES, NONE};
use crate::math::{finite3, sqrt_f32};

/// Queries per tile: one per lane.
pub(super) const TILE: usize = LANES;
/// A tile is searched as one box only while the box's rows of cells are at most this many ...
const TILE_MAX_ROWS: usize = 48;
/// ... and its rows' chords hold at most this many points per query of the tile, when every
/// query starts from a hint's distance. A point costs a tile about 2 ns and a single search
/// about 200 ns (13k-vertex body, radius 3 cm, Zen 4); on a garment's queries in mesh order the
/// hinted nearest-centroid query measured fastest between 192 and 256 (3 % faster than at 128),
/// the hinted body-edge query flat from 128 to 320.
const TILE_POINTS_PER_QUERY: usize = 192;
/// The same when some query starts from the radius alone: the chords are sized from the start
/// bounds, and a single search's ball shrinks from the radius after its first rows, so tiles
/// pay off less (unhinted body edges: 0.96 ms at 192, 0.91 at 128, 0.89 at 96; the hinted
/// body-edge query, whose far queries have no hint, 1 % slower at 96 and 7 % at 64). Unhinted
/// body edges took 0.86 ms when tiles were chosen and scanned by their whole box: the chords
/// cost more per row than they save on balls that have not shrunk yet (6 % on this first-frame
/// path, against 2–3 % saved on every hinted frame).
const TILE_POINTS_PER_QUERY_UNHINTED: usize = 128;

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
    /// distance)`; unused lanes never take a point. `reach2[l]` is the squared radius of lane
    /// `l`'s chords: its start bound, padded for rounding (`PointGrid::padded`).
    fn new(queries: &[[f32; 3]], start: &[(u32, f32)], reach2: &[f32]) -> Self;
    /// Offers the points `k0..k1` of the sorted arrays to every lane.
    fn scan(&mut self, sorted: (&[f32], &[f32], &[f32], &[u32]), k0: usize, k1: usize);
    /// The x interval (metres) that the lanes' balls of radius `sqrt(reach2)` cover, together,
    /// within the slabs `y` and `z` (`[lo, hi]`, metres); `None` when no ball reaches them. Per
    /// lane the same arithmetic as a single search's chord, from a bound at least as large, so
    /// the interval holds every chord the single search scans.
    fn reach(&self, y: [f32; 2], z: [f32; 2]) -> Option<(f32, f32)>;
    /// The answers `(index, squared distance)` of the first `out.len()` lanes.
    fn answers(&self, out: &mut [(u32, f32)]);
}

/// The portable twin of `x86::Avx2Tile`: the same updates, one lane at a time.
pub(super) struct PortableTile {
    q: [[f32; 3]; TILE],
    d2: [f32; TILE],
    index: [u32; TILE],
    reach2: [f32; TILE],
}

impl TileBest for PortableTile {
    #[inline(always)]
    fn new(queries: &[[f32; 3]], start: &[(u32, f32)], reach2: &[f32]) -> PortableTile {
        let nan = [f32::NAN; TILE];
        let mut t = PortableTile { q: [[f32::NAN; 3]; TILE], d2: nan, index: [NONE; TILE], reach2: nan };
        for (l, ((q, s), r2)) in queries.iter().zip(start).zip(reach2).enumerate().take(TILE) {
            t.q[l] = *q;
            (t.index[l], t.d2[l]) = *s;
            t.reach2[l] = *r2;
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
    fn reach(&self, y: [f32; 2], z: [f32; 2]) -> Option<(f32, f32)> {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for (q, r2) in self.q.iter().zip(self.reach2) {
            // As `PointGrid::scan_ball`; unused lanes are NaN and fail the test.
            let (dz, dy) = (slab_gap(q[2], z), slab_gap(q[1], y));
            let rest = r2 - dz * dz - dy * dy;
            if rest >= 0.0 {
                let r = sqrt_f32(rest);
                lo = fmin(lo, q[0] - r);
                hi = fmax(hi, q[0] + r);
            }
        }
        (lo <= hi).then_some((lo, hi))
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
        let mut reach2 = [f32::NAN; TILE];
        for ((q, s), r2) in queries.iter().zip(start).zip(reach2.iter_mut()) {
            *r2 = self.padded(s.1);
            let r = sqrt_f32(*r2);
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
        let mut tile = T::new(queries, start, &reach2);
        #[cfg(test)]
        let forced = self.tile_mode == Some(TileMode::Always);
        #[cfg(not(test))]
        let forced = false;
        let [xs, ys, zs] = &self.sorted;
        let sorted = (&xs[..], &ys[..], &zs[..], &self.sorted_index[..]);
        // Every row's chord first (from the start bounds: independent of each other, so they
        // overlap in the pipeline), to count the points; then the scans.
        let mut ranges = [(0, 0); TILE_MAX_ROWS];
        let stored = rows <= TILE_MAX_ROWS;
        if !stored && !forced {
            return false;
        }
        let per_query =
            if start.iter().all(|s| s.0 != NONE) { TILE_POINTS_PER_QUERY } else { TILE_POINTS_PER_QUERY_UNHINTED };
        let limit = per_query * queries.len();
        let (mut n, mut points) = (0, 0);
        for z in clo[2]..=chi[2] {
            for y in clo[1]..=chi[1] {
                if let Some((p0, p1)) = self.row_reach(&tile, y, z) {
                    if stored {
                        ranges[n] = (p0, p1);
                        n += 1;
                        points += p1 - p0;
                        if points > limit && !forced {
                            return false;
                        }
                    } else {
                        tile.scan(sorted, p0, p1);
                    }
                }
            }
        }
        for &(p0, p1) in &ranges[..n] {
            tile.scan(sorted, p0, p1);
        }
        tile.answers(out);
        true
    }

    /// The points of the row of cells `(y, z)` within the chords of the tile's current balls.
    /// (A method, not a closure: closures are not inlined into the AVX2 caller.)
    #[inline(always)]
    fn row_reach<T: TileBest>(&self, tile: &T, y: usize, z: usize) -> Option<(usize, usize)> {
        let (xlo, xhi) = tile.reach(self.slab(1, y), self.slab(2, z))?;
        let dims = self.cells();
        let last = (dims[0] - 1) as f32;
        let x0 = cell_index((xlo - self.lo[0]) * self.inv_edge[0], last);
        let x1 = cell_index((xhi - self.lo[0]) * self.inv_edge[0], last);
        let row = dims[0] * (y + dims[1] * z);
        Some((self.cell_start[row + x0] as usize, self.cell_start[row + x1 + 1] as usize))
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod x86 {
    use super::super::scan::x86::merge;
    use super::{TileBest, NONE, TILE};
    use core::arch::x86_64::*;

    /// [`super::PortableTile`] in AVX2 registers: the queries' coordinates and running answers,
    /// lane by lane. Only made inside functions compiled with AVX2, reached only when the CPU
    /// has it.
    pub(in super::super) struct Avx2Tile {
        q: [__m256; 3],
        d2: __m256,
        index: __m256i,
        reach2: __m256,
    }

    /// Per lane, `super::slab_gap`. (A function, not a closure: closures are not inlined into
    /// the AVX2 caller.)
    #[inline(always)]
    unsafe fn slab_gap(t: __m256, [lo, hi]: [f32; 2]) -> __m256 {
        // SAFETY: AVX on a CPU that has AVX2.
        unsafe {
            let below = _mm256_sub_ps(_mm256_set1_ps(lo), t);
            let above = _mm256_sub_ps(t, _mm256_set1_ps(hi));
            _mm256_max_ps(_mm256_max_ps(below, above), _mm256_setzero_ps())
        }
    }

    /// Squared distances from point `k` of the sorted arrays to the eight queries, as
    /// `(dx² + dy²) + dz²` without FMA (the portable twin's arithmetic). `k` must be in bounds of
    /// all three slices.
    #[inline(always)]
    unsafe fn dist(xs: &[f32], ys: &[f32], zs: &[f32], k: usize, [qx, qy, qz]: [__m256; 3]) -> __m256 {
        // SAFETY: AVX on a CPU that has AVX2; the caller keeps `k` in bounds.
        unsafe {
            let dx = _mm256_sub_ps(_mm256_broadcast_ss(&*xs.as_ptr().add(k)), qx);
            let dy = _mm256_sub_ps(_mm256_broadcast_ss(&*ys.as_ptr().add(k)), qy);
            let dz = _mm256_sub_ps(_mm256_broadcast_ss(&*zs.as_ptr().add(k)), qz);
            _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)), _mm256_mul_ps(dz, dz))
        }
    }

    impl TileBest for Avx2Tile {
        #[inline(always)]
        fn new(queries: &[[f32; 3]], start: &[(u32, f32)], reach2: &[f32]) -> Avx2Tile {
            let (mut q, mut d2, mut index) = ([[f32::NAN; TILE]; 3], [f32::NAN; TILE], [NONE; TILE]);
            let mut r2 = [f32::NAN; TILE];
            for (l, ((p, s), r)) in queries.iter().zip(start).zip(reach2).enumerate().take(TILE) {
                for a in 0..3 {
                    q[a][l] = p[a];
                }
                (index[l], d2[l]) = *s;
                r2[l] = *r;
            }
            // SAFETY: AVX2 loads of local arrays of eight, on a CPU that has AVX2.
            unsafe {
                let d = _mm256_loadu_ps(d2.as_ptr());
                let i = _mm256_loadu_si256(index.as_ptr().cast());
                // Loads spelled out: a closure (as in `map`) is not inlined into the AVX2 caller.
                let q =
                    [_mm256_loadu_ps(q[0].as_ptr()), _mm256_loadu_ps(q[1].as_ptr()), _mm256_loadu_ps(q[2].as_ptr())];
                Avx2Tile { q, d2: d, index: i, reach2: _mm256_loadu_ps(r2.as_ptr()) }
            }
        }

        #[inline(always)]
        fn scan(&mut self, (xs, ys, zs, idx): (&[f32], &[f32], &[f32], &[u32]), k0: usize, k1: usize) {
            let k1 = k1.min(xs.len()).min(ys.len()).min(zs.len()).min(idx.len());
            // SAFETY: AVX2 on a CPU that has it; every load reads index `k < k1`, inside all four
            // slices.
            unsafe {
                let (mut bd, mut bi) = (self.d2, self.index);
                // Most points improve no lane, so four points share one compare and one branch
                // (the lexicographic minimum does not depend on the order of the merges). One
                // branch per point measured 4 % slower on the hinted queries: its mispredictions
                // cost more than the arithmetic; one per eight points gained under 1 % more.
                let mut k = k0;
                while k + 4 <= k1 {
                    // Calls spelled out: a closure (as in `map`) is not inlined into the AVX2
                    // caller, and passing registers to a call made this scan 30 times slower.
                    let q = self.q;
                    let d = [
                        dist(xs, ys, zs, k, q),
                        dist(xs, ys, zs, k + 1, q),
                        dist(xs, ys, zs, k + 2, q),
                        dist(xs, ys, zs, k + 3, q),
                    ];
                    let m = _mm256_min_ps(_mm256_min_ps(d[0], d[1]), _mm256_min_ps(d[2], d[3]));
                    if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(m, bd)) != 0 {
                        for (j, d) in d.into_iter().enumerate() {
                            (bd, bi) = merge(bd, bi, d, _mm256_set1_epi32(*idx.as_ptr().add(k + j) as i32));
                        }
                    }
                    k += 4;
                }
                for k in k..k1 {
                    let d = dist(xs, ys, zs, k, self.q);
                    if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(d, bd)) != 0 {
                        (bd, bi) = merge(bd, bi, d, _mm256_set1_epi32(*idx.as_ptr().add(k) as i32));
                    }
                }
                (self.d2, self.index) = (bd, bi);
            }
        }

        /// The portable twin's arithmetic lane by lane (`max` as `a > b ? a : b`, no FMA).
        #[inline(always)]
        fn reach(&self, y: [f32; 2], z: [f32; 2]) -> Option<(f32, f32)> {
            let [qx, qy, qz] = self.q;
            // SAFETY: AVX2 on a CPU that has it; register arithmetic and stores into locals.
            let (lo, hi) = unsafe {
                let zero = _mm256_setzero_ps();
                let (dz, dy) = (slab_gap(qz, z), slab_gap(qy, y));
                let rest = _mm256_sub_ps(_mm256_sub_ps(self.reach2, _mm256_mul_ps(dz, dz)), _mm256_mul_ps(dy, dy));
                // Unused lanes are NaN and fail the test.
                let reached = _mm256_cmp_ps::<_CMP_GE_OQ>(rest, zero);
                let r = _mm256_sqrt_ps(rest);
                let lo = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), _mm256_sub_ps(qx, r), reached);
                let hi = _mm256_blendv_ps(_mm256_set1_ps(f32::NEG_INFINITY), _mm256_add_ps(qx, r), reached);
                let lo = _mm_min_ps(_mm256_castps256_ps128(lo), _mm256_extractf128_ps::<1>(lo));
                let hi = _mm_max_ps(_mm256_castps256_ps128(hi), _mm256_extractf128_ps::<1>(hi));
                let lo = _mm_min_ps(lo, _mm_movehl_ps(lo, lo));
                let hi = _mm_max_ps(hi, _mm_movehl_ps(hi, hi));
                let lo = _mm_min_ss(lo, _mm_shuffle_ps::<1>(lo, lo));
                let hi = _mm_max_ss(hi, _mm_shuffle_ps::<1>(hi, hi));
                (_mm_cvtss_f32(lo), _mm_cvtss_f32(hi))
            };
            (lo <= hi).then_some((lo, hi))
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
