//! The trainer's products on the AMX tiles, in split bf16.
//!
//! A product on bf16 operands keeps 8 significant bits of each (up to 0.2 % error), twenty times
//! the bound the trainer's gradients are held to. Split in two (`x = hi + lo`, three products)
//! is not enough either: the gradients of a training step sum and normalise products through
//! many layers, and on the software model of the tiles that split missed the bound by more than
//! a hundred times (`train_fast_matches_generic`). So each f32 operand is split in three bf16,
//! `x = h + m + l` (`h` the nearest bf16 to `x`, `m` the nearest to `x - h`, `l` to
//! `x - h - m`, which for a normal f32 is exact: `|m| <= 2^-8 |x|`, `|l| <= 2^-16 |x|`), and each
//! product is taken as the six terms it cannot do without, `h·h + h·m + m·h + m·m + h·l + l·h`,
//! each accumulated in f32 on the tiles; the dropped `m·l + l·m + l·l` is below about `2^-23` of
//! the product. That is about f32's precision for six times the bf16 work, which pays only where
//! the tile unit's rate (about 16 times the f32 vector rate on Intel's AMX cores) covers it and
//! the splitting; [`super::Gemm::best`] measures it before choosing it.
//!
//! **What runs here.** The products with a short sum and many rows, `C (op)= A·B` (the
//! forward products, and the input gradients `dX = dY·W`): `B` (the weights, `k × n`) is split
//! once per call into panels of 16 columns, and `A` 16 rows at a time, each row's inputs in
//! order, so the split is a few vector instructions per 16 inputs ([`split_rows`]). The weight
//! gradients (`C += Aᵀ·B`, a sum over rows) stay on the f32 FMAs ([`super::Gemm::tn`]): their
//! tiles would need both operands split and one transposed on every call.
//!
//! **Layouts** (as [`crate::kernels`]' AMX path): an A tile is 16 rows of 16 bf16 pairs along the
//! sum (64 bytes a row); a B tile is 16 pair rows of 16 columns × (even, odd) input. Sizes are
//! padded with zeros to whole tiles.
//!
//! **Order of the sums.** Each output element sums, per 32 inputs in order, the six terms in the
//! order above (each pair the even then the odd input, as `tdpbf16ps` does), whatever its row or
//! column position: a row computed in a tile of 16 equals the same row computed alone, so
//! splitting rows between threads never changes a result. The sums differ from the f32 paths'
//! fused multiply-adds in rounding; a run that resumes on a CPU that chooses the other path
//! continues with its arithmetic.

use super::{Mat, Out};
use crate::kernels::{round_bf16, TileUnit};
use alloc::vec::Vec;
use core::cell::RefCell;

/// Rows of an A or C tile, and input pairs of a B tile.
const ROWS: usize = 16;
/// Columns of a C or B tile (one panel).
const COLS: usize = 16;
/// Input pairs of one A tile row.
const PAIRS: usize = 16;
/// The fewest inputs and output columns a product needs to run here: half an A tile row and one
/// whole panel (smaller ones stay on the f32 path, [`super::Gemm::nn_out`]).
pub(super) const MIN_INPUTS: usize = PAIRS;
pub(super) const MIN_COLUMNS: usize = COLS;

/// The split of `x` in three bf16 (`h`, `m`, `l`; see the module docs), as `f32` bit patterns
/// with zero low halves.
#[inline(always)]
fn split(x: f32) -> [u32; 3] {
    let h = round_bf16(x);
    let m = round_bf16(x - h);
    [h.to_bits(), m.to_bits(), round_bf16(x - h - m).to_bits()]
}

/// One tile slot: the bf16 of the even input in the low half, the odd one in the high half.
#[inline(always)]
fn pair(even: u32, odd: u32) -> u32 {
    (even >> 16) | (odd & 0xFFFF_0000)
}

/// Thread-local scratch of the split operands, one buffer per part (`h`, `m`, `l`), kept
/// between calls: a trainer's products have the same few shapes every iteration.
#[derive(Default)]
struct Scratch {
    a: [Vec<u32>; 3],
    b: [Vec<u32>; 3],
}

std::thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

/// 16 × 16 f32 of one output tile, as `tilestored` writes it.
#[repr(C, align(64))]
struct CTile([f32; ROWS * COLS]);

/// Splits `value(i, j)` (input `i` of the sum, column `j`; zero outside the operand) into B-tile
/// panels of `pairs` pair rows: panel `p`, pair row `q` (inputs `2q` and `2q + 1`), column `j`
/// at `(p · pairs + q) · 16 + j`, one buffer per part.
fn pack_b(panels: usize, pairs: usize, b: &mut [Vec<u32>; 3], value: impl Fn(usize, usize) -> f32) {
    // Every slot is written below.
    b.iter_mut().for_each(|v| v.resize(panels * pairs * COLS, 0));
    for p in 0..panels {
        for q in 0..pairs {
            for j in 0..COLS {
                let (even, odd) = (split(value(2 * q, p * COLS + j)), split(value(2 * q + 1, p * COLS + j)));
                for part in 0..3 {
                    b[part][(p * pairs + q) * COLS + j] = pair(even[part], odd[part]);
                }
            }
        }
    }
}

/// Splits rows `rows` (at most 16) of `A` (`k` inputs each) into A-tile rows of `pairs` slots in
/// each part: row `r` of the tile, pair `q` at `r · pairs + q`; rows past the last and inputs
/// past `k` zero. With AVX-512-BF16 (every CPU with AMX has it) 16 inputs at a time
/// (`vcvtneps2bf16`), which rounds as [`split`] does but reads subnormal parts as zero, as the
/// tiles do anyway.
fn split_rows(a: Mat<'_>, rows: core::ops::Range<usize>, k: usize, pairs: usize, parts: &mut [Vec<u32>; 3]) {
    assert!(
        rows.len() <= ROWS
            && pairs.is_multiple_of(PAIRS)
            && 2 * pairs >= k
            && parts.iter().all(|p| p.len() >= ROWS * pairs)
    );
    assert!(rows.is_empty() || k == 0 || a.data.len() >= (rows.end - 1) * a.ld + k, "split_rows: A too short");
    if let Some(t) = crate::kernels::Avx512Bf16::new() {
        // SAFETY: the token proves the features; the asserts above bound every read and write.
        return unsafe { split_rows_avx512(t, a, rows, k, pairs, parts) };
    }
    split_rows_scalar(a, rows, k, pairs, parts);
}

/// The scalar twin of [`split_rows_avx512`].
fn split_rows_scalar(a: Mat<'_>, rows: core::ops::Range<usize>, k: usize, pairs: usize, parts: &mut [Vec<u32>; 3]) {
    for r in 0..ROWS {
        for q in 0..pairs {
            let at = |kk: usize| if r < rows.len() && kk < k { a.data[(rows.start + r) * a.ld + kk] } else { 0.0 };
            let (even, odd) = (split(at(2 * q)), split(at(2 * q + 1)));
            for part in 0..3 {
                parts[part][r * pairs + q] = pair(even[part], odd[part]);
            }
        }
    }
}

/// [`split_rows`] 16 inputs at a time: per part one `vcvtneps2bf16` gives the 8 pair slots.
///
/// # Safety
/// The asserts of [`split_rows`] hold.
#[target_feature(enable = "avx2,fma,avx512f,avx512bf16")]
unsafe fn split_rows_avx512(
    _t: crate::kernels::Avx512Bf16,
    a: Mat<'_>,
    rows: core::ops::Range<usize>,
    k: usize,
    pairs: usize,
    parts: &mut [Vec<u32>; 3],
) {
    use core::arch::x86_64::*;
    // The bf16 `b` as f32 (exact).
    let widen = |b: __m256bh| {
        // SAFETY: a lane rename of 16 bf16, then register-only integer operations.
        unsafe {
            _mm512_castsi512_ps(_mm512_slli_epi32::<16>(_mm512_cvtepu16_epi32(
                core::mem::transmute::<__m256bh, __m256i>(b),
            )))
        }
    };
    for r in 0..ROWS {
        for c in 0..pairs / 8 {
            let first = 16 * c;
            let x = if r < rows.len() && first < k {
                let cols = (k - first).min(16);
                // SAFETY: the masked load reads inputs `first..first + cols` of the row, below
                // `k`, inside `a` (the caller's asserts).
                unsafe {
                    _mm512_maskz_loadu_ps(
                        ((1u32 << cols) - 1) as __mmask16,
                        a.data.as_ptr().add((rows.start + r) * a.ld + first),
                    )
                }
            } else {
                _mm512_setzero_ps()
            };
            let h = _mm512_cvtneps_pbh(x);
            let rest = _mm512_sub_ps(x, widen(h));
            let m = _mm512_cvtneps_pbh(rest);
            let l = _mm512_cvtneps_pbh(_mm512_sub_ps(rest, widen(m)));
            for (part, v) in [h, m, l].into_iter().enumerate() {
                // SAFETY: slots `r · pairs + 8c .. + 8` lie inside the part (`8c + 8 <= pairs`,
                // `r < 16`, each part at least 16 · pairs long).
                unsafe {
                    _mm256_storeu_si256(
                        parts[part].as_mut_ptr().add(r * pairs + 8 * c) as *mut __m256i,
                        core::mem::transmute::<__m256bh, __m256i>(v),
                    )
                };
            }
        }
    }
}

/// The six products of one output tile `C` from A tiles 2-4 (`h`, `m`, `l`) and B tiles 5-7,
/// in the order of the module docs.
#[inline(always)]
fn six_products<U: TileUnit, const C: usize>(u: &mut U) {
    u.dot::<C, 2, 5>();
    u.dot::<C, 2, 6>();
    u.dot::<C, 3, 5>();
    u.dot::<C, 3, 6>();
    u.dot::<C, 2, 7>();
    u.dot::<C, 4, 5>();
}

/// Accumulates one row tile against one or two panels over `pairs` pair rows (a multiple of
/// 16): `A`'s parts at `a` (rows `a_stride` slots apart), `B`'s parts in `b` from panel `p0`;
/// stores the results in `c[0]` (and `c[1]`).
///
/// # Safety
/// `U` is configured on this thread; 16 rows of `pairs` slots are readable at each of `a` with
/// stride `a_stride`.
#[inline(always)]
unsafe fn row_tile<U: TileUnit>(
    u: &mut U,
    (a, a_stride): ([*const u32; 3], usize),
    b: &[Vec<u32>; 3],
    (p0, two): (usize, bool),
    pairs: usize,
    c: &mut [CTile; 2],
) {
    // Bounds-checked start of a B tile: a panel holds `pairs` whole pair rows, so the 16 rows
    // from pair `q` stay inside it.
    let panel =
        |part: usize, p: usize, q: usize| b[part][(p * pairs + q) * COLS..][..PAIRS * COLS].as_ptr() as *const f32;
    u.zero::<0>();
    u.zero::<1>();
    // SAFETY: the caller's contract covers the A rows; the B tiles are inside their panels.
    unsafe {
        for q in (0..pairs).step_by(PAIRS) {
            u.load::<2>(a[0].add(q) as *const f32, a_stride * 4);
            u.load::<3>(a[1].add(q) as *const f32, a_stride * 4);
            u.load::<4>(a[2].add(q) as *const f32, a_stride * 4);
            u.load::<5>(panel(0, p0, q), COLS * 4);
            u.load::<6>(panel(1, p0, q), COLS * 4);
            u.load::<7>(panel(2, p0, q), COLS * 4);
            six_products::<U, 0>(u);
            if two {
                u.load::<5>(panel(0, p0 + 1, q), COLS * 4);
                u.load::<6>(panel(1, p0 + 1, q), COLS * 4);
                u.load::<7>(panel(2, p0 + 1, q), COLS * 4);
                six_products::<U, 1>(u);
            }
        }
        u.store::<0>(c[0].0.as_mut_ptr());
        u.store::<1>(c[1].0.as_mut_ptr());
    }
}

/// `C[m×n] (op)= A[m×k] · B[k×n]` on the tile unit `U` (see [`super::Gemm::nn_out`]).
///
/// # Safety
/// `U` is available ([`TileUnit::available`]); the operands hold their shapes and strides
/// (checked by the caller); `m` and `n` are not zero (`k` may be: the tiles then add zeros).
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn nn<U: TileUnit>(
    m: usize,
    n: usize,
    k: usize,
    a: Mat<'_>,
    b: Mat<'_>,
    out: Out<'_>,
    c: &mut [f32],
    ldc: usize,
) {
    let pairs = k.div_ceil(2 * PAIRS) * PAIRS;
    let panels = n.div_ceil(COLS);
    SCRATCH.with_borrow_mut(|s| {
        let in_b = |kk: usize, j: usize| if kk < k && j < n { b.data[kk * b.ld + j] } else { 0.0 };
        pack_b(panels, pairs, &mut s.b, in_b);
        // `split_rows` writes every slot, padding included.
        s.a.iter_mut().for_each(|v| v.resize(ROWS * pairs, 0));
        let mut tiles = [CTile([0.0; ROWS * COLS]), CTile([0.0; ROWS * COLS])];
        // SAFETY: the caller's contract makes the unit available; it is released below.
        unsafe { U::configure() };
        // SAFETY: as above, configured.
        let u = &mut unsafe { U::on_this_thread() };
        for r0 in (0..m).step_by(ROWS) {
            let nr = (m - r0).min(ROWS);
            split_rows(a, r0..r0 + nr, k, pairs, &mut s.a);
            let a_parts = [s.a[0].as_ptr(), s.a[1].as_ptr(), s.a[2].as_ptr()];
            for p0 in (0..panels).step_by(2) {
                let two = p0 + 1 < panels;
                // SAFETY: configured; each part holds 16 rows of `pairs` slots.
                unsafe { row_tile(u, (a_parts, pairs), &s.b, (p0, two), pairs, &mut tiles) };
                for (pj, tile) in tiles.iter().enumerate().take(1 + usize::from(two)) {
                    for r in 0..nr {
                        for j in 0..COLS.min(n - (p0 + pj) * COLS) {
                            let col = (p0 + pj) * COLS + j;
                            out.apply(&mut c[(r0 + r) * ldc + col], col, tile.0[r * COLS + j]);
                        }
                    }
                }
            }
        }
        // SAFETY: configured above on this thread.
        unsafe { U::release() };
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec;

    /// Each of the six products counts: operands whose three parts are all far from zero
    /// (`x = 1 + 1.5·2^-9 + 1.25·2^-18`, so `m·m` and `h·l` are about 2^-17 of the product),
    /// squared, within 1e-6 of the exact square (dropping any term misses by 4e-6 or more).
    #[test]
    fn train_tiles_take_all_six_products() {
        let x = 1.0f32 + 1.5 * (-9f32).exp2() + 1.25 * (-18f32).exp2();
        assert_eq!(split(x).map(f32::from_bits), [1.0, 1.5 * (-9f32).exp2(), 1.25 * (-18f32).exp2()]);
        let (m, n) = (20, 16);
        let a: Vec<f32> = (0..m).map(|r| if r % 2 == 0 { x } else { -x }).collect();
        let b = vec![x; n];
        let mut c = vec![0.0f32; m * n];
        // SAFETY: the model needs nothing of the CPU; the operands hold their shapes.
        unsafe {
            nn::<crate::kernels::TileModel>(
                m,
                n,
                1,
                Mat { data: &a, ld: 1 },
                Mat { data: &b, ld: n },
                Out::Set,
                &mut c,
                n,
            )
        };
        let exact = x as f64 * x as f64;
        for (i, &v) in c.iter().enumerate() {
            let sign = if (i / n) % 2 == 0 { 1.0 } else { -1.0 };
            assert!((v as f64 - sign * exact).abs() <= 1e-6 * exact, "{i}: {v} against {}", sign * exact);
        }
    }

    /// The vector split against its scalar twin, bitwise, on fresh random rows of mixed
    /// magnitudes, ragged inputs and a partial row tile.
    #[test]
    fn train_split_rows_avx512_equals_scalar() {
        let Some(t) = crate::kernels::Avx512Bf16::new() else {
            std::println!("train_split_rows_avx512_equals_scalar: no AVX-512-BF16 on this CPU, SKIPPED");
            return;
        };
        let mut rng = crate::rng::Rng::new(17);
        for &(rows, k, ld) in
            &[(16usize, 64usize, 64usize), (5, 33, 40), (16, 1, 3), (11, 100, 101), (0, 8, 8), (16, 0, 4)]
        {
            let pairs = k.div_ceil(2 * PAIRS) * PAIRS;
            let data: Vec<f32> =
                (0..(rows + 2) * ld).map(|_| (rng.normal() * 10f64.powf(rng.uniform(-6.0, 4.0))) as f32).collect();
            let a = Mat { data: &data, ld };
            let mut simd: [Vec<u32>; 3] = core::array::from_fn(|_| vec![7; ROWS * pairs]);
            let mut scalar = simd.clone();
            // SAFETY: the token proves the features; the shapes are those `split_rows` asserts.
            unsafe { split_rows_avx512(t, a, 1..1 + rows, k, pairs, &mut simd) };
            split_rows_scalar(a, 1..1 + rows, k, pairs, &mut scalar);
            assert_eq!(simd, scalar, "{rows} rows of {k}");
            if rows > 0 && k > 0 {
                assert!(simd[1].iter().any(|&v| v != 0) && simd[2].iter().any(|&v| v != 0), "empty parts");
            }
        }
    }
}
