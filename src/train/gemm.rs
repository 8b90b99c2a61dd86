//! The trainer's f32 matrix products on strided row-major operands: `C += A·B` (forward
//! products against transposed weights, and `dX = dY·W` in the backward) and `C += Aᵀ·B`
//! (weight gradients `dW += dYᵀ·X`). AVX-512 and AVX2+FMA paths chosen at run time (by
//! [`crate::kernels::Kernels::best`], so `HOOD_KERNEL_TIER` caps them too), written once over the
//! kernels' vector vocabulary, and a scalar twin.
//!
//! Every output element is one chain of fused multiply-adds in a fixed order whatever the row
//! position and the vector width (a tile of six rows and a tail tile of fewer, a 512-bit and a
//! 256-bit vector, run the same chain), so splitting rows between threads never changes a result
//! and the two SIMD paths agree bitwise. Column remainders run masked vectors (the same fused
//! multiply-adds as the full vectors), not scalar loops: the narrow inputs of the encoders (3 to
//! 14 features) made those loops a visible share of a training step.
//!
//! Where the CPU has AMX, a third path runs the forward and input-gradient products on the
//! tiles in split bf16 (`amx`: about f32's precision), chosen only where it is measured faster
//! than the f32 path ([`Gemm::best`]); its weight gradients, and products too small for whole
//! tiles, stay on the f32 path.

use crate::kernels::{Kernels, Tier};

#[cfg(target_arch = "x86_64")]
mod amx;

/// A chosen product path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gemm {
    path: Path,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Path {
    Scalar,
    #[cfg(target_arch = "x86_64")]
    Avx2(crate::kernels::Avx2Fma),
    #[cfg(target_arch = "x86_64")]
    Avx512(crate::kernels::Avx512),
    /// Split bf16 on the tile unit (made only where AMX is usable).
    #[cfg(target_arch = "x86_64")]
    Amx,
    /// Split bf16 on the software model of the tiles (any x86-64 CPU; slow).
    #[cfg(target_arch = "x86_64")]
    AmxModel,
}

/// What a product [`Gemm::nn_out`] does with `C` (the epilogue of each output tile: fusing it
/// saves a separate pass, and a call to `memcpy` or `memset` per row, at small widths).
#[derive(Clone, Copy, Debug)]
pub enum Out<'a> {
    /// `C += A·B`.
    Add,
    /// `C = A·B`.
    Set,
    /// `C = bias + A·B`, `bias` per column.
    Bias(&'a [f32]),
    /// `C = max(bias + A·B, 0)`: a hidden layer with its ReLU.
    BiasRelu(&'a [f32]),
}

impl Out<'_> {
    /// The epilogue of one output element (the scalar twin of the SIMD tiles').
    #[inline(always)]
    fn apply(&self, c: &mut f32, j: usize, acc: f32) {
        *c = match self {
            Out::Add => *c + acc,
            Out::Set => acc,
            Out::Bias(b) => b[j] + acc,
            Out::BiasRelu(b) => (b[j] + acc).max(0.0),
        };
    }
}

/// A strided row-major matrix operand: element `(r, c)` at `data[r * ld + c]`.
#[derive(Clone, Copy, Debug)]
pub struct Mat<'a> {
    /// Elements.
    pub data: &'a [f32],
    /// Row stride.
    pub ld: usize,
}

fn needed(rows: usize, cols: usize, ld: usize) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * ld + cols
    }
}

impl Gemm {
    /// The best path for this CPU within the tier f32 runs on ([`Kernels::best_f32`]: AVX-512
    /// unless AVX2 measured faster, under any tier cap).
    ///
    /// Where AMX is usable, the split-bf16 tile path instead if a tier cap asks for it
    /// (`HOOD_KERNEL_TIER=amx`) or, without a cap, if it is measured faster than that f32 path
    /// by [`SWITCH_MARGIN`](crate::kernels::SWITCH_MARGIN) ([`Gemm::tile_choice`]).
    pub fn best() -> Gemm {
        let f32_path = Gemm::at_most(Kernels::best_f32().tier());
        #[cfg(target_arch = "x86_64")]
        if let Some(choice) = Gemm::tile_choice() {
            if choice.chosen {
                return Gemm { path: Path::Amx };
            }
        }
        f32_path
    }

    /// Whether the split-bf16 tile path runs the trainer's products, and why: `None` where AMX
    /// is not usable in this process. Measured once per process (six runs of one forward
    /// product on each path). The tiles, though the more capable path, must win by the margin:
    /// their sums round differently from the f32 paths', so a close call keeps f32.
    #[cfg(target_arch = "x86_64")]
    pub fn tile_choice() -> Option<TileChoice> {
        let tiles = Gemm::tiles()?;
        if let Some(cap) = crate::kernels::tier_cap() {
            return Some(TileChoice { chosen: cap >= Tier::Amx, timing: None });
        }
        static MEASURED: std::sync::OnceLock<TileChoice> = std::sync::OnceLock::new();
        Some(*MEASURED.get_or_init(|| {
            let f32_path = Gemm::at_most(Kernels::best_f32().tier());
            let (tiles_us, f32_us) = (calibration_us(tiles), calibration_us(f32_path));
            let chosen = tiles_us * crate::kernels::SWITCH_MARGIN < f32_us;
            TileChoice { chosen, timing: Some((tiles_us, f32_us)) }
        }))
    }

    /// The split-bf16 tile path, where AMX is usable in this process (whether or not
    /// [`Gemm::best`] chooses it).
    #[cfg(target_arch = "x86_64")]
    pub fn tiles() -> Option<Gemm> {
        use crate::kernels::{AmxBf16, TileHardware};
        AmxBf16::<TileHardware>::new().map(|_| Gemm { path: Path::Amx })
    }

    /// The split-bf16 tile path with the tiles modelled in software: the AMX path's packing,
    /// tiling and precision on any x86-64 CPU, for tests (far slower than any other path).
    #[cfg(target_arch = "x86_64")]
    pub fn tile_model() -> Gemm {
        Gemm { path: Path::AmxModel }
    }

    /// The best path on this CPU at or below `tier` (AVX-512 for the AVX-512 tiers and above,
    /// AVX2+FMA for [`Tier::Avx2Fma`], scalar below).
    pub fn at_most(tier: Tier) -> Gemm {
        #[cfg(target_arch = "x86_64")]
        {
            use crate::kernels::{Avx2Fma, Avx512};
            if tier >= Tier::Avx512 {
                if let Some(t) = Avx512::new() {
                    return Gemm { path: Path::Avx512(t) };
                }
            }
            if tier >= Tier::Avx2Fma {
                if let Some(t) = Avx2Fma::new() {
                    return Gemm { path: Path::Avx2(t) };
                }
            }
        }
        let _ = tier;
        Gemm::scalar()
    }

    /// The scalar reference.
    pub fn scalar() -> Gemm {
        Gemm { path: Path::Scalar }
    }

    /// True for any path but the scalar reference (the SIMD paths, the tiles and their model).
    pub fn is_simd(&self) -> bool {
        self.path != Path::Scalar
    }

    /// The tier of the path: [`Tier::Scalar`], [`Tier::Avx2Fma`], [`Tier::Avx512`], or
    /// [`Tier::Amx`] for the tiles (and their model).
    pub fn tier(&self) -> Tier {
        match self.path {
            Path::Scalar => Tier::Scalar,
            #[cfg(target_arch = "x86_64")]
            Path::Avx2(_) => Tier::Avx2Fma,
            #[cfg(target_arch = "x86_64")]
            Path::Avx512(_) => Tier::Avx512,
            #[cfg(target_arch = "x86_64")]
            Path::Amx | Path::AmxModel => Tier::Amx,
        }
    }

    /// `C[m×n] += A[m×k] · B[k×n]`.
    ///
    /// # Panics
    /// When an operand is shorter than its shape and stride need (a caller bug).
    #[allow(clippy::too_many_arguments)] // BLAS-style: three sizes, three operands, a stride
    pub fn nn(&self, m: usize, n: usize, k: usize, a: Mat<'_>, b: Mat<'_>, c: &mut [f32], ldc: usize) {
        self.nn_out(m, n, k, a, b, Out::Add, c, ldc);
    }

    /// `C[m×n] (op)= A[m×k] · B[k×n]` with the epilogue `out`.
    ///
    /// # Panics
    /// When an operand is shorter than its shape and stride need, or a bias shorter than `n`
    /// (a caller bug).
    #[allow(clippy::too_many_arguments)] // BLAS-style: three sizes, three operands, a stride
    pub fn nn_out(
        &self,
        m: usize,
        n: usize,
        k: usize,
        a: Mat<'_>,
        b: Mat<'_>,
        out: Out<'_>,
        c: &mut [f32],
        ldc: usize,
    ) {
        if let Out::Bias(bias) | Out::BiasRelu(bias) = out {
            assert!(bias.len() >= n, "gemm nn bias too short");
        }
        assert!(
            a.data.len() >= needed(m, k, a.ld) && b.data.len() >= needed(k, n, b.ld) && c.len() >= needed(m, n, ldc),
            "gemm nn operands too short"
        );
        assert!(a.ld >= k && b.ld >= n && ldc >= n, "gemm nn strides");
        if m == 0 || n == 0 {
            return;
        }
        match self.path {
            // SAFETY (both): the token proves the instructions; the asserts above bound every
            // index the kernel reads or writes.
            #[cfg(target_arch = "x86_64")]
            Path::Avx2(t) => return unsafe { entry::nn_avx2(t, m, n, k, a, b, out, c, ldc) },
            #[cfg(target_arch = "x86_64")]
            Path::Avx512(t) => return unsafe { entry::nn_avx512(t, m, n, k, a, b, out, c, ldc) },
            // Products smaller than a whole tile (the encoders' 3 to 14 inputs, the decoder's 3
            // outputs) would be mostly padding there: they stay on the f32 path.
            #[cfg(target_arch = "x86_64")]
            Path::Amx | Path::AmxModel if k < amx::MIN_INPUTS || n < amx::MIN_COLUMNS => {
                return Gemm::at_most(Tier::Avx512).nn_out(m, n, k, a, b, out, c, ldc)
            }
            // SAFETY (both): `Path::Amx` is made only where the tiles are usable; the model
            // needs nothing of the CPU; the asserts above bound the operands.
            #[cfg(target_arch = "x86_64")]
            Path::Amx => return unsafe { amx::nn::<crate::kernels::TileHardware>(m, n, k, a, b, out, c, ldc) },
            #[cfg(target_arch = "x86_64")]
            Path::AmxModel => return unsafe { amx::nn::<crate::kernels::TileModel>(m, n, k, a, b, out, c, ldc) },
            Path::Scalar => {}
        }
        for r in 0..m {
            for j in 0..n {
                let mut acc = 0.0f32;
                for kk in 0..k {
                    acc += a.data[r * a.ld + kk] * b.data[kk * b.ld + j];
                }
                out.apply(&mut c[r * ldc + j], j, acc);
            }
        }
    }

    /// `C[ka×n] += Aᵀ · B` with `A` `m × ka` and `B` `m × n` (a sum over the `m` rows).
    ///
    /// # Panics
    /// When an operand is shorter than its shape and stride need (a caller bug).
    #[allow(clippy::too_many_arguments)] // BLAS-style: three sizes, three operands, a stride
    pub fn tn(&self, m: usize, ka: usize, n: usize, a: Mat<'_>, b: Mat<'_>, c: &mut [f32], ldc: usize) {
        assert!(
            a.data.len() >= needed(m, ka, a.ld) && b.data.len() >= needed(m, n, b.ld) && c.len() >= needed(ka, n, ldc),
            "gemm tn operands too short"
        );
        assert!(a.ld >= ka && b.ld >= n && ldc >= n, "gemm tn strides");
        if m == 0 || n == 0 || ka == 0 {
            return;
        }
        match self.path {
            // SAFETY (both): as in `nn_out`.
            #[cfg(target_arch = "x86_64")]
            Path::Avx2(t) => return unsafe { entry::tn_avx2(t, m, ka, n, a, b, c, ldc) },
            #[cfg(target_arch = "x86_64")]
            Path::Avx512(t) => return unsafe { entry::tn_avx512(t, m, ka, n, a, b, c, ldc) },
            // The weight gradients stay on the f32 FMAs (see `amx`).
            #[cfg(target_arch = "x86_64")]
            Path::Amx | Path::AmxModel => return Gemm::at_most(Tier::Avx512).tn(m, ka, n, a, b, c, ldc),
            Path::Scalar => {}
        }
        for o in 0..ka {
            for j in 0..n {
                let mut acc = 0.0f32;
                for r in 0..m {
                    acc += a.data[r * a.ld + o] * b.data[r * b.ld + j];
                }
                c[o * ldc + j] += acc;
            }
        }
    }
}

/// Whether the trainer's products run on the AMX tiles in split bf16 ([`Gemm::tile_choice`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileChoice {
    /// The tile path runs them.
    pub chosen: bool,
    /// Best-of-runs microseconds of the calibration products on the tiles and on the f32 path;
    /// `None` where a tier cap decided.
    pub timing: Option<(f64, f64)>,
}

impl TileChoice {
    /// One line for people: what runs and why.
    pub fn describe(&self) -> std::string::String {
        let what = if self.chosen { "on the AMX tiles in split bf16" } else { "in f32, not on the AMX tiles" };
        match self.timing {
            None => std::format!("products {what}: the tier cap (HOOD_KERNEL_TIER)"),
            Some((tiles, f32_us)) => std::format!(
                "products {what}: measured tiles {tiles:.0} us, f32 {f32_us:.0} us (the tiles must win by {}x)",
                crate::kernels::SWITCH_MARGIN
            ),
        }
    }
}

/// Best of five runs of a forward product of a training step's shape (2,048 rows, h = 64) on
/// `g`, microseconds (the products the tiles run: [`Gemm::nn_out`]).
#[cfg(target_arch = "x86_64")]
fn calibration_us(g: Gemm) -> f64 {
    const ROWS: usize = 2048;
    const H: usize = 64;
    let x: alloc::vec::Vec<f32> = (0..ROWS * H).map(|i| ((i * 7919 % 1000) as f32 - 500.0) * 1e-3).collect();
    let w: alloc::vec::Vec<f32> = (0..H * H).map(|i| ((i * 104_729 % 1000) as f32 - 500.0) * 1e-4).collect();
    let mut y = alloc::vec![0.0f32; ROWS * H];
    let mut best = f64::INFINITY;
    for run in 0..6 {
        let t = std::time::Instant::now();
        g.nn_out(ROWS, H, H, Mat { data: &x, ld: H }, Mat { data: &w, ld: H }, Out::Set, &mut y, H);
        let us = t.elapsed().as_secs_f64() * 1e6;
        if run > 0 {
            best = best.min(us);
        }
    }
    best
}

/// The register tiles, generic over the vector width.
#[cfg(target_arch = "x86_64")]
mod tiles {
    use super::{Mat, Out};
    use crate::kernels::{Avx2Fma, Avx512, Simd};
    use core::arch::x86_64::*;

    /// The kernels' vector vocabulary plus the masked partial vectors of column remainders.
    pub(super) trait Partial: Simd {
        /// Reads the first `cols` (1 to `LANES - 1`) floats at `p`; the other lanes are 0 and
        /// their memory is not touched.
        ///
        /// # Safety
        /// `cols` floats are readable at `p`.
        unsafe fn load_part(self, p: *const f32, cols: usize) -> Self::V;
        /// Writes the first `cols` (1 to `LANES - 1`) lanes of `v` at `p`, nothing after them.
        ///
        /// # Safety
        /// `cols` floats are writable at `p`.
        unsafe fn store_part(self, p: *mut f32, cols: usize, v: Self::V);
    }

    /// The lanes below `cols` of a 256-bit vector set.
    #[inline(always)]
    fn lanes8(_t: Avx2Fma, cols: usize) -> __m256i {
        // SAFETY: AVX2 integer operations on no memory; the token proves AVX2.
        unsafe { _mm256_cmpgt_epi32(_mm256_set1_epi32(cols as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)) }
    }

    impl Partial for Avx2Fma {
        #[inline(always)]
        unsafe fn load_part(self, p: *const f32, cols: usize) -> __m256 {
            // SAFETY: the masked load reads only the lanes below `cols` (caller: readable); the
            // token proves AVX2.
            unsafe { _mm256_maskload_ps(p, lanes8(self, cols)) }
        }
        #[inline(always)]
        unsafe fn store_part(self, p: *mut f32, cols: usize, v: __m256) {
            // SAFETY: the masked store writes only the lanes below `cols` (caller: writable).
            unsafe { _mm256_maskstore_ps(p, lanes8(self, cols), v) }
        }
    }

    impl Partial for Avx512 {
        #[inline(always)]
        unsafe fn load_part(self, p: *const f32, cols: usize) -> __m512 {
            // SAFETY: the masked load reads only the lanes below `cols` (caller: readable); the
            // token proves AVX-512F.
            unsafe { _mm512_maskz_loadu_ps(((1u32 << cols) - 1) as __mmask16, p) }
        }
        #[inline(always)]
        unsafe fn store_part(self, p: *mut f32, cols: usize, v: __m512) {
            // SAFETY: the masked store writes only the lanes below `cols` (caller: writable).
            unsafe { _mm512_mask_storeu_ps(p, ((1u32 << cols) - 1) as __mmask16, v) }
        }
    }

    /// Rows of `B` streamed per pass of [`tn`] (keeps a strip of columns in L1).
    const TN_ROWS: usize = 128;

    /// Row tile height: six rows, with at most four vectors of columns (24 accumulators) on
    /// 32-register AVX-512 and two (12) on 16-register AVX2.
    const ROWS: usize = 6;

    /// `LANES` floats at `p`, or with `M` only the first `cols` (the others read as 0).
    #[inline(always)]
    unsafe fn load<S: Partial, const M: bool>(s: S, p: *const f32, cols: usize) -> S::V {
        // SAFETY: `p` addresses `LANES` valid elements, or (masked) `cols` (caller).
        unsafe {
            if M {
                s.load_part(p, cols)
            } else {
                s.load(p)
            }
        }
    }

    /// The epilogue of a tile's vector `x` into `p`, bias vector at `bias` (see [`Out`]); with
    /// `M`, only the first `cols` lanes are read and written.
    #[inline(always)]
    unsafe fn store<S: Partial, const M: bool>(
        s: S,
        out: Out<'_>,
        p: *mut f32,
        bias: *const f32,
        x: S::V,
        cols: usize,
    ) {
        // SAFETY: `p` and (for the bias forms) `bias` address the lanes used (caller).
        unsafe {
            let v = match out {
                Out::Add => s.add(load::<S, M>(s, p, cols), x),
                Out::Set => x,
                Out::Bias(_) => s.add(load::<S, M>(s, bias, cols), x),
                Out::BiasRelu(_) => s.max(s.add(load::<S, M>(s, bias, cols), x), s.zero()),
            };
            if M {
                s.store_part(p, cols, v);
            } else {
                s.store(p, v);
            }
        }
    }

    /// One tile of `C (op)= A·B`: `R` rows (1..=6) × `V` vectors of columns at column `j`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn nn_tile<S: Partial, const R: usize, const V: usize, const M: bool>(
        s: S,
        k: usize,
        (a, lda): (*const f32, usize),
        (b, ldb): (*const f32, usize),
        out: Out<'_>,
        j: usize,
        (c, ldc): (*mut f32, usize),
        cols: usize,
    ) {
        // SAFETY (whole body): the caller passes pointers to the tile's first elements with
        // `R` rows of `k` (A), `k` rows of `V · LANES` (B) and `R` rows of `V · LANES` (C) in
        // bounds (with `M`, V = 1 and only the first `cols` lanes).
        unsafe {
            let mut acc = [[s.zero(); V]; R];
            for kk in 0..k {
                let mut bv = [s.zero(); V];
                for (v, x) in bv.iter_mut().enumerate() {
                    *x = load::<S, M>(s, b.add(kk * ldb + S::LANES * v), cols);
                }
                for (i, row) in acc.iter_mut().enumerate() {
                    let av = s.splat(*a.add(i * lda + kk));
                    for (x, &w) in row.iter_mut().zip(&bv) {
                        *x = s.fma(av, w, *x);
                    }
                }
            }
            let bias = match out {
                Out::Bias(b) | Out::BiasRelu(b) => b.as_ptr().add(j),
                _ => core::ptr::null(),
            };
            for (i, row) in acc.iter().enumerate() {
                for (v, x) in row.iter().enumerate() {
                    let o = S::LANES * v;
                    store::<S, M>(s, out, c.add(i * ldc + o), bias.wrapping_add(o), *x, cols);
                }
            }
        }
    }

    /// Rows `r..r + R` of `C (op)= A·B`, the widest tiles first.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn nn_rows<S: Partial, const R: usize>(
        s: S,
        n: usize,
        k: usize,
        a: Mat<'_>,
        b: Mat<'_>,
        out: Out<'_>,
        c: *mut f32,
        ldc: usize,
        r: usize,
    ) {
        // SAFETY: rows r..r+R exist (caller), columns stay below n; the bounds were checked by
        // `Gemm::nn_out`.
        unsafe {
            let a = (a.data.as_ptr().add(r * a.ld), a.ld);
            let (bp, cp, w) = (b.data.as_ptr(), c.add(r * ldc), S::LANES);
            let mut j = 0;
            if w >= 16 {
                while j + 4 * w <= n {
                    nn_tile::<S, R, 4, false>(s, k, a, (bp.add(j), b.ld), out, j, (cp.add(j), ldc), w);
                    j += 4 * w;
                }
                if j + 2 * w <= n {
                    nn_tile::<S, R, 2, false>(s, k, a, (bp.add(j), b.ld), out, j, (cp.add(j), ldc), w);
                    j += 2 * w;
                }
            } else {
                while j + 2 * w <= n {
                    nn_tile::<S, R, 2, false>(s, k, a, (bp.add(j), b.ld), out, j, (cp.add(j), ldc), w);
                    j += 2 * w;
                }
            }
            if j + w <= n {
                nn_tile::<S, R, 1, false>(s, k, a, (bp.add(j), b.ld), out, j, (cp.add(j), ldc), w);
                j += w;
            }
            if j < n {
                nn_tile::<S, R, 1, true>(s, k, a, (bp.add(j), b.ld), out, j, (cp.add(j), ldc), n - j);
            }
        }
    }

    /// `C (op)= A·B` (see [`super::Gemm::nn_out`]).
    ///
    /// # Safety
    /// The operands hold their shapes and strides (checked by the caller); the CPU has the
    /// instructions of `S` and the calling function enables them.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn nn<S: Partial>(
        s: S,
        m: usize,
        n: usize,
        k: usize,
        a: Mat<'_>,
        b: Mat<'_>,
        out: Out<'_>,
        c: &mut [f32],
        ldc: usize,
    ) {
        let cp = c.as_mut_ptr();
        let mut r = 0;
        // SAFETY: as the contract above.
        unsafe {
            while r + ROWS <= m {
                nn_rows::<S, ROWS>(s, n, k, a, b, out, cp, ldc, r);
                r += ROWS;
            }
            match m - r {
                5 => nn_rows::<S, 5>(s, n, k, a, b, out, cp, ldc, r),
                4 => nn_rows::<S, 4>(s, n, k, a, b, out, cp, ldc, r),
                3 => nn_rows::<S, 3>(s, n, k, a, b, out, cp, ldc, r),
                2 => nn_rows::<S, 2>(s, n, k, a, b, out, cp, ldc, r),
                1 => nn_rows::<S, 1>(s, n, k, a, b, out, cp, ldc, r),
                _ => {}
            }
        }
    }

    /// One tile of `C += Aᵀ·B` over rows `rows`: `R` outputs (A columns) × `V` vectors.
    #[inline(always)]
    unsafe fn tn_tile<S: Partial, const R: usize, const V: usize, const M: bool>(
        s: S,
        rows: core::ops::Range<usize>,
        (a, lda): (*const f32, usize),
        (b, ldb): (*const f32, usize),
        (c, ldc): (*mut f32, usize),
        cols: usize,
    ) {
        // SAFETY (whole body): pointers at the tile's first column/row; rows in bounds (with
        // `M`, V = 1 and only the first `cols` lanes).
        unsafe {
            let mut acc = [[s.zero(); V]; R];
            for r in rows {
                let mut bv = [s.zero(); V];
                for (v, x) in bv.iter_mut().enumerate() {
                    *x = load::<S, M>(s, b.add(r * ldb + S::LANES * v), cols);
                }
                for (i, row) in acc.iter_mut().enumerate() {
                    let av = s.splat(*a.add(r * lda + i));
                    for (x, &w) in row.iter_mut().zip(&bv) {
                        *x = s.fma(av, w, *x);
                    }
                }
            }
            for (i, row) in acc.iter().enumerate() {
                for (v, x) in row.iter().enumerate() {
                    store::<S, M>(s, Out::Add, c.add(i * ldc + S::LANES * v), core::ptr::null(), *x, cols);
                }
            }
        }
    }

    /// Outputs `o..o + R` of `C += Aᵀ·B` over rows `rows`, the widest tiles first.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tn_outs<S: Partial, const R: usize>(
        s: S,
        rows: core::ops::Range<usize>,
        n: usize,
        a: Mat<'_>,
        b: Mat<'_>,
        c: *mut f32,
        ldc: usize,
        o: usize,
    ) {
        // SAFETY: outputs o..o+R exist (caller); bounds checked by `Gemm::tn`.
        unsafe {
            let a = (a.data.as_ptr().add(o), a.ld);
            let (bp, cp, w) = (b.data.as_ptr(), c.add(o * ldc), S::LANES);
            let mut j = 0;
            if w >= 16 {
                while j + 4 * w <= n {
                    tn_tile::<S, R, 4, false>(s, rows.clone(), a, (bp.add(j), b.ld), (cp.add(j), ldc), w);
                    j += 4 * w;
                }
                if j + 2 * w <= n {
                    tn_tile::<S, R, 2, false>(s, rows.clone(), a, (bp.add(j), b.ld), (cp.add(j), ldc), w);
                    j += 2 * w;
                }
            } else {
                while j + 2 * w <= n {
                    tn_tile::<S, R, 2, false>(s, rows.clone(), a, (bp.add(j), b.ld), (cp.add(j), ldc), w);
                    j += 2 * w;
                }
            }
            if j + w <= n {
                tn_tile::<S, R, 1, false>(s, rows.clone(), a, (bp.add(j), b.ld), (cp.add(j), ldc), w);
                j += w;
            }
            if j < n {
                tn_tile::<S, R, 1, true>(s, rows, a, (bp.add(j), b.ld), (cp.add(j), ldc), n - j);
            }
        }
    }

    /// `C += Aᵀ·B` (see [`super::Gemm::tn`]).
    ///
    /// # Safety
    /// As [`nn`].
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn tn<S: Partial>(
        s: S,
        m: usize,
        ka: usize,
        n: usize,
        a: Mat<'_>,
        b: Mat<'_>,
        c: &mut [f32],
        ldc: usize,
    ) {
        let cp = c.as_mut_ptr();
        let mut r0 = 0;
        // SAFETY: as the contract above.
        unsafe {
            while r0 < m {
                let rows = r0..(r0 + TN_ROWS).min(m);
                let mut o = 0;
                while o + ROWS <= ka {
                    tn_outs::<S, ROWS>(s, rows.clone(), n, a, b, cp, ldc, o);
                    o += ROWS;
                }
                match ka - o {
                    5 => tn_outs::<S, 5>(s, rows.clone(), n, a, b, cp, ldc, o),
                    4 => tn_outs::<S, 4>(s, rows.clone(), n, a, b, cp, ldc, o),
                    3 => tn_outs::<S, 3>(s, rows.clone(), n, a, b, cp, ldc, o),
                    2 => tn_outs::<S, 2>(s, rows.clone(), n, a, b, cp, ldc, o),
                    1 => tn_outs::<S, 1>(s, rows.clone(), n, a, b, cp, ldc, o),
                    _ => {}
                }
                r0 = rows.end;
            }
        }
    }
}

/// The `#[target_feature]` entry points: each instantiates the tiles for its vector width.
#[cfg(target_arch = "x86_64")]
mod entry {
    use super::{tiles, Mat, Out};
    use crate::kernels::{Avx2Fma, Avx512};

    macro_rules! entries {
        ($nn:ident, $tn:ident, $token:ty, $features:literal) => {
            /// # Safety
            /// The operands hold their shapes and strides (checked by the caller).
            #[target_feature(enable = $features)]
            #[allow(clippy::too_many_arguments)]
            pub(super) unsafe fn $nn(
                t: $token,
                m: usize,
                n: usize,
                k: usize,
                a: Mat<'_>,
                b: Mat<'_>,
                out: Out<'_>,
                c: &mut [f32],
                ldc: usize,
            ) {
                // SAFETY: the token proves the features this function enables; the caller the
                // shapes.
                unsafe { tiles::nn(t, m, n, k, a, b, out, c, ldc) }
            }

            /// # Safety
            /// The operands hold their shapes and strides (checked by the caller).
            #[target_feature(enable = $features)]
            #[allow(clippy::too_many_arguments)]
            pub(super) unsafe fn $tn(
                t: $token,
                m: usize,
                ka: usize,
                n: usize,
                a: Mat<'_>,
                b: Mat<'_>,
                c: &mut [f32],
                ldc: usize,
            ) {
                // SAFETY: as above.
                unsafe { tiles::tn(t, m, ka, n, a, b, c, ldc) }
            }
        };
    }

    entries!(nn_avx2, tn_avx2, Avx2Fma, "avx2,fma");
    entries!(nn_avx512, tn_avx512, Avx512, "avx512f,avx2,fma");
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec::Vec;

    fn rand(n: usize, seed: &mut u64) -> Vec<f32> {
        (0..n)
            .map(|_| {
                *seed = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
                let mut z = *seed;
                z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
            })
            .collect()
    }

    /// The SIMD paths this CPU has, narrowest first.
    fn simd_paths() -> Vec<Gemm> {
        let mut paths: Vec<Gemm> = [Tier::Avx2Fma, Tier::Avx512].iter().map(|&t| Gemm::at_most(t)).collect();
        paths.dedup();
        paths.retain(|g| g.is_simd());
        paths
    }

    /// Every SIMD path against the scalar twin on fresh random data, odd shapes and strides.
    #[test]
    fn train_gemm_simd_matches_scalar() {
        let paths = simd_paths();
        if paths.is_empty() {
            std::println!("train_gemm_simd_matches_scalar: no SIMD path on this CPU, SKIPPED");
        }
        for simd in paths {
            std::println!("train_gemm_simd_matches_scalar: {}", simd.tier().name());
            simd_matches_scalar(simd);
        }
    }

    fn simd_matches_scalar(simd: Gemm) {
        let mut seed = 11u64;
        for &(m, n, k) in &[
            (1, 1, 1),
            (5, 3, 7),
            (4, 16, 9),
            (37, 33, 24),
            (130, 40, 12),
            (300, 128, 96),
            (9, 8, 1),
            (11, 13, 64),
            (8, 14, 32),
            (13, 64, 192),
            (7, 100, 5),
            (6, 48, 64),
        ] {
            let (lda, ldb, ldc) = (k + 3, n + 5, n + 2);
            let a = rand(m * lda, &mut seed);
            let b = rand(k * ldb, &mut seed);
            let c0 = rand(m * ldc, &mut seed);
            let (mut c1, mut c2) = (c0.clone(), c0.clone());
            simd.nn(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, &mut c1, ldc);
            Gemm::scalar().nn(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, &mut c2, ldc);
            let mut changed = false;
            for i in 0..c1.len() {
                assert!((c1[i] - c2[i]).abs() <= 1e-5 * (1.0 + k as f32), "nn {m}x{n}x{k} at {i}: {} {}", c1[i], c2[i]);
                changed |= c1[i] != c0[i];
            }
            assert!(changed);
            // The other epilogues.
            let bias = rand(n, &mut seed);
            for out in [Out::Set, Out::Bias(&bias), Out::BiasRelu(&bias)] {
                let (mut c1, mut c2) = (c0.clone(), c0.clone());
                simd.nn_out(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, out, &mut c1, ldc);
                Gemm::scalar().nn_out(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, out, &mut c2, ldc);
                let mut zeros = 0;
                for r in 0..m {
                    for j in 0..n {
                        let i = r * ldc + j;
                        assert!((c1[i] - c2[i]).abs() <= 1e-5 * (1.0 + k as f32), "{out:?} {m}x{n}x{k} at {i}");
                        zeros += usize::from(c1[i] == 0.0);
                    }
                    // Padding between rows is never written.
                    assert_eq!(
                        c1[r * ldc + n..(r * ldc + ldc).min(c1.len())],
                        c0[r * ldc + n..(r * ldc + ldc).min(c0.len())]
                    );
                }
                if matches!(out, Out::BiasRelu(_)) && m * n > 8 {
                    assert!(zeros > 0 && zeros < m * n, "ReLU cut {zeros} of {}", m * n);
                }
            }
            // tn: A is m × k (ka = k outputs), B is m × n.
            let bt = rand(m * ldb, &mut seed);
            let c0 = rand(k * ldc, &mut seed);
            let (mut c1, mut c2) = (c0.clone(), c0.clone());
            simd.tn(m, k, n, Mat { data: &a, ld: lda }, Mat { data: &bt, ld: ldb }, &mut c1, ldc);
            Gemm::scalar().tn(m, k, n, Mat { data: &a, ld: lda }, Mat { data: &bt, ld: ldb }, &mut c2, ldc);
            for i in 0..c1.len() {
                assert!((c1[i] - c2[i]).abs() <= 1e-5 * (1.0 + m as f32), "tn {m}x{n}x{k} at {i}: {} {}", c1[i], c2[i]);
            }
        }
    }

    /// The AVX-512 and AVX2 paths agree bitwise (the same chain of fused multiply-adds per
    /// element), on every shape and epilogue: a run may resume on a machine of the other kind.
    #[test]
    fn train_gemm_avx512_equals_avx2_bitwise() {
        let (wide, narrow) = (Gemm::at_most(Tier::Avx512), Gemm::at_most(Tier::Avx2Fma));
        if wide.tier() != Tier::Avx512 || narrow.tier() != Tier::Avx2Fma {
            std::println!("train_gemm_avx512_equals_avx2_bitwise: no AVX-512 on this CPU, SKIPPED");
            return;
        }
        let mut seed = 23u64;
        for &(m, n, k) in &[(1, 1, 1), (7, 15, 3), (13, 64, 192), (25, 200, 64), (130, 33, 14), (6, 80, 128)] {
            let (lda, ldb, ldc) = (k + 1, n + 3, n + 4);
            let a = rand(m * lda, &mut seed);
            let b = rand(k * ldb, &mut seed);
            let c0 = rand(m * ldc, &mut seed);
            let bias = rand(n, &mut seed);
            for out in [Out::Add, Out::Set, Out::Bias(&bias), Out::BiasRelu(&bias)] {
                let (mut c1, mut c2) = (c0.clone(), c0.clone());
                wide.nn_out(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, out, &mut c1, ldc);
                narrow.nn_out(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, out, &mut c2, ldc);
                assert!(c1.iter().zip(&c2).all(|(x, y)| x.to_bits() == y.to_bits()), "nn {out:?} {m}x{n}x{k}");
            }
            // tn over more rows than one streamed pass.
            let rows = 3 * m + 131;
            let at = rand(rows * lda, &mut seed);
            let bt = rand(rows * ldb, &mut seed);
            let c0 = rand(k * ldc, &mut seed);
            let (mut c1, mut c2) = (c0.clone(), c0.clone());
            wide.tn(rows, k, n, Mat { data: &at, ld: lda }, Mat { data: &bt, ld: ldb }, &mut c1, ldc);
            narrow.tn(rows, k, n, Mat { data: &at, ld: lda }, Mat { data: &bt, ld: ldb }, &mut c2, ldc);
            assert!(c1.iter().zip(&c2).all(|(x, y)| x.to_bits() == y.to_bits()), "tn {rows}x{n}x{k}");
        }
    }

    /// Checks `got` against `start + Σ terms` summed in f64: within a few f32 roundings of the
    /// terms' magnitude. Returns the error over that magnitude.
    #[cfg(target_arch = "x86_64")]
    fn check_sum(
        got: f32,
        start: f32,
        terms: impl Iterator<Item = f64>,
        what: impl Fn() -> std::string::String,
    ) -> f64 {
        let (mut sum, mut size) = (start as f64, 0.0f64);
        for p in terms {
            sum += p;
            size += p.abs();
        }
        let err = (got as f64 - sum).abs();
        assert!(err <= 1e-6 * size + 1e-6 * (1.0 + sum.abs()), "{}: {err:e} of {size}", what());
        err / size.max(1e-30)
    }

    /// The split-bf16 tile path (on the software model of the tiles) against sums in f64 on
    /// fresh random data: every sum within a few f32 roundings of its terms' magnitude, where
    /// products on bf16 operands would be off by up to 2^-8 and a split in two by 2^-16; sizes
    /// across tile and panel boundaries; and every epilogue and padding rule of the f32 paths.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn train_gemm_tile_model_matches_f64() {
        tiles_match_f64(Gemm::tile_model());
    }

    /// The same on the tile unit itself, where this process may use it; and bitwise the model's
    /// results (the model is `tdpbf16ps` as Intel defines it).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn train_gemm_tiles_match_f64_and_the_model() {
        let Some(tiles) = Gemm::tiles() else {
            std::println!("train_gemm_tiles_match_f64_and_the_model: no AMX in this process, SKIPPED");
            return;
        };
        tiles_match_f64(tiles);
        let mut seed = 3u64;
        for &(m, n, k) in &[(40, 64, 64), (17, 33, 100), (5, 16, 16)] {
            let a = rand(m * k, &mut seed);
            let b = rand(k * n, &mut seed);
            let (mut c1, mut c2) = (rand(m * n, &mut seed), std::vec::Vec::new());
            c2.clone_from(&c1);
            tiles.nn(m, n, k, Mat { data: &a, ld: k }, Mat { data: &b, ld: n }, &mut c1, n);
            Gemm::tile_model().nn(m, n, k, Mat { data: &a, ld: k }, Mat { data: &b, ld: n }, &mut c2, n);
            assert!(c1.iter().zip(&c2).all(|(x, y)| x.to_bits() == y.to_bits()), "{m}x{n}x{k}");
        }
    }

    #[cfg(target_arch = "x86_64")]
    fn tiles_match_f64(g: Gemm) {
        assert_eq!(g.tier(), Tier::Amx);
        simd_matches_scalar(g);
        let mut seed = 41u64;
        let mut worst = 0.0f64;
        for &(m, n, k) in &[(1, 1, 1), (16, 16, 32), (17, 33, 33), (40, 64, 64), (3, 100, 70), (33, 5, 192), (9, 48, 0)]
        {
            let (lda, ldb, ldc) = (k + 2, n + 1, n + 3);
            let a = rand(m * lda, &mut seed);
            let b = rand(k * ldb, &mut seed);
            let c0 = rand(m * ldc, &mut seed);
            let mut c = c0.clone();
            g.nn(m, n, k, Mat { data: &a, ld: lda }, Mat { data: &b, ld: ldb }, &mut c, ldc);
            for r in 0..m {
                for j in 0..n {
                    let terms = (0..k).map(|kk| a[r * lda + kk] as f64 * b[kk * ldb + j] as f64);
                    let rel =
                        check_sum(c[r * ldc + j], c0[r * ldc + j], terms, || std::format!("nn {m}x{n}x{k} ({r}, {j})"));
                    worst = worst.max(rel);
                }
            }
        }
        std::println!("tiles_match_f64: worst error {worst:e} of the products' magnitude");
    }

    /// A row computed in a tile of six equals the same row computed alone (thread splits); on
    /// the tile path, a row of a tile of 16 the same.
    #[test]
    fn train_gemm_rows_independent_of_split() {
        rows_independent_of_split(Gemm::best());
        #[cfg(target_arch = "x86_64")]
        rows_independent_of_split(Gemm::tile_model());
    }

    fn rows_independent_of_split(g: Gemm) {
        let mut seed = 5u64;
        let (m, n, k) = (37, 37, 29);
        let a = rand(m * k, &mut seed);
        let b = rand(k * n, &mut seed);
        let mut all = alloc::vec![0.0; m * n];
        g.nn(m, n, k, Mat { data: &a, ld: k }, Mat { data: &b, ld: n }, &mut all, n);
        for r in 0..m {
            let mut one = alloc::vec![0.0; n];
            g.nn(1, n, k, Mat { data: &a[r * k..], ld: k }, Mat { data: &b, ld: n }, &mut one, n);
            assert_eq!(&all[r * n..(r + 1) * n], &one[..]);
        }
    }
}
