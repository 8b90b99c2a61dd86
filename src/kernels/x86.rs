//! x86-64 tiers: capability tokens, their [`Simd`] vocabularies and `#[target_feature]` entry
//! points. A token is made only by its `new()` (its one field is private to this module), which
//! checks the CPU (at run time under `std`, by compile-time target features otherwise), so owning
//! one proves the instructions exist: the register-only methods of [`Simd`] are safe on that
//! proof, and the entry points' only `unsafe` is the call into the feature-enabled function.

// Without std, `has!` is a compile-time constant, and a conjunction of two can be `false && false`.
#![cfg_attr(not(feature = "std"), allow(clippy::nonminimal_bool, clippy::eq_op))]

use core::arch::x86_64::*;
use core::marker::PhantomData;

use super::amx::TileUnit;
use super::frame::{self, Simd};
use super::{EdgeInputs, EdgeMlp, Epilogue, Operand};

macro_rules! has {
    ($f:tt) => {{
        #[cfg(feature = "std")]
        {
            std::arch::is_x86_feature_detected!($f)
        }
        #[cfg(not(feature = "std"))]
        {
            cfg!(target_feature = $f)
        }
    }};
}

/// Proof that the CPU has AVX2 and FMA.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Avx2Fma(());

impl Avx2Fma {
    pub(crate) fn new() -> Option<Self> {
        (has!("avx2") && has!("fma")).then_some(Self(()))
    }
}

/// Proof that the CPU has AVX-512F (and AVX2+FMA, which every AVX-512 CPU has).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Avx512(());

impl Avx512 {
    pub(crate) fn new() -> Option<Self> {
        (Avx2Fma::new().is_some() && has!("avx512f")).then_some(Self(()))
    }
}

/// Proof that the CPU has AVX-512F and AVX-512-BF16.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx512Bf16(());

impl Avx512Bf16 {
    pub(crate) fn new() -> Option<Self> {
        (Avx512::new().is_some() && has!("avx512bf16")).then_some(Self(()))
    }
}

/// Proof that the CPU has AVX-512-BF16 and AMX-BF16, and that this process may use the tiles
/// (see [`super::amx`]). In tests `U` may be the software model of the tiles
/// (`amx::Emulator`, a test-only type), which needs only AVX-512-BF16.
pub(crate) struct AmxBf16<U = super::amx::Hardware>(Avx512Bf16, PhantomData<fn() -> U>);

// By hand: derived impls would ask the same of `U`, which is only a marker here.
impl<U> Clone for AmxBf16<U> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<U> Copy for AmxBf16<U> {}
impl<U> core::fmt::Debug for AmxBf16<U> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("AmxBf16")
    }
}

impl<U: TileUnit> AmxBf16<U> {
    pub(crate) fn new() -> Option<Self> {
        let v = Avx512Bf16::new()?;
        U::available().then_some(Self(v, PhantomData))
    }
}

/// [`frame::layer_norm_stats_rows`] in 256-bit vectors, for every x86 tier: per row the eight
/// partial sums of [`frame::lane_sum`] in one register, the same tail and the same reduction
/// tree, so the results are bitwise the portable ones. Four rows go at a time: one row's two
/// passes are each a chain of dependent additions, and one row at a time (which the compiler
/// vectorised with 128-bit shuffles) took 8 % of the bf16 edge MLP's time.
///
/// # Safety
/// The CPU has AVX (every x86 tier's token proves it).
#[inline(always)]
unsafe fn layer_norm_stats_rows_avx(y: &[f32], width: usize, stats: &mut [(f32, f32)]) {
    const R: usize = 4;
    let rows = y.len().checked_div(width).unwrap_or(0).min(stats.len());
    let full = width / 8 * 8;
    let n = width as f32;
    // Sum of one row's eight partial sums and tail, in `lane_sum`'s order.
    #[inline(always)]
    unsafe fn finish(acc: __m256, rest: f32) -> f32 {
        // SAFETY: AVX, as the caller's contract.
        unsafe {
            let s = _mm_add_ps(_mm256_castps256_ps128(acc), _mm256_extractf128_ps::<1>(acc));
            let t = _mm_add_ps(s, _mm_shuffle_ps::<0b10_11_00_01>(s, s));
            _mm_cvtss_f32(_mm_add_ss(t, _mm_movehl_ps(t, t))) + rest
        }
    }
    let mut r0 = 0;
    // SAFETY: rows `r0..r0 + R` are below `rows`, so every load reads inside `y`.
    unsafe {
        while width >= 8 && r0 + R <= rows {
            let mut p = [y.as_ptr(); R];
            for (r, p) in p.iter_mut().enumerate() {
                *p = p.add((r0 + r) * width);
            }
            let mut acc = [_mm256_setzero_ps(); R];
            for c in (0..full).step_by(8) {
                for r in 0..R {
                    acc[r] = _mm256_add_ps(acc[r], _mm256_loadu_ps(p[r].add(c)));
                }
            }
            let mut mean = [0.0f32; R];
            for r in 0..R {
                let tail = &y[(r0 + r) * width + full..(r0 + r + 1) * width];
                mean[r] = finish(acc[r], tail.iter().fold(0.0f32, |t, v| t + v)) / n;
            }
            let mut acc = [_mm256_setzero_ps(); R];
            for c in (0..full).step_by(8) {
                for r in 0..R {
                    let d = _mm256_sub_ps(_mm256_loadu_ps(p[r].add(c)), _mm256_set1_ps(mean[r]));
                    acc[r] = _mm256_add_ps(acc[r], _mm256_mul_ps(d, d));
                }
            }
            let mut var_eps = [0.0f32; R];
            for r in 0..R {
                let (m, tail) = (mean[r], &y[(r0 + r) * width + full..(r0 + r + 1) * width]);
                let var = finish(acc[r], tail.iter().fold(0.0f32, |t, v| t + (v - m) * (v - m))) / n;
                var_eps[r] = var + super::LN_EPS;
            }
            // The four square roots and divisions in one vector each: correctly rounded per
            // lane, so the same bits as the portable `1 / sqrt(var + eps)`.
            let mut inv = [0.0f32; R];
            _mm_storeu_ps(inv.as_mut_ptr(), _mm_div_ps(_mm_set1_ps(1.0), _mm_sqrt_ps(_mm_loadu_ps(var_eps.as_ptr()))));
            for r in 0..R {
                stats[r0 + r] = (mean[r], inv[r]);
            }
            r0 += R;
        }
    }
    if r0 < rows {
        frame::layer_norm_stats_rows(&y[r0 * width..rows * width], width, &mut stats[r0..rows]);
    }
}

macro_rules! ln_stats_avx {
    () => {
        #[inline(always)]
        fn layer_norm_stats_rows(self, y: &[f32], width: usize, stats: &mut [(f32, f32)]) {
            // SAFETY: the token proves AVX2, hence AVX.
            unsafe { layer_norm_stats_rows_avx(y, width, stats) }
        }
    };
}

// The methods below are called from the entry points generated by `entries!`, which run with
// the token's features enabled, so the intrinsics inline; pointers come from the frame, which
// keeps them in bounds.

// SAFETY (the `unsafe` of every register-only method of this impl: `zero`, `splat`, `fma`, `add`,
// `max`, `dot2`): AVX, AVX2 and FMA instructions on no memory. `self` is an `Avx2Fma`, which
// only `Avx2Fma::new` makes, after checking that the CPU has AVX2 and FMA (AVX2 implies AVX).
impl Simd for Avx2Fma {
    ln_stats_avx!();
    const LANES: usize = 8;
    const TILE_PANELS: usize = 1;
    // See `prefetch_next_rows`. The AVX-512 tiers, whose tiles are four panels wide and prefetch
    // their weights, go without.
    const PREFETCH_NEXT_ROWS: bool = true;
    const SLOTS_PER_PAIR: usize = 2;
    type V = __m256;
    type WP = (__m256, __m256);
    type XP = (__m256, __m256);

    #[inline(always)]
    fn zero(self) -> __m256 {
        unsafe { _mm256_setzero_ps() }
    }
    #[inline(always)]
    fn splat(self, v: f32) -> __m256 {
        unsafe { _mm256_set1_ps(v) }
    }
    #[inline(always)]
    unsafe fn load(self, p: *const f32) -> __m256 {
        // SAFETY: the caller guarantees 8 readable floats at `p`.
        unsafe { _mm256_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f32, v: __m256) {
        // SAFETY: the caller guarantees 8 writable floats at `p`.
        unsafe { _mm256_storeu_ps(p, v) }
    }
    #[inline(always)]
    fn fma(self, a: __m256, b: __m256, c: __m256) -> __m256 {
        unsafe { _mm256_fmadd_ps(a, b, c) }
    }
    #[inline(always)]
    fn add(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_add_ps(a, b) }
    }
    #[inline(always)]
    fn max(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_max_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn prefetch(self, p: *const u8) {
        // SAFETY: a prefetch never faults, whatever the address.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(p as *const i8) }
    }
    #[inline(always)]
    unsafe fn load_w2(self, p: *const u16) -> Self::WP {
        // SAFETY: the caller guarantees 16 readable bf16 at `p`; AVX2 is implied by the token.
        unsafe {
            let v = _mm256_loadu_si256(p as *const __m256i);
            let even = _mm256_castsi256_ps(_mm256_slli_epi32::<16>(v));
            let odd = _mm256_castsi256_ps(_mm256_and_si256(v, _mm256_set1_epi32(0xFFFF_0000u32 as i32)));
            (even, odd)
        }
    }
    #[inline(always)]
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> __m256 {
        // SAFETY: the caller guarantees 16 readable bf16 at `p`; AVX2 is implied by the token.
        unsafe {
            let v = _mm256_loadu_si256(p as *const __m256i);
            let v = if half == 0 { v } else { _mm256_srli_epi32::<16>(v) };
            _mm256_castsi256_ps(_mm256_slli_epi32::<16>(v))
        }
    }
    #[inline(always)]
    unsafe fn bcast_x2(self, p: *const f32) -> Self::XP {
        // SAFETY: the caller guarantees 2 readable floats at `p`.
        unsafe { (_mm256_broadcast_ss(&*p), _mm256_broadcast_ss(&*p.add(1))) }
    }
    #[inline(always)]
    fn dot2(self, acc: __m256, w: Self::WP, x: Self::XP) -> __m256 {
        unsafe { _mm256_fmadd_ps(w.1, x.1, _mm256_fmadd_ps(w.0, x.0, acc)) }
    }
}

/// The 512-bit f32 operations of the AVX-512 tiers. Each impl that uses it states why its
/// register-only methods' `unsafe` holds.
macro_rules! avx512_f32_ops {
    () => {
        const LANES: usize = 16;
        const TILE_PANELS: usize = 4;
        type V = __m512;

        #[inline(always)]
        fn zero(self) -> __m512 {
            unsafe { _mm512_setzero_ps() }
        }
        #[inline(always)]
        fn splat(self, v: f32) -> __m512 {
            unsafe { _mm512_set1_ps(v) }
        }
        #[inline(always)]
        unsafe fn load(self, p: *const f32) -> __m512 {
            // SAFETY: the caller guarantees 16 readable floats at `p`.
            unsafe { _mm512_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f32, v: __m512) {
            // SAFETY: the caller guarantees 16 writable floats at `p`.
            unsafe { _mm512_storeu_ps(p, v) }
        }
        #[inline(always)]
        fn fma(self, a: __m512, b: __m512, c: __m512) -> __m512 {
            unsafe { _mm512_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        fn add(self, a: __m512, b: __m512) -> __m512 {
            unsafe { _mm512_add_ps(a, b) }
        }
        #[inline(always)]
        fn max(self, a: __m512, b: __m512) -> __m512 {
            unsafe { _mm512_max_ps(a, b) }
        }
        #[inline(always)]
        unsafe fn prefetch(self, p: *const u8) {
            // SAFETY: a prefetch never faults, whatever the address.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p as *const i8) }
        }
    };
}

// SAFETY (the `unsafe` of every register-only method of this impl, `avx512_f32_ops!`'s included):
// AVX-512F instructions on no memory. `self` is an `Avx512`, which only `Avx512::new` makes,
// after checking that the CPU has AVX-512F (and AVX2 and FMA).
impl Simd for Avx512 {
    avx512_f32_ops!();
    ln_stats_avx!();
    const SLOTS_PER_PAIR: usize = 2;
    type WP = (__m512, __m512);
    type XP = (__m512, __m512);

    #[inline(always)]
    unsafe fn load_w2(self, p: *const u16) -> Self::WP {
        // SAFETY: the caller guarantees 32 readable bf16 at `p`; AVX-512F is implied.
        unsafe {
            let v = _mm512_loadu_si512(p as *const __m512i);
            let even = _mm512_castsi512_ps(_mm512_slli_epi32::<16>(v));
            let odd = _mm512_castsi512_ps(_mm512_and_si512(v, _mm512_set1_epi32(0xFFFF_0000u32 as i32)));
            (even, odd)
        }
    }
    #[inline(always)]
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> __m512 {
        // SAFETY: the caller guarantees 32 readable bf16 at `p`; AVX-512F is implied.
        unsafe {
            let v = _mm512_loadu_si512(p as *const __m512i);
            let v = if half == 0 { v } else { _mm512_srli_epi32::<16>(v) };
            _mm512_castsi512_ps(_mm512_slli_epi32::<16>(v))
        }
    }
    #[inline(always)]
    unsafe fn bcast_x2(self, p: *const f32) -> Self::XP {
        // SAFETY: the caller guarantees 2 readable floats at `p`.
        unsafe { (_mm512_set1_ps(*p), _mm512_set1_ps(*p.add(1))) }
    }
    #[inline(always)]
    fn dot2(self, acc: __m512, w: Self::WP, x: Self::XP) -> __m512 {
        unsafe { _mm512_fmadd_ps(w.1, x.1, _mm512_fmadd_ps(w.0, x.0, acc)) }
    }
}

/// What the AVX-512-BF16 tiers share: the 512-bit f32 operations, the LayerNorm statistics and
/// packed bf16 pairs as `__m512bh`.
macro_rules! avx512_bf16_vocabulary {
    () => {
        avx512_f32_ops!();
        ln_stats_avx!();
        const SLOTS_PER_PAIR: usize = 1;
        type WP = __m512bh;
        type XP = __m512bh;
    };
}

// SAFETY (the `unsafe` of every register-only method of this impl, the macros' included):
// AVX-512F and AVX-512-BF16 instructions on no memory. `self` is an `Avx512Bf16`, which only
// `Avx512Bf16::new` makes, after checking that the CPU has both.
impl Simd for Avx512Bf16 {
    avx512_bf16_vocabulary!();

    #[inline(always)]
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> __m512 {
        // SAFETY: the caller guarantees 32 readable bf16 at `p`; AVX-512F is implied by the token.
        unsafe {
            let v = _mm512_loadu_si512(p as *const __m512i);
            let v = if half == 0 { v } else { _mm512_srli_epi32::<16>(v) };
            _mm512_castsi512_ps(_mm512_slli_epi32::<16>(v))
        }
    }
    #[inline(always)]
    unsafe fn load_w2(self, p: *const u16) -> __m512bh {
        // SAFETY: the caller guarantees 32 readable bf16 at `p`. `__m512i` and `__m512bh` are
        // both plain 64-byte vectors, so the transmute only renames the lanes.
        unsafe { core::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(p as *const __m512i)) }
    }
    #[inline(always)]
    unsafe fn bcast_x2(self, p: *const f32) -> __m512bh {
        // SAFETY: the caller guarantees one readable slot (a packed bf16 pair) at `p`; the
        // transmute is a lane rename as above.
        unsafe { core::mem::transmute::<__m512i, __m512bh>(_mm512_set1_epi32((*p).to_bits() as i32)) }
    }
    #[inline(always)]
    fn dot2(self, acc: __m512, w: __m512bh, x: __m512bh) -> __m512 {
        unsafe { _mm512_dpbf16_ps(acc, w, x) }
    }

    #[inline(always)]
    unsafe fn store_prepared(self, p: *mut f32, v: __m512) {
        // SAFETY: the caller guarantees 8 writable slots at `p`; the transmute is a lane rename.
        unsafe {
            let packed: __m256i = core::mem::transmute::<__m256bh, __m256i>(_mm512_cvtneps_pbh(v));
            _mm256_storeu_si256(p as *mut __m256i, packed);
        }
    }

    /// `vcvtneps2bf16` turns 16 inputs into 8 pair slots in one instruction (the portable
    /// pairing took a fifth of the bf16 edge MLP's time). It rounds to nearest even like
    /// [`frame::round_bf16`], but flushes subnormal inputs (below 1.2e-38 in magnitude) to zero.
    #[inline(always)]
    fn prep_bf16(self, src: &[f32], dst: &mut [f32]) {
        let blocks = (src.len() / 16).min(dst.len() / 8);
        for b in 0..blocks {
            // SAFETY: the token proves AVX-512F and AVX-512-BF16; block `b` reads floats
            // `16b..16b + 16` of `src` and writes slots `8b..8b + 8` of `dst`, both in bounds.
            unsafe { self.store_prepared(dst.as_mut_ptr().add(8 * b), _mm512_loadu_ps(src.as_ptr().add(16 * b))) };
        }
        frame::pack_bf16_pairs(&src[16 * blocks..], &mut dst[8 * blocks..]);
    }
}

/// The AVX-512-BF16 vocabulary, with bf16 products on the tile unit.
// SAFETY (the `unsafe` of the register-only methods of `avx512_bf16_vocabulary!`): as for
// `Avx512Bf16`, which an `AmxBf16` holds (only `AmxBf16::new` makes one, from an `Avx512Bf16`).
impl<U: TileUnit> Simd for AmxBf16<U> {
    avx512_bf16_vocabulary!();

    #[inline(always)]
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> __m512 {
        // SAFETY: forwarded contract; the token holds the AVX-512-BF16 one.
        unsafe { self.0.load_w_half(p, half) }
    }
    #[inline(always)]
    unsafe fn load_w2(self, p: *const u16) -> __m512bh {
        // SAFETY: as above.
        unsafe { self.0.load_w2(p) }
    }
    #[inline(always)]
    unsafe fn bcast_x2(self, p: *const f32) -> __m512bh {
        // SAFETY: as above.
        unsafe { self.0.bcast_x2(p) }
    }
    #[inline(always)]
    fn dot2(self, acc: __m512, w: __m512bh, x: __m512bh) -> __m512 {
        self.0.dot2(acc, w, x)
    }
    #[inline(always)]
    unsafe fn store_prepared(self, p: *mut f32, v: __m512) {
        // SAFETY: forwarded contract; the token holds the AVX-512-BF16 one.
        unsafe { self.0.store_prepared(p, v) }
    }
    #[inline(always)]
    fn prep_bf16(self, src: &[f32], dst: &mut [f32]) {
        self.0.prep_bf16(src, dst)
    }
    #[inline(always)]
    unsafe fn gemm_bf16(
        self,
        segs: &[frame::SegBf16],
        rows: usize,
        n: usize,
        out: *mut f32,
        ldo: usize,
        epi: &frame::TileEpi,
    ) -> bool {
        // SAFETY: forwarded contract of `frame::gemm`; the token proves the tile unit usable
        // (`U::available`) and the frame set it up on this thread (`bf16_begin`).
        unsafe { super::amx::gemm::<_, U>(self.0, segs, rows, n, out, ldo, epi) };
        true
    }
    #[inline(always)]
    fn bf16_begin(self) {
        // SAFETY: the token proves the unit usable in this process.
        unsafe { U::configure() }
    }
    #[inline(always)]
    fn bf16_end(self) {
        // SAFETY: as above.
        unsafe { U::release() }
    }
}

macro_rules! entries {
    ($tok:ty, $feat:literal) => {
        impl $tok {
            pub(crate) fn linear(
                self,
                ops: &[Operand<'_>],
                bias: Option<&[f32]>,
                epi: &Epilogue<'_>,
                out: &mut [f32],
                scratch: &mut [f32],
            ) {
                #[target_feature(enable = $feat)]
                unsafe fn imp(
                    s: $tok,
                    ops: &[Operand<'_>],
                    bias: Option<&[f32]>,
                    epi: &Epilogue<'_>,
                    out: &mut [f32],
                    scratch: &mut [f32],
                ) {
                    // SAFETY: forwarded contract (features present, arguments validated).
                    unsafe { frame::linear(s, ops, bias, epi, out, scratch) }
                }
                // SAFETY: `self` exists only if the CPU has these features (checked in `new`);
                // `Kernels::linear` validated every shape.
                unsafe { imp(self, ops, bias, epi, out, scratch) }
            }

            pub(crate) fn edge_mlp(
                self,
                mlp: &EdgeMlp<'_>,
                edges: &EdgeInputs<'_>,
                latent: &mut [f32],
                aggregate: &mut [f32],
                scratch: &mut [f32],
            ) {
                #[target_feature(enable = $feat)]
                unsafe fn imp(
                    s: $tok,
                    mlp: &EdgeMlp<'_>,
                    edges: &EdgeInputs<'_>,
                    latent: &mut [f32],
                    aggregate: &mut [f32],
                    scratch: &mut [f32],
                ) {
                    // SAFETY: forwarded contract (features present, arguments validated).
                    unsafe { frame::edge_mlp(s, mlp, edges, latent, aggregate, scratch) }
                }
                // SAFETY: `self` exists only if the CPU has these features (checked in `new`);
                // `Kernels::edge_mlp` validated every shape and index.
                unsafe { imp(self, mlp, edges, latent, aggregate, scratch) }
            }
        }
    };
}

entries!(Avx2Fma, "avx2,fma");
entries!(Avx512, "avx2,fma,avx512f");
entries!(Avx512Bf16, "avx2,fma,avx512f,avx512bf16");
entries!(AmxBf16, "avx2,fma,avx512f,avx512bf16");
#[cfg(test)]
entries!(AmxBf16<super::amx::Emulator>, "avx2,fma,avx512f,avx512bf16");

/// Throughput loops for [`super::peak`]: `iters` rounds of 12 independent accumulator chains.
/// Returns a value depending on every chain so the work cannot be elided.
#[cfg(feature = "tools")]
pub(crate) mod peak_loops {
    use super::*;

    const CHAINS: usize = 12;

    /// f32 FMAs on 256-bit vectors: `iters · 12 · 8 · 2` FLOPs.
    pub(crate) fn fma_avx2(_t: Avx2Fma, iters: usize, a: f32, b: f32) -> f32 {
        #[target_feature(enable = "avx2,fma")]
        fn imp(iters: usize, a: f32, b: f32) -> f32 {
            let (va, vb) = (_mm256_set1_ps(a), _mm256_set1_ps(b));
            let mut acc: [__m256; CHAINS] = core::array::from_fn(|i| _mm256_set1_ps(i as f32));
            for _ in 0..iters {
                for c in acc.iter_mut() {
                    *c = _mm256_fmadd_ps(*c, va, vb);
                }
            }
            let mut s = _mm256_setzero_ps();
            for c in acc {
                s = _mm256_add_ps(s, c);
            }
            let mut lanes = [0.0f32; 8];
            // SAFETY: `lanes` holds 8 floats.
            unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), s) };
            lanes.iter().sum()
        }
        // SAFETY: the token proves AVX2 and FMA.
        unsafe { imp(iters, a, b) }
    }

    /// f32 FMAs on 512-bit vectors: `iters · 12 · 16 · 2` FLOPs.
    pub(crate) fn fma_avx512(_t: Avx512, iters: usize, a: f32, b: f32) -> f32 {
        #[target_feature(enable = "avx512f")]
        fn imp(iters: usize, a: f32, b: f32) -> f32 {
            let (va, vb) = (_mm512_set1_ps(a), _mm512_set1_ps(b));
            let mut acc: [__m512; CHAINS] = core::array::from_fn(|i| _mm512_set1_ps(i as f32));
            for _ in 0..iters {
                for c in acc.iter_mut() {
                    *c = _mm512_fmadd_ps(*c, va, vb);
                }
            }
            let mut s = _mm512_setzero_ps();
            for c in acc {
                s = _mm512_add_ps(s, c);
            }
            _mm512_reduce_add_ps(s)
        }
        // SAFETY: the token proves AVX-512F.
        unsafe { imp(iters, a, b) }
    }

    /// bf16 dot products: `iters · 12 · 16 · 4` FLOPs (two multiply-adds per lane).
    pub(crate) fn dpbf16(_t: Avx512Bf16, iters: usize, a: f32, b: f32) -> f32 {
        #[target_feature(enable = "avx512f,avx512bf16")]
        fn imp(iters: usize, a: f32, b: f32) -> f32 {
            let va = _mm512_cvtne2ps_pbh(_mm512_set1_ps(a), _mm512_set1_ps(a));
            let vb = _mm512_cvtne2ps_pbh(_mm512_set1_ps(b), _mm512_set1_ps(b));
            let mut acc: [__m512; CHAINS] = core::array::from_fn(|i| _mm512_set1_ps(i as f32));
            for _ in 0..iters {
                for c in acc.iter_mut() {
                    *c = _mm512_dpbf16_ps(*c, va, vb);
                }
            }
            let mut s = _mm512_setzero_ps();
            for c in acc {
                s = _mm512_add_ps(s, c);
            }
            _mm512_reduce_add_ps(s)
        }
        // SAFETY: the token proves AVX-512F and AVX-512-BF16.
        unsafe { imp(iters, a, b) }
    }
}
