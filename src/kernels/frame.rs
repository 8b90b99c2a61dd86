//! The architecture-neutral half of the SIMD paths: micro-kernels and frames written once over a
//! [`Simd`] vocabulary, instantiated inside each tier's `#[target_feature]` entry point (every
//! function here is `#[inline(always)]` so it is compiled with the caller's features).
//!
//! * The **micro-kernel** computes an `MR × (NV · LANES)` tile of `Σ x · Wᵀ` in registers: per
//!   input, `NV` weight vectors are loaded from the packed panels and each of the `MR` activation
//!   rows is broadcast once (`MR · NV` FMAs for `NV + MR` loads).
//! * The **frame** walks row blocks and column tiles, handles row tails (smaller `MR`) and the
//!   last partial panel (through a small stack tile), and applies the fused epilogue.
//! * Row passes (bf16 rounding of activations, LayerNorm, residual and aggregate adds) are plain
//!   loops that the compiler vectorises for the caller's features.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

use super::{
    packed_len_f32, EdgeInputs, EdgeMlp, Epilogue, Operand, PackedBf16, Weights, EDGE_BLOCK, LINEAR_BLOCK_ROWS, LN_EPS,
    PANEL,
};

/// Rows per micro-kernel tile.
pub(crate) const MR: usize = 6;

/// Largest tile width in `f32` (stack tile for partial panels).
const MAX_TILE: usize = 64;

/// Rounds to the nearest bf16 (ties to even) and widens back: the value a bf16 activation has.
/// Finite inputs only (NaN payloads are not preserved).
#[inline(always)]
pub(crate) fn round_bf16(x: f32) -> f32 {
    let b = x.to_bits();
    f32::from_bits(b.wrapping_add(0x7FFF + ((b >> 16) & 1)) & 0xFFFF_0000)
}

/// `Σ f(y_i)` in 8 interleaved partial sums, so the compiler can keep them in one vector (a
/// single serial sum would be a latency chain as long as the row). The tail (`len % 8`) is summed
/// apart: folding it into the partial sums made the compiler keep them on the stack with masked
/// stores, which cannot forward to the next load and stalled every LayerNorm row.
#[inline(always)]
pub(crate) fn lane_sum(y: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut acc = [0.0f32; 8];
    let chunks = y.chunks_exact(8);
    let tail = chunks.remainder();
    for c in chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            *a += f(*v);
        }
    }
    let rest = tail.iter().fold(0.0f32, |t, v| t + f(*v));
    (((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]))) + rest
}

/// `Σ a_i·b_i` over the shorter of the two, in the partial sums of [`lane_sum`] (the trainer's
/// LayerNorm backward).
#[cfg(feature = "train")]
#[inline(always)]
pub(crate) fn lane_dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f32; 8];
    for (ca, cb) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        for ((s, x), y) in acc.iter_mut().zip(ca).zip(cb) {
            *s += x * y;
        }
    }
    let t = n - n % 8;
    let rest = a[t..].iter().zip(&b[t..]).fold(0.0f32, |s, (x, y)| s + x * y);
    (((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]))) + rest
}

/// Mean and inverse standard deviation of one row (two-pass, eps [`LN_EPS`]).
#[inline(always)]
pub(crate) fn layer_norm_stats(y: &[f32]) -> (f32, f32) {
    let n = y.len() as f32;
    let mean = lane_sum(y, |v| v) / n;
    let var = lane_sum(y, |v| (v - mean) * (v - mean)) / n;
    (mean, 1.0 / crate::math::sqrt_f32(var + LN_EPS))
}

/// [`layer_norm_stats`] of consecutive rows of `width` values (`stats` gets one entry per row).
/// The portable form, row by row; the x86 tiers batch rows with the same arithmetic
/// ([`Simd::layer_norm_stats_rows`]).
#[inline(always)]
pub(crate) fn layer_norm_stats_rows(y: &[f32], width: usize, stats: &mut [(f32, f32)]) {
    if width == 0 {
        return;
    }
    for (row, out) in y.chunks_exact(width).zip(stats) {
        *out = layer_norm_stats(row);
    }
}

/// In-place affine LayerNorm of one row (two-pass mean and variance, eps [`LN_EPS`]).
#[inline(always)]
pub(crate) fn layer_norm_row(y: &mut [f32], gamma: &[f32], beta: &[f32]) {
    let (mean, inv) = layer_norm_stats(y);
    for ((v, g), b) in y.iter_mut().zip(gamma).zip(beta) {
        *v = (*v - mean) * inv * g + b;
    }
}

/// Widens packed bf16 weights into the f32 panel layout (same `k` and `n`), for tiers without
/// bf16 dot products: they then run the f32 micro-kernel on bf16-exact weights.
#[inline(always)]
pub(crate) fn widen_bf16(w: &PackedBf16<'_>, dst: &mut [f32]) {
    let k = w.k();
    let kp = k.next_multiple_of(2);
    if k == 0 {
        return;
    }
    for (sp, dp) in w.data().chunks_exact(PANEL * kp).zip(dst.chunks_exact_mut(PANEL * k)) {
        for kk in 0..k {
            let src = &sp[(kk / 2) * 2 * PANEL + kk % 2..];
            for j in 0..PANEL {
                dp[kk * PANEL + j] = f32::from_bits((src[2 * j].to_bits() as u32) << 16);
            }
        }
    }
}

/// The vector vocabulary a tier provides. All methods are `unsafe`: they are only sound on a
/// CPU with the tier's features (which the token type proves) and with in-bounds pointers.
pub(crate) trait Simd: Copy {
    /// f32 lanes per vector.
    const LANES: usize;
    /// Panels (of [`PANEL`] columns) per widest tile.
    const TILE_PANELS: usize;
    /// Prepared-activation `f32` slots per input pair: 2 (bf16-rounded f32 values) or 1 (a
    /// packed pair of bf16, as `vdpbf16ps` broadcasts it).
    const SLOTS_PER_PAIR: usize;
    type V: Copy;
    /// A loaded weight vector holding `LANES` columns × (even, odd) input.
    type WP: Copy;
    /// A broadcast activation pair.
    type XP: Copy;

    unsafe fn zero(self) -> Self::V;
    unsafe fn splat(self, v: f32) -> Self::V;
    unsafe fn load(self, p: *const f32) -> Self::V;
    unsafe fn store(self, p: *mut f32, v: Self::V);
    /// `a · b + c`.
    unsafe fn fma(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    unsafe fn add(self, a: Self::V, b: Self::V) -> Self::V;
    unsafe fn max(self, a: Self::V, b: Self::V) -> Self::V;
    unsafe fn prefetch(self, p: *const u8);

    /// Loads `LANES` columns × 2 inputs of packed bf16 weights.
    unsafe fn load_w2(self, p: *const u16) -> Self::WP;
    /// Loads `LANES` columns of the even (`half == 0`) or odd input of packed bf16 weights,
    /// widened to f32.
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> Self::V;
    /// Broadcasts the prepared activation pair at `p`.
    unsafe fn bcast_x2(self, p: *const f32) -> Self::XP;
    /// `acc + w_even · x_even + w_odd · x_odd`, f32 accumulation.
    unsafe fn dot2(self, acc: Self::V, w: Self::WP, x: Self::XP) -> Self::V;

    /// [`layer_norm_stats_rows`]; a tier may override it only with the same arithmetic (its
    /// results must stay bitwise those of [`layer_norm_stats`]).
    #[inline(always)]
    fn layer_norm_stats_rows(self, y: &[f32], width: usize, stats: &mut [(f32, f32)]) {
        layer_norm_stats_rows(y, width, stats);
    }

    /// A tier's own product for bf16 operands (the AMX tiles), or `false` when the register
    /// tiles run it. Arguments and contract as [`gemm`]'s; called between [`Simd::bf16_begin`]
    /// and [`Simd::bf16_end`].
    #[inline(always)]
    unsafe fn gemm_bf16(
        self,
        _segs: &[SegBf16],
        _rows: usize,
        _n: usize,
        _out: *mut f32,
        _ldo: usize,
        _epi: &TileEpi,
    ) -> bool {
        false
    }

    /// Sets up what [`Simd::gemm_bf16`] needs for one kernel call (the tile configuration).
    #[inline(always)]
    fn bf16_begin(self) {}

    /// Releases what [`Simd::bf16_begin`] set up.
    #[inline(always)]
    fn bf16_end(self) {}

    /// Writes `src` (k values) as prepared bf16 activations (`kp · SLOTS_PER_PAIR / 2` slots).
    #[inline(always)]
    fn prep_bf16(self, src: &[f32], dst: &mut [f32]) {
        if Self::SLOTS_PER_PAIR == 2 {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = round_bf16(*s);
            }
            if src.len() % 2 == 1 {
                dst[src.len()] = 0.0;
            }
        } else {
            pack_bf16_pairs(src, dst);
        }
    }
}

/// Writes `src` as packed bf16 pairs, one per `f32` slot (the even input in the low half, as
/// `vdpbf16ps` reads them); an odd last input is paired with zero. The portable form of the
/// prepared activations of tiers with bf16 dot products.
#[inline(always)]
pub(crate) fn pack_bf16_pairs(src: &[f32], dst: &mut [f32]) {
    let pairs = src.len() / 2;
    for (d, s) in dst[..pairs].iter_mut().zip(src.chunks_exact(2)) {
        let lo = round_bf16(s[0]).to_bits() >> 16;
        let hi = round_bf16(s[1]).to_bits() & 0xFFFF_0000;
        *d = f32::from_bits(hi | lo);
    }
    if src.len() % 2 == 1 {
        dst[pairs] = f32::from_bits(round_bf16(src[src.len() - 1]).to_bits() >> 16);
    }
}

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
        let mut acc = [[s.zero(); NV]; R];
        for seg in segs {
            let k = seg.k;
            let w: [*const f32; NV] = core::array::from_fn(|v| {
                let c = v * S::LANES;
                seg.w.add((p0 + c / PANEL) * PANEL * k + c % PANEL)
            });
            let x: [*const f32; R] = core::array::from_fn(|r| seg.x.add((row0 + r) * seg.ldx));
            for kk in 0..k {
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
        let mut acc = [[s.zero(); NV]; R];
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
                for pr in 0..seg.pairs {
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
        if epi.accumulate {
            y = s.add(y, s.load(o.add(c)));
        }
        s.store(o.add(c), y);
    }
}

/// [`epilogue_vec`] for one value.
#[inline(always)]
unsafe fn epilogue_one(mut y: f32, c: usize, g: Option<*const f32>, o: *mut f32, epi: &TileEpi) {
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
/// The CPU supports `S`; every operand has `rows` rows and packed weights with `ceil(n/16)`
/// panels; `out` has `rows` rows of stride `ldo >= n`; the epilogue's pointers cover `n` columns
/// (and, for a gather, `rows` valid indices).
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

fn bias_ptr(bias: Option<&[f32]>) -> *const f32 {
    bias.map_or(core::ptr::null(), |b| b.as_ptr())
}

/// [`super::Kernels::linear`] on tier `S` (arguments validated by the caller).
///
/// # Safety
/// The CPU supports `S`.
#[inline(always)]
pub(crate) unsafe fn linear<S: Simd>(
    s: S,
    ops: &[Operand<'_>],
    bias: Option<&[f32]>,
    epi: &Epilogue<'_>,
    out: &mut [f32],
    scratch: &mut [f32],
) {
    let n = ops[0].w.n();
    let rows = out.len() / n;
    let kps: usize = ops.iter().map(|o| o.w.k().next_multiple_of(2)).sum();
    let (prep, rest) = scratch.split_at_mut(LINEAR_BLOCK_ROWS * kps);
    let (pre_ln, mut wide) = rest.split_at_mut(LINEAR_BLOCK_ROWS * super::padded_cols(n));
    // Without bf16 dot products, bf16 weights are widened once per call.
    let emulate = S::SLOTS_PER_PAIR == 2;
    let mut wide_ptr = [core::ptr::null::<f32>(); super::MAX_OPERANDS];
    if emulate {
        for (i, op) in ops.iter().enumerate() {
            if let Weights::Bf16(w) = op.w {
                let (this, next) = core::mem::take(&mut wide).split_at_mut(packed_len_f32(w.k(), n));
                widen_bf16(&w, this);
                wide_ptr[i] = this.as_ptr();
                wide = next;
            }
        }
    }
    let native_bf16 = ops[0].w.is_bf16() && !emulate;
    if native_bf16 {
        s.bf16_begin();
    }
    let mut b0 = 0;
    while b0 < rows {
        let br = (rows - b0).min(LINEAR_BLOCK_ROWS);
        let mut f32_segs = [SegF32 { x: core::ptr::null(), ldx: 0, w: core::ptr::null(), k: 0 }; super::MAX_OPERANDS];
        let mut bf_segs =
            [SegBf16 { x: core::ptr::null(), ldx: 0, w: core::ptr::null(), pairs: 0 }; super::MAX_OPERANDS];
        let mut off = 0;
        for (i, op) in ops.iter().enumerate() {
            let k = op.w.k();
            let x = &op.x[b0 * k..(b0 + br) * k];
            match op.w {
                Weights::F32(w) => f32_segs[i] = SegF32 { x: x.as_ptr(), ldx: k, w: w.data().as_ptr(), k },
                Weights::Bf16(w) => {
                    let kp = k.next_multiple_of(2);
                    let area = &mut prep[off..off + br * kp];
                    for (src, dst) in x.chunks_exact(k.max(1)).zip(area.chunks_exact_mut(kp.max(1))) {
                        s.prep_bf16(src, dst);
                    }
                    bf_segs[i] =
                        SegBf16 { x: area.as_ptr(), ldx: kp, w: w.data().as_ptr() as *const u16, pairs: kp / 2 };
                    f32_segs[i] = SegF32 { x: area.as_ptr(), ldx: kp, w: wide_ptr[i], k };
                    off += br * kp;
                }
            }
        }
        let segs = if ops[0].w.is_bf16() && !emulate {
            Segs::Bf16(&bf_segs[..ops.len()])
        } else {
            Segs::F32(&f32_segs[..ops.len()])
        };
        let out_blk = &mut out[b0 * n..(b0 + br) * n];
        let tepi = TileEpi { bias: bias_ptr(bias), addend: core::ptr::null(), relu: epi.relu, accumulate: false };
        match (&epi.layer_norm, epi.residual) {
            (None, residual) => {
                let tepi = TileEpi { accumulate: residual, ..tepi };
                // SAFETY: shapes validated by `Kernels::linear`; the CPU supports `S`.
                unsafe { gemm(s, segs, br, n, out_blk.as_mut_ptr(), n, &tepi) };
            }
            (Some(ln), false) => {
                // SAFETY: as above.
                unsafe { gemm(s, segs, br, n, out_blk.as_mut_ptr(), n, &tepi) };
                for y in out_blk.chunks_exact_mut(n) {
                    layer_norm_row(y, ln.gamma, ln.beta);
                }
            }
            (Some(ln), true) => {
                let tmp = &mut pre_ln[..br * n];
                // SAFETY: as above, into the scratch rows.
                unsafe { gemm(s, segs, br, n, tmp.as_mut_ptr(), n, &tepi) };
                for (y, o) in tmp.chunks_exact_mut(n).zip(out_blk.chunks_exact_mut(n)) {
                    layer_norm_row(y, ln.gamma, ln.beta);
                    for (o, v) in o.iter_mut().zip(y.iter()) {
                        *o += v;
                    }
                }
            }
        }
        b0 += br;
    }
    if native_bf16 {
        s.bf16_end();
    }
}

/// Runs one layer of the edge chain on `br` rows: `x` (f32, `k` wide) or its prepared bf16 copy.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn chain_layer<S: Simd>(
    s: S,
    w: &Weights<'_>,
    x: &[f32],
    br: usize,
    prep: &mut [f32],
    wide: &[f32],
    out: &mut [f32],
    epi: &TileEpi,
) {
    let (k, n) = (w.k(), w.n());
    match w {
        Weights::F32(wf) => {
            let seg = [SegF32 { x: x.as_ptr(), ldx: k, w: wf.data().as_ptr(), k }];
            // SAFETY: `x` has `br` rows of `k`, `out` `br` rows of `n`; the CPU supports `S`.
            unsafe { gemm(s, Segs::F32(&seg), br, n, out.as_mut_ptr(), n, epi) };
        }
        Weights::Bf16(wb) => {
            let kp = k.next_multiple_of(2);
            for (src, dst) in x[..br * k].chunks_exact(k).zip(prep.chunks_exact_mut(kp)) {
                s.prep_bf16(src, dst);
            }
            if S::SLOTS_PER_PAIR == 2 {
                // Widened weights (see `widen_bf16`) and bf16-rounded activations.
                let seg = [SegF32 { x: prep.as_ptr(), ldx: kp, w: wide.as_ptr(), k }];
                // SAFETY: as above with the prepared rows and the widened weights.
                unsafe { gemm(s, Segs::F32(&seg), br, n, out.as_mut_ptr(), n, epi) };
            } else {
                let seg = [SegBf16 { x: prep.as_ptr(), ldx: kp, w: wb.data().as_ptr() as *const u16, pairs: kp / 2 }];
                // SAFETY: as above with the prepared rows.
                unsafe { gemm(s, Segs::Bf16(&seg), br, n, out.as_mut_ptr(), n, epi) };
            }
        }
    }
}

/// [`super::Kernels::edge_mlp`] on tier `S` (arguments validated by the caller).
///
/// # Safety
/// The CPU supports `S`.
#[inline(always)]
pub(crate) unsafe fn edge_mlp<S: Simd>(
    s: S,
    mlp: &EdgeMlp<'_>,
    edges: &EdgeInputs<'_>,
    latent: &mut [f32],
    aggregate: &mut [f32],
    scratch: &mut [f32],
) {
    let k_e = mlp.w1_edge.k();
    let h = mlp.w1_edge.n();
    let n_edges = edges.target.len();
    let prep_w = k_e.next_multiple_of(2).max(h.next_multiple_of(2));
    let (prep, rest) = scratch.split_at_mut(EDGE_BLOCK * prep_w);
    let (buf_a, rest) = rest.split_at_mut(EDGE_BLOCK * h.max(k_e));
    let (buf_b, rest) = rest.split_at_mut(EDGE_BLOCK * h);
    let (wide1, rest) = rest.split_at_mut(packed_len_f32(k_e, h));
    let (wide2, rest) = rest.split_at_mut(packed_len_f32(h, h));
    let wide3 = &mut rest[..packed_len_f32(h, k_e)];
    if S::SLOTS_PER_PAIR == 2 {
        for (w, dst) in [(&mlp.w1_edge, &mut *wide1), (&mlp.w2, &mut *wide2), (&mlp.w3, &mut *wide3)] {
            if let Weights::Bf16(wb) = w {
                widen_bf16(wb, dst);
            }
        }
    }
    let native_bf16 = mlp.w1_edge.is_bf16() && S::SLOTS_PER_PAIR != 2;
    if native_bf16 {
        s.bf16_begin();
    }
    let mut e0 = 0;
    while e0 < n_edges {
        let br = (n_edges - e0).min(EDGE_BLOCK);
        // The split first layer's node projections, gathered and summed once per edge: the
        // loads of random node rows overlap here, instead of stalling each column pass's
        // epilogue. (`pt + ps` is the same sum the epilogue formed before, so results are
        // unchanged.)
        for (i, g) in buf_b[..br * h].chunks_exact_mut(h).enumerate() {
            let (t, src) = (edges.target[e0 + i] as usize * h, edges.source[e0 + i] as usize * h);
            for ((g, a), b) in g.iter_mut().zip(&edges.p_target[t..t + h]).zip(&edges.p_source[src..src + h]) {
                *g = a + b;
            }
        }
        // The source projection rows are random rows of node arrays that outgrow L2: request
        // those of the block after next now (one block ahead left part of their latency
        // exposed). Target rows are sequential (edges are sorted by target): the hardware
        // prefetcher has them, and prefetching them too cost 2.5 % of the bf16 edge MLP.
        // (Prefetching the next block's latent rows gained 3 % in f32 but lost 2 % in bf16.)
        for e in (e0 + 2 * br).min(n_edges)..(e0 + 3 * br).min(n_edges) {
            let src = edges.source[e] as usize * h;
            for c in (0..h).step_by(16) {
                // SAFETY: `src + c` is inside the projection array (indices validated); a
                // prefetch never faults anyway.
                unsafe { s.prefetch(edges.p_source.as_ptr().add(src + c) as *const u8) };
            }
        }
        let lat = &mut latent[e0 * k_e..(e0 + br) * k_e];
        let none = core::ptr::null();
        let epi1 = TileEpi { bias: mlp.b1.as_ptr(), addend: buf_b.as_ptr(), relu: true, accumulate: false };
        let epi2 = TileEpi { bias: mlp.b2.as_ptr(), addend: none, relu: true, accumulate: false };
        let epi3 = TileEpi { bias: mlp.b3.as_ptr(), addend: none, relu: false, accumulate: false };
        // SAFETY: shapes validated by `Kernels::edge_mlp` (indices checked against the projection
        // rows); scratch buffers hold `EDGE_BLOCK` rows of their widths; the CPU supports `S`.
        unsafe {
            chain_layer(s, &mlp.w1_edge, lat, br, prep, wide1, buf_a, &epi1);
            chain_layer(s, &mlp.w2, buf_a, br, prep, wide2, buf_b, &epi2);
            chain_layer(s, &mlp.w3, buf_b, br, prep, wide3, buf_a, &epi3);
        }
        // LayerNorm statistics for all rows first: independent chains the core can overlap
        // (one row at a time would serialise on each row's sum -> sqrt -> divide latency).
        let mut stats = [(0.0f32, 0.0f32); EDGE_BLOCK];
        if mlp.layer_norm.is_some() {
            s.layer_norm_stats_rows(&buf_a[..br * k_e], k_e, &mut stats[..br]);
        }
        // Normalise, aggregate and add the residual in one pass over each message row.
        for (i, (m, l)) in buf_a[..br * k_e].chunks_exact(k_e).zip(lat.chunks_exact_mut(k_e)).enumerate() {
            let t = edges.target[e0 + i] as usize;
            let agg = aggregate[t * k_e..(t + 1) * k_e].iter_mut().zip(l.iter_mut());
            match &mlp.layer_norm {
                Some(ln) => {
                    let (mean, inv) = stats[i];
                    for (((a, l), v), (g, b)) in agg.zip(m).zip(ln.gamma.iter().zip(ln.beta)) {
                        let y = (*v - mean) * inv * g + b;
                        *a += y;
                        *l += y;
                    }
                }
                None => {
                    for ((a, l), v) in agg.zip(m) {
                        *a += v;
                        *l += v;
                    }
                }
            }
        }
        e0 += br;
    }
    if native_bf16 {
        s.bf16_end();
    }
}
