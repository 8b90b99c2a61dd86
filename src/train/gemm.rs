//! The trainer's f32 matrix products on strided row-major operands: `C += A·B` (forward
//! products against transposed weights, and `dX = dY·W` in the backward) and `C += Aᵀ·B`
//! (weight gradients `dW += dYᵀ·X`). An AVX2+FMA path chosen at run time (by
//! [`crate::kernels::Kernels::best`], so `HOOD_KERNEL_TIER` caps it too) and a scalar twin.
//!
//! Every output element is one sum in a fixed order whatever the row position (a tile of six
//! rows and a tail tile of fewer run the same chain of operations), so splitting rows between
//! threads never changes a result. Column remainders run masked vectors (the same fused
//! multiply-adds as the full vectors), not scalar loops: the narrow inputs of the encoders (3 to
//! 14 features) made those loops a visible share of a training step.

use crate::kernels::{Kernels, Tier};

/// A chosen product path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gemm {
    avx2: bool,
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
    /// The best path for this CPU (AVX2+FMA when [`Kernels::best`] reaches that tier).
    pub fn best() -> Gemm {
        Gemm { avx2: Kernels::best().tier() >= Tier::Avx2Fma && cfg!(target_arch = "x86_64") }
    }

    /// The scalar reference.
    pub fn scalar() -> Gemm {
        Gemm { avx2: false }
    }

    /// True for the SIMD path.
    pub fn is_simd(&self) -> bool {
        self.avx2
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
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when `Kernels::best()` found AVX2+FMA on this CPU; the
            // asserts above bound every index the kernel reads or writes.
            unsafe { avx2::nn(m, n, k, a, b, out, c, ldc) };
            return;
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
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: as in `nn`.
            unsafe { avx2::tn(m, ka, n, a, b, c, ldc) };
            return;
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

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Mat, Out};
    use core::arch::x86_64::*;

    /// Rows of `B` streamed per pass of [`tn`] (keeps a 16-column strip in L1).
    const TN_ROWS: usize = 128;

    /// Lanes below `cols` set: the mask of a last, partial vector of columns.
    #[inline(always)]
    unsafe fn lanes(cols: usize) -> __m256i {
        // SAFETY: plain AVX2 integer operations (the caller enabled AVX2).
        unsafe { _mm256_cmpgt_epi32(_mm256_set1_epi32(cols as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)) }
    }

    /// 8 floats at `p`, only the lanes of `mask` when `M` (the others read as 0, not touched).
    #[inline(always)]
    unsafe fn load<const M: bool>(p: *const f32, mask: __m256i) -> __m256 {
        // SAFETY: `p` addresses 8 valid elements, or (masked) the masked ones (caller).
        unsafe {
            if M {
                _mm256_maskload_ps(p, mask)
            } else {
                _mm256_loadu_ps(p)
            }
        }
    }

    /// The epilogue of a tile's vector `x` into `p`, bias vector at `bias` (see [`Out`]); with
    /// `M`, only the lanes of `mask` are read and written.
    #[inline(always)]
    unsafe fn store<const M: bool>(out: Out<'_>, p: *mut f32, bias: *const f32, x: __m256, mask: __m256i) {
        // SAFETY: `p` and (for the bias forms) `bias` address the lanes used (caller).
        unsafe {
            let v = match out {
                Out::Add => _mm256_add_ps(load::<M>(p, mask), x),
                Out::Set => x,
                Out::Bias(_) => _mm256_add_ps(load::<M>(bias, mask), x),
                Out::BiasRelu(_) => _mm256_max_ps(_mm256_add_ps(load::<M>(bias, mask), x), _mm256_setzero_ps()),
            };
            if M {
                _mm256_maskstore_ps(p, mask, v);
            } else {
                _mm256_storeu_ps(p, v);
            }
        }
    }

    /// One tile of `C (op)= A·B`: `R` rows (1..=6) × `V` vectors of 8 columns at column `j`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn nn_tile<const R: usize, const V: usize, const M: bool>(
        k: usize,
        a: *const f32,
        lda: usize,
        b: *const f32,
        ldb: usize,
        out: Out<'_>,
        j: usize,
        c: *mut f32,
        ldc: usize,
        mask: __m256i,
    ) {
        // SAFETY (whole body): the caller passes pointers to the tile's first elements with
        // `R` rows of `k` (A), `k` rows of `8V` (B) and `R` rows of `8V` (C) in bounds (with
        // `M`, V = 1 and only the lanes of `mask`).
        unsafe {
            let mut acc = [[_mm256_setzero_ps(); V]; R];
            for kk in 0..k {
                let mut bv = [_mm256_setzero_ps(); V];
                for (v, x) in bv.iter_mut().enumerate() {
                    *x = load::<M>(b.add(kk * ldb + 8 * v), mask);
                }
                for (i, row) in acc.iter_mut().enumerate() {
                    let av = _mm256_broadcast_ss(&*a.add(i * lda + kk));
                    for (x, &w) in row.iter_mut().zip(&bv) {
                        *x = _mm256_fmadd_ps(av, w, *x);
                    }
                }
            }
            let bias = match out {
                Out::Bias(b) | Out::BiasRelu(b) => b.as_ptr().add(j),
                _ => core::ptr::null(),
            };
            for (i, row) in acc.iter().enumerate() {
                for (v, x) in row.iter().enumerate() {
                    store::<M>(out, c.add(i * ldc + 8 * v), bias.wrapping_add(8 * v), *x, mask);
                }
            }
        }
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn nn_rows<const R: usize>(
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
        // `Gemm::nn`.
        unsafe {
            let ap = a.data.as_ptr().add(r * a.ld);
            let cp = c.add(r * ldc);
            let mut j = 0;
            let full = lanes(8);
            while j + 16 <= n {
                nn_tile::<R, 2, false>(k, ap, a.ld, b.data.as_ptr().add(j), b.ld, out, j, cp.add(j), ldc, full);
                j += 16;
            }
            if j + 8 <= n {
                nn_tile::<R, 1, false>(k, ap, a.ld, b.data.as_ptr().add(j), b.ld, out, j, cp.add(j), ldc, full);
                j += 8;
            }
            if j < n {
                let mask = lanes(n - j);
                nn_tile::<R, 1, true>(k, ap, a.ld, b.data.as_ptr().add(j), b.ld, out, j, cp.add(j), ldc, mask);
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn nn(
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
        // SAFETY: bounds checked by `Gemm::nn_out`; AVX2+FMA enabled by the caller's token.
        unsafe {
            while r + 6 <= m {
                nn_rows::<6>(n, k, a, b, out, cp, ldc, r);
                r += 6;
            }
            match m - r {
                5 => nn_rows::<5>(n, k, a, b, out, cp, ldc, r),
                4 => nn_rows::<4>(n, k, a, b, out, cp, ldc, r),
                3 => nn_rows::<3>(n, k, a, b, out, cp, ldc, r),
                2 => nn_rows::<2>(n, k, a, b, out, cp, ldc, r),
                1 => nn_rows::<1>(n, k, a, b, out, cp, ldc, r),
                _ => {}
            }
        }
    }

    /// One tile of `C += Aᵀ·B` over rows `r0..r1`: `R` outputs (A columns) × `V` vectors.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tn_tile<const R: usize, const V: usize, const M: bool>(
        rows: core::ops::Range<usize>,
        a: *const f32,
        lda: usize,
        b: *const f32,
        ldb: usize,
        c: *mut f32,
        ldc: usize,
        mask: __m256i,
    ) {
        // SAFETY (whole body): pointers at the tile's first column/row; rows in bounds (with
        // `M`, V = 1 and only the lanes of `mask`).
        unsafe {
            let mut acc = [[_mm256_setzero_ps(); V]; R];
            for r in rows {
                let mut bv = [_mm256_setzero_ps(); V];
                for (v, x) in bv.iter_mut().enumerate() {
                    *x = load::<M>(b.add(r * ldb + 8 * v), mask);
                }
                for (i, row) in acc.iter_mut().enumerate() {
                    let av = _mm256_broadcast_ss(&*a.add(r * lda + i));
                    for (x, &w) in row.iter_mut().zip(&bv) {
                        *x = _mm256_fmadd_ps(av, w, *x);
                    }
                }
            }
            for (i, row) in acc.iter().enumerate() {
                for (v, x) in row.iter().enumerate() {
                    store::<M>(Out::Add, c.add(i * ldc + 8 * v), core::ptr::null(), *x, mask);
                }
            }
        }
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tn_outs<const R: usize>(
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
            let ap = a.data.as_ptr().add(o);
            let cp = c.add(o * ldc);
            let mut j = 0;
            let full = lanes(8);
            let bp = b.data.as_ptr();
            while j + 16 <= n {
                tn_tile::<R, 2, false>(rows.clone(), ap, a.ld, bp.add(j), b.ld, cp.add(j), ldc, full);
                j += 16;
            }
            if j + 8 <= n {
                tn_tile::<R, 1, false>(rows.clone(), ap, a.ld, bp.add(j), b.ld, cp.add(j), ldc, full);
                j += 8;
            }
            if j < n {
                tn_tile::<R, 1, true>(rows.clone(), ap, a.ld, bp.add(j), b.ld, cp.add(j), ldc, lanes(n - j));
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn tn(m: usize, ka: usize, n: usize, a: Mat<'_>, b: Mat<'_>, c: &mut [f32], ldc: usize) {
        let cp = c.as_mut_ptr();
        let mut r0 = 0;
        // SAFETY: bounds checked by `Gemm::tn`; AVX2+FMA enabled by the caller's token.
        unsafe {
            while r0 < m {
                let rows = r0..(r0 + TN_ROWS).min(m);
                let mut o = 0;
                while o + 6 <= ka {
                    tn_outs::<6>(rows.clone(), n, a, b, cp, ldc, o);
                    o += 6;
                }
                match ka - o {
                    5 => tn_outs::<5>(rows.clone(), n, a, b, cp, ldc, o),
                    4 => tn_outs::<4>(rows.clone(), n, a, b, cp, ldc, o),
                    3 => tn_outs::<3>(rows.clone(), n, a, b, cp, ldc, o),
                    2 => tn_outs::<2>(rows.clone(), n, a, b, cp, ldc, o),
                    1 => tn_outs::<1>(rows.clone(), n, a, b, cp, ldc, o),
                    _ => {}
                }
                r0 = rows.end;
            }
        }
    }
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

    /// The SIMD products against the scalar twin on fresh random data, odd shapes and strides.
    #[test]
    fn train_gemm_simd_matches_scalar() {
        let simd = Gemm::best();
        if !simd.is_simd() {
            std::println!("train_gemm_simd_matches_scalar: no SIMD path on this CPU, skipped");
            return;
        }
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

    /// A row computed in a tile of six equals the same row computed alone (thread splits).
    #[test]
    fn train_gemm_rows_independent_of_split() {
        let g = Gemm::best();
        let mut seed = 5u64;
        let (m, n, k) = (11, 37, 29);
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
