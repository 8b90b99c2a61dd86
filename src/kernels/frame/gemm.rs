//! The register-tile product: the f32 and bf16 micro-kernels, the fused epilogue, the row and
//! column passes over a tile, and [`gemm`], the frame every layer runs its products on.

use super::Simd;
use crate::kernels::PANEL;

/// Rows per micro-kernel tile.
pub(crate) const MR: usize = 6;

/// Largest tile width in `f32` (stack tile for partial panels).
const MAX_TILE: usize = 64;

/// One f32 operand of a tile: activations (row stride `ldx`) and packed weights with `k` inputs.
#[derive(Clone, Copy)]
pub(crate) struct SegF32 {
    pub x: *const f32,
    pub ldx: usize,
    pub w: *const f32,
    pub k: usize,
}

/// One bf16 operand: prepared activations (row stride `ldx` slots) and packed pair-panels.
#[derive(Clone, Copy)]
pub(crate) struct SegBf16 {
    pub x: *const f32,
    pub ldx: usize,
    pub w: *const u16,
    pub pairs: usize,
    /// What the tiles request while they run: the f32 rows the next block will prepare.
    pub ahead: Ahead,
}

/// A region of memory that the row tiles of a product's first column pass request between them,
/// a share each: the f32 source rows of the next row block, which its bf16 preparation will
/// read (the AMX path does not request it; it was not measured there). Prepared all at
/// once, a block's rows came from L3 or memory in one burst that the core waited on (about a
/// tenth of a bf16 linear layer's time); requested a few lines per pair step over the block
/// before, they are in cache when it starts. (Requested all at once, they pushed the tiles'
/// weights out of L1 and lost more than they gained.)
#[derive(Clone, Copy)]
pub(crate) struct Ahead {
    /// First byte of the region, or null for none.
    start: *const u8,
    /// Its length in bytes.
    bytes: usize,
    /// Cache lines each row tile requests: the region's lines over the row tiles.
    lines_per_tile: usize,
}

impl Ahead {
    /// No region.
    pub(crate) const NONE: Ahead = Ahead { start: core::ptr::null(), bytes: 0, lines_per_tile: 0 };

    /// The rows `next` (the next block's, possibly none), shared among the row tiles of a
    /// product of `rows` rows.
    pub(crate) fn new(next: &[f32], rows: usize) -> Ahead {
        let bytes = core::mem::size_of_val(next);
        if bytes == 0 || rows == 0 {
            return Ahead::NONE;
        }
        let lines_per_tile = bytes.div_ceil(LINE_BYTES).div_ceil(rows.div_ceil(MR));
        Ahead { start: next.as_ptr() as *const u8, bytes, lines_per_tile }
    }

    /// The byte range `[from, to)` of the region that the row tile from row `row0` requests.
    fn share(&self, row0: usize) -> (usize, usize) {
        let from = (row0 / MR * self.lines_per_tile * LINE_BYTES).min(self.bytes);
        (from, (from + self.lines_per_tile * LINE_BYTES).min(self.bytes))
    }
}

/// Operand lists of either precision.
#[derive(Clone, Copy)]
pub(crate) enum Segs<'a> {
    F32(&'a [SegF32]),
    Bf16(&'a [SegBf16]),
}

/// The fused epilogue of a tile: `+ bias`, `+ addend row`, ReLU, then store or add.
#[derive(Clone, Copy)]
pub(crate) struct TileEpi {
    pub bias: *const f32,
    /// Null, or rows of `n` values (stride `n`) added to output row `i` after the bias: the
    /// gathered node projections of the split first edge layer, summed once per block.
    pub addend: *const f32,
    pub relu: bool,
    pub accumulate: bool,
    /// Whether each tile first requests the cache lines of its output rows. For outputs in
    /// arrays that outgrow L1 (a linear layer's): the tile's stores then find their lines in
    /// cache instead of stalling on them. The edge chain's outputs are scratch rows already in L1,
    /// where the hints only cost (2-17 % of the kernels bench's edge MLP).
    pub prefetch_out: bool,
    /// Whether the output rows are the next layer's prepared bf16 activations
    /// ([`Simd::store_prepared`]: column `c` at slot `c · SLOTS_PER_PAIR / 2` of its row) rather
    /// than f32 values. Only for `n` a multiple of [`PANEL`] (every vector is whole) and without
    /// `accumulate`.
    pub prepared_out: bool,
}

/// Bytes per cache line.
const LINE_BYTES: usize = 64;

/// `f32` values per 64-byte cache line.
const LINE_FLOATS: usize = LINE_BYTES / 4;

/// Fewest inputs for which an f32 tile prefetches the rows below it: shorter rows form one
/// stream the hardware prefetcher follows (at k = 32 the hint did not pay).
const PREFETCH_MIN_K: usize = 64;

/// Prefetches, for each of a tile's `R` activation rows `x`, the line `offset` floats on: with
/// `offset = R · ldx + k`, the line the tile below will read where this one reads now. On the
/// first column pass of a row block the activations come from memory or L3, and the six
/// interleaved row streams of a tile are too short (k = 128: eight lines each) for the hardware
/// prefetcher to run ahead of them. On a Zen 3 core the hint took the f32 linear layer of the
/// kernels bench (h = 128, 30,000 rows) from 72 % to 87 % of the FMA peak. `kernel_bf16` goes
/// without: its activations are a prepared copy, already in cache (there the hint did not pay).
#[inline(always)]
unsafe fn prefetch_next_rows<S: Simd, const R: usize>(s: S, x: &[*const f32; R], offset: usize) {
    for &row in x {
        // SAFETY: a prefetch never faults; the address is formed with `wrapping_add`, so it
        // may lie past the operand (the last tile) without a pointer to outside it being used.
        unsafe { s.prefetch(row.wrapping_add(offset) as *const u8) };
    }
}

/// A tile of zero accumulators. The tiles' accumulators live in a stack array that the compiler
/// moves into registers around the product loop; zeroed from the constant, that array was
/// cleared by a call to `memset` on every tile (1.5 KB at 6 × 4 vectors of 64 bytes). A zero the
/// compiler cannot see as a constant makes it plain vector stores.
#[inline(always)]
fn zero_tile<S: Simd, const R: usize, const NV: usize>(s: S) -> [[S::V; NV]; R] {
    [[s.splat(core::hint::black_box(0.0)); NV]; R]
}

#[inline(always)]
unsafe fn kernel_f32<S: Simd, const R: usize, const NV: usize>(
    s: S,
    segs: &[SegF32],
    row0: usize,
    p0: usize,
) -> [[S::V; NV]; R] {
    // SAFETY (whole body): the frame passes rows `row0..row0+R` that exist in every operand and
    // panels `p0..p0+NV·LANES/PANEL` that exist in every packed matrix.
    unsafe {
        let mut acc = zero_tile::<S, R, NV>(s);
        for seg in segs {
            let k = seg.k;
            let w: [*const f32; NV] = core::array::from_fn(|v| {
                let c = v * S::LANES;
                seg.w.add((p0 + c / PANEL) * PANEL * k + c % PANEL)
            });
            let x: [*const f32; R] = core::array::from_fn(|r| seg.x.add((row0 + r) * seg.ldx));
            // With the row hint, the inputs go in runs of one cache line, the hint before each
            // run; without it, in one run (the inner loop then has no test for the hint).
            let prefetch_rows = S::PREFETCH_NEXT_ROWS && k >= PREFETCH_MIN_K;
            let mut k0 = 0;
            while k0 < k {
                let k1 = if prefetch_rows {
                    prefetch_next_rows::<S, R>(s, &x, R * seg.ldx + k0);
                    (k0 + LINE_FLOATS).min(k)
                } else {
                    k
                };
                for kk in k0..k1 {
                    if NV * S::LANES >= 32 {
                        s.prefetch(w[0].wrapping_add((kk + 8) * PANEL) as *const u8);
                    }
                    let wv: [S::V; NV] = core::array::from_fn(|v| s.load(w[v].add(kk * PANEL)));
                    for r in 0..R {
                        let xb = s.splat(*x[r].add(kk));
                        for v in 0..NV {
                            acc[r][v] = s.fma(xb, wv[v], acc[r][v]);
                        }
                    }
                }
                k0 = k1;
            }
        }
        acc
    }
}

#[inline(always)]
unsafe fn kernel_bf16<S: Simd, const R: usize, const NV: usize>(
    s: S,
    segs: &[SegBf16],
    row0: usize,
    p0: usize,
) -> [[S::V; NV]; R] {
    // SAFETY (whole body): as in `kernel_f32`, for pairs of inputs.
    unsafe {
        let mut acc = zero_tile::<S, R, NV>(s);
        for seg in segs {
            let kp = seg.pairs * 2;
            let w: [*const u16; NV] = core::array::from_fn(|v| {
                let c = v * S::LANES;
                seg.w.add((p0 + c / PANEL) * PANEL * kp + (c % PANEL) * 2)
            });
            let x: [*const f32; R] = core::array::from_fn(|r| seg.x.add((row0 + r) * seg.ldx));
            if S::SLOTS_PER_PAIR == 2 {
                // Widened weights: the even then the odd input of each pair, like two f32 steps
                // (only NV weight registers live, and the scalar reference's summation order).
                for pr in 0..seg.pairs {
                    for half in 0..2 {
                        let wv: [S::V; NV] = core::array::from_fn(|v| s.load_w_half(w[v].add(pr * 2 * PANEL), half));
                        for r in 0..R {
                            let xb = s.splat(*x[r].add(pr * 2 + half));
                            for v in 0..NV {
                                acc[r][v] = s.fma(xb, wv[v], acc[r][v]);
                            }
                        }
                    }
                }
            } else {
                // This tile's share of the region ahead (first column pass only), a few lines
                // per pair step.
                let (mut pf, pf_end) = if p0 == 0 { seg.ahead.share(row0) } else { (0, 0) };
                let step = seg.ahead.lines_per_tile.div_ceil(seg.pairs.max(1)) * LINE_BYTES;
                for pr in 0..seg.pairs {
                    if pf < pf_end {
                        let mut q = pf;
                        pf = (pf + step).min(pf_end);
                        while q < pf {
                            // SAFETY: inside the region (`q < bytes`); a prefetch never faults.
                            s.prefetch(seg.ahead.start.add(q));
                            q += LINE_BYTES;
                        }
                    }
                    let wv: [S::WP; NV] = core::array::from_fn(|v| s.load_w2(w[v].add(pr * 2 * PANEL)));
                    for r in 0..R {
                        let xp = s.bcast_x2(x[r].add(pr));
                        for v in 0..NV {
                            acc[r][v] = s.dot2(acc[r][v], wv[v], xp);
                        }
                    }
                }
            }
        }
        acc
    }
}

/// The epilogue of one output vector `y` at column `c` of output row `o` (`g`: that row of the
/// addend, if any): `+ bias`, `+ addend`, ReLU, then store or add.
#[inline(always)]
unsafe fn epilogue_vec<S: Simd>(s: S, mut y: S::V, c: usize, g: Option<*const f32>, o: *mut f32, epi: &TileEpi) {
    // SAFETY: the caller's: `LANES` columns from `c` exist in the bias, `g` and `o`.
    unsafe {
        if !epi.bias.is_null() {
            y = s.add(y, s.load(epi.bias.add(c)));
        }
        if let Some(g) = g {
            y = s.add(y, s.load(g.add(c)));
        }
        if epi.relu {
            y = s.max(y, s.zero());
        }
        if epi.prepared_out {
            s.store_prepared(o.add(c * S::SLOTS_PER_PAIR / 2), y);
            return;
        }
        if epi.accumulate {
            y = s.add(y, s.load(o.add(c)));
        }
        s.store(o.add(c), y);
    }
}

/// [`epilogue_vec`] for one value (of an f32 output: prepared outputs have whole vectors).
#[inline(always)]
unsafe fn epilogue_one(mut y: f32, c: usize, g: Option<*const f32>, o: *mut f32, epi: &TileEpi) {
    debug_assert!(!epi.prepared_out, "a prepared output with a partial vector");
    // SAFETY: the caller's: column `c` exists in the bias, `g` and `o`.
    unsafe {
        if !epi.bias.is_null() {
            y += *epi.bias.add(c);
        }
        if let Some(g) = g {
            y += *g.add(c);
        }
        if epi.relu {
            y = y.max(0.0);
        }
        if epi.accumulate {
            y += *o.add(c);
        }
        *o.add(c) = y;
    }
}

/// Applies the epilogue to one panel of sums (`PANEL` values at `sums`) and writes them to output
/// row `row`, columns `c0..min(c0 + PANEL, n)`: for kernels that accumulate outside registers.
///
/// # Safety
/// As [`gemm`]'s; `sums` holds `PANEL` values and `c0 < n`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn epilogue_row<S: Simd>(
    s: S,
    sums: *const f32,
    row: usize,
    c0: usize,
    n: usize,
    out: *mut f32,
    ldo: usize,
    epi: &TileEpi,
) {
    // SAFETY: as the contract: row `row` exists in `out` and the addend, columns below `n`.
    unsafe {
        let o = out.add(row * ldo);
        let g = if epi.addend.is_null() { None } else { Some(epi.addend.add(row * n)) };
        if c0 + PANEL <= n && PANEL.is_multiple_of(S::LANES) {
            for v in (0..PANEL).step_by(S::LANES) {
                epilogue_vec(s, s.load(sums.add(v)), c0 + v, g, o, epi);
            }
        } else {
            for j in 0..(n - c0).min(PANEL) {
                epilogue_one(*sums.add(j), c0 + j, g, o, epi);
            }
        }
    }
}

/// Applies the epilogue to a tile and writes output rows `row0..row0+R`, columns from panel `p0`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn store_tile<S: Simd, const R: usize, const NV: usize>(
    s: S,
    acc: [[S::V; NV]; R],
    row0: usize,
    p0: usize,
    n: usize,
    out: *mut f32,
    ldo: usize,
    epi: &TileEpi,
) {
    let c0 = p0 * PANEL;
    let width = NV * S::LANES;
    // SAFETY (whole body): output rows exist with `ldo >= n`; bias and gathered rows have `n`
    // columns; vector accesses stay below `n` (full tiles) or go through the stack tile.
    unsafe {
        for (r, acc_r) in acc.iter().enumerate() {
            let row = row0 + r;
            let o = out.add(row * ldo);
            let g = if epi.addend.is_null() { None } else { Some(epi.addend.add(row * n)) };
            if c0 + width <= n {
                for (v, &a) in acc_r.iter().enumerate() {
                    epilogue_vec(s, a, c0 + v * S::LANES, g, o, epi);
                }
            } else {
                let mut tile = [0.0f32; MAX_TILE];
                for (v, &a) in acc_r.iter().enumerate() {
                    s.store(tile.as_mut_ptr().add(v * S::LANES), a);
                }
                for (j, &t) in tile.iter().enumerate().take(n.saturating_sub(c0).min(width)) {
                    epilogue_one(t, c0 + j, g, o, epi);
                }
            }
        }
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tile<S: Simd, const R: usize, const NV: usize>(
    s: S,
    segs: Segs<'_>,
    row0: usize,
    p0: usize,
    n: usize,
    out: *mut f32,
    ldo: usize,
    epi: &TileEpi,
) {
    // SAFETY: forwarded contract of `gemm`.
    unsafe {
        if epi.prefetch_out {
            for r in 0..R {
                let o = out.wrapping_add((row0 + r) * ldo + p0 * PANEL);
                for c in (0..NV * S::LANES).step_by(LINE_FLOATS) {
                    s.prefetch(o.wrapping_add(c) as *const u8);
                }
            }
        }
        let acc = match segs {
            Segs::F32(sg) => kernel_f32::<S, R, NV>(s, sg, row0, p0),
            Segs::Bf16(sg) => kernel_bf16::<S, R, NV>(s, sg, row0, p0),
        };
        store_tile::<S, R, NV>(s, acc, row0, p0, n, out, ldo, epi);
    }
}

/// All rows of one column tile (panels `p0..p0 + NV·LANES/PANEL`): the tile's weights stay in L1
/// while the row block's activations stream past them.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn column_pass<S: Simd, const NV: usize>(
    s: S,
    segs: Segs<'_>,
    rows: usize,
    p0: usize,
    n: usize,
    out: *mut f32,
    ldo: usize,
    epi: &TileEpi,
) {
    let mut row0 = 0;
    // SAFETY: forwarded contract of `gemm`; each tile covers rows below `rows`.
    unsafe {
        while row0 + MR <= rows {
            tile::<S, MR, NV>(s, segs, row0, p0, n, out, ldo, epi);
            row0 += MR;
        }
        match rows - row0 {
            1 => tile::<S, 1, NV>(s, segs, row0, p0, n, out, ldo, epi),
            2 => tile::<S, 2, NV>(s, segs, row0, p0, n, out, ldo, epi),
            3 => tile::<S, 3, NV>(s, segs, row0, p0, n, out, ldo, epi),
            4 => tile::<S, 4, NV>(s, segs, row0, p0, n, out, ldo, epi),
            5 => tile::<S, 5, NV>(s, segs, row0, p0, n, out, ldo, epi),
            _ => {}
        }
    }
}

/// `out[rows × n] (+)= epilogue(Σ segs)`, column tiles outside, row tiles inside (callers pass
/// blocks of at most ~100 rows, so the activations stay in L2 and each weight tile in L1).
///
/// # Safety
/// Every operand has `rows` rows and packed weights with `ceil(n/16)` panels; `out` has `rows`
/// rows of stride `ldo >= n`; the epilogue's pointers cover `n` columns (and, for a gather, `rows`
/// valid indices). (That the CPU runs `S` is proven by the token `s`.)
#[inline(always)]
pub(crate) unsafe fn gemm<S: Simd>(
    s: S,
    segs: Segs<'_>,
    rows: usize,
    n: usize,
    out: *mut f32,
    ldo: usize,
    epi: &TileEpi,
) {
    if let Segs::Bf16(sg) = segs {
        // SAFETY: forwarded contract.
        if unsafe { s.gemm_bf16(sg, rows, n, out, ldo, epi) } {
            return;
        }
    }
    let panels = n.div_ceil(PANEL);
    let mut p = 0;
    // SAFETY: forwarded; each pass covers panels below `panels`.
    unsafe {
        while p < panels {
            if S::LANES == 8 {
                column_pass::<S, 2>(s, segs, rows, p, n, out, ldo, epi);
                p += 1;
                continue;
            }
            let np = (panels - p).min(S::TILE_PANELS);
            match np {
                1 => column_pass::<S, 1>(s, segs, rows, p, n, out, ldo, epi),
                2 => column_pass::<S, 2>(s, segs, rows, p, n, out, ldo, epi),
                3 => column_pass::<S, 3>(s, segs, rows, p, n, out, ldo, epi),
                _ => column_pass::<S, 4>(s, segs, rows, p, n, out, ldo, epi),
            }
            p += np;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Ahead, LINE_BYTES, MR};
    use alloc::vec;
    use proptest::prelude::*;

    proptest! {
        /// The row tiles of a product share out the region ahead whole: every cache line of it is
        /// requested by exactly one tile, and no tile reaches past its end.
        #[test]
        fn ahead_shares_cover_the_region_once(rows in 1usize..400, floats in 0usize..50_000) {
            let next = vec![0.0f32; floats];
            let bytes = 4 * floats;
            let ahead = Ahead::new(&next, rows);
            let mut next = 0;
            for row0 in (0..rows).step_by(MR) {
                let (from, to) = ahead.share(row0);
                prop_assert!(from <= to && to <= bytes);
                if from < to {
                    prop_assert_eq!(from, next);
                    next = to;
                }
            }
            prop_assert_eq!(next, bytes);
            prop_assert!(ahead.lines_per_tile * LINE_BYTES * rows.div_ceil(MR) >= bytes);
        }
    }
}
