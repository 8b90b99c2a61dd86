//! The architecture-neutral half of the tiled paths: micro-kernels and frames written once over a
//! [`Simd`] vocabulary and instantiated by each tier: inside the `#[target_feature]` entry points
//! of the x86 tiers, and with the target's baseline features for the portable one (every
//! function here is `#[inline(always)]` so it is compiled with the caller's features).
//!
//! * The **micro-kernel** computes an `MR × (NV · LANES)` tile of `Σ x · Wᵀ` in registers: per
//!   input, `NV` weight vectors are loaded from the packed panels and each of the `MR` activation
//!   rows is broadcast once (`MR · NV` FMAs for `NV + MR` loads).
//! * The **frame** walks row blocks and column tiles, handles row tails (smaller `MR`) and the
//!   last partial panel (through a small stack tile), and applies the fused epilogue.
//! * Row passes (bf16 rounding of activations, LayerNorm, residual and aggregate adds) are plain
//!   loops that the compiler vectorises for the caller's features.

mod gemm;
mod layers;
mod rows;
// For the AMX tiles, which accumulate outside registers.
#[cfg(target_arch = "x86_64")]
pub(crate) use gemm::epilogue_row;
pub(crate) use gemm::{gemm, Ahead, SegBf16, SegF32, Segs, TileEpi};
pub(crate) use layers::{edge_mlp, linear};
#[cfg(any(test, feature = "train"))]
pub(crate) use rows::layer_norm_stats;
#[cfg(feature = "train")]
pub(crate) use rows::{lane_dot, lane_sum};
pub(crate) use rows::{
    layer_norm_apply, layer_norm_row, layer_norm_stats_rows, layer_norm_value, pack_bf16_pairs, round_bf16, widen_bf16,
};

/// The vector vocabulary a tier provides, implemented only by capability tokens: a value of the
/// implementing type exists only on a CPU with the tier's instructions (each token's constructor
/// checks), so holding `self` is the proof those instructions need. Methods that only work on
/// registers are therefore safe; methods that dereference a pointer are `unsafe` and need the
/// pointed-to elements to exist.
pub(crate) trait Simd: Copy {
    /// f32 lanes per vector.
    const LANES: usize;
    /// Panels (of [`PANEL`] columns) per widest tile.
    ///
    /// [`PANEL`]: super::PANEL
    const TILE_PANELS: usize;
    /// Prepared-activation `f32` slots per input pair: 2 (bf16-rounded f32 values) or 1 (a
    /// packed pair of bf16, as `vdpbf16ps` broadcasts it).
    const SLOTS_PER_PAIR: usize;
    /// Whether a register tile prefetches the activation rows of the tile below it, one cache
    /// line per row for each line it reads (see [`gemm`](fn@gemm)'s kernels).
    const PREFETCH_NEXT_ROWS: bool = false;
    type V: Copy;
    /// A loaded weight vector holding `LANES` columns × (even, odd) input.
    type WP: Copy;
    /// A broadcast activation pair.
    type XP: Copy;

    fn zero(self) -> Self::V;
    fn splat(self, v: f32) -> Self::V;
    /// `a · b + c` (fused on the x86 tiers, a product then a sum on the portable one).
    fn fma(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    fn add(self, a: Self::V, b: Self::V) -> Self::V;
    fn max(self, a: Self::V, b: Self::V) -> Self::V;
    /// `acc + w_even · x_even + w_odd · x_odd`, f32 accumulation.
    fn dot2(self, acc: Self::V, w: Self::WP, x: Self::XP) -> Self::V;

    /// Reads `LANES` floats at `p`.
    ///
    /// # Safety
    /// `LANES` floats are readable at `p`.
    unsafe fn load(self, p: *const f32) -> Self::V;
    /// Writes `LANES` floats at `p`.
    ///
    /// # Safety
    /// `LANES` floats are writable at `p`.
    unsafe fn store(self, p: *mut f32, v: Self::V);
    /// A hint to fetch the cache line at `p`.
    ///
    /// # Safety
    /// None beyond the call: a prefetch reads nothing and never faults, whatever the address
    /// (it is `unsafe` with the other pointer methods so that every pointer use is marked).
    unsafe fn prefetch(self, p: *const u8);
    /// Loads `LANES` columns × 2 inputs of packed bf16 weights.
    ///
    /// # Safety
    /// `2 · LANES` bf16 values are readable at `p`.
    unsafe fn load_w2(self, p: *const u16) -> Self::WP;
    /// Loads `LANES` columns of the even (`half == 0`) or odd input of packed bf16 weights,
    /// widened to f32.
    ///
    /// # Safety
    /// As [`Simd::load_w2`].
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> Self::V;
    /// Broadcasts the prepared activation pair at `p`.
    ///
    /// # Safety
    /// `SLOTS_PER_PAIR` floats are readable at `p`.
    unsafe fn bcast_x2(self, p: *const f32) -> Self::XP;

    /// [`layer_norm_stats_rows`]; a tier may override it only with the same arithmetic (its
    /// results must stay bitwise those of [`layer_norm_stats`]).
    #[inline(always)]
    fn layer_norm_stats_rows(self, y: &[f32], width: usize, stats: &mut [(f32, f32)]) {
        layer_norm_stats_rows(y, width, stats);
    }

    /// A tier's own product for bf16 operands (the AMX tiles), or `false` when the register
    /// tiles run it.
    ///
    /// # Safety
    /// Arguments and contract as [`gemm`](fn@gemm)'s; called between [`Simd::bf16_begin`] and
    /// [`Simd::bf16_end`].
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

    /// Writes the `LANES` values of `v` as [`Simd::prep_bf16`] writes them: `LANES ·
    /// SLOTS_PER_PAIR / 2` slots at `p`.
    ///
    /// # Safety
    /// Those slots are writable at `p`.
    #[inline(always)]
    unsafe fn store_prepared(self, p: *mut f32, v: Self::V) {
        let mut t = [0.0f32; 16];
        let lanes = Self::LANES.min(t.len());
        // SAFETY: `t` holds `LANES` floats (at most 16 on every tier); the caller guarantees the
        // slots at `p`.
        unsafe {
            self.store(t.as_mut_ptr(), v);
            let dst = core::slice::from_raw_parts_mut(p, lanes * Self::SLOTS_PER_PAIR / 2);
            self.prep_bf16(&t[..lanes], dst);
        }
    }

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
