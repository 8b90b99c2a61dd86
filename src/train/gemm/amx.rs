//! The trainer's products on the AMX tiles, in split bf16.
//!
//! A product on bf16 operands keeps 8 significant bits of each (up to 0.2 % error), twenty times
//! the bound the trainer's gradients are held to. Split in two (`x = hi + lo`, three products)
//! is not enough either: the gradients of a training step sum and normalise products through
//! many layers, and on the software model of the tiles that split missed the bound by more than
//! a hundred times (`train_fast_matches_generic`). So each f32 operand is split in three bf16,
//! `x = h + m + l` (`h` the nearest bf16 to `x`, `m` the nearest to `x - h`, `l` to
//! `x - h - m`; what is left is below about `2^-26 |x|`), and each product is taken as the six
//! terms above about `2^-24` of it: `h·h + h·m + m·h + m·m + h·l + l·h`, each accumulated in f32
//! on the tiles. That is about f32's precision for six times the bf16 work, which pays only
//! where the tile unit's rate (about 16 times the f32 vector rate on Intel's AMX cores) covers it
//! and the splitting; [`super::Gemm::best`] measures it before choosing it.
//!
//! **Layouts** (as [`crate::kernels`]' AMX path): an A tile is 16 rows of 16 bf16 pairs along the
//! sum (64 bytes a row); a B tile is 16 pair rows of 16 columns × (even, odd) input. Operands are
//! split and packed into thread-local scratch on each call: for `C += A·B`, `B` (the weights,
//! `k × n`) once per call into panels of 16 columns and `A` 16 rows at a time; for `C += Aᵀ·B`
//! (weight gradients, a sum over rows), both operands a block of [`TN_ROWS`] rows at a time, `A`
//! transposed. Sizes are padded with zeros to whole tiles.
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
/// Rows of `A` and `B` split and packed per block of [`tn`] (a multiple of `2 · PAIRS`).
pub(super) const TN_ROWS: usize = 512;

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
    acc: Vec<f32>,
}

std::thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

fn zeros<T: Copy + Default>(v: &mut Vec<T>, n: usize) {
    v.clear();
    v.resize(n, T::default());
}

/// 16 × 16 f32 of one output tile, as `tilestored` writes it.
#[repr(C, align(64))]
struct CTile([f32; ROWS * COLS]);

/// Splits `value(i, j)` (input `i` of the sum, column `j`; zero outside the operand) into B-tile
/// panels of `pairs` pair rows: panel `p`, pair row `q` (inputs `2q` and `2q + 1`), column `j`
/// at `(p · pairs + q) · 16 + j`, one buffer per part.
fn pack_b(panels: usize, pairs: usize, b: &mut [Vec<u32>; 3], value: impl Fn(usize, usize) -> f32) {
    b.iter_mut().for_each(|v| zeros(v, panels * pairs * COLS));
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
/// (checked by the caller); `m`, `n` and `k` are not zero.
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
        s.a.iter_mut().for_each(|v| zeros(v, ROWS * pairs));
        let mut tiles = [CTile([0.0; ROWS * COLS]), CTile([0.0; ROWS * COLS])];
        // SAFETY: the caller's contract makes the unit available; it is released below.
        unsafe { U::configure() };
        // SAFETY: as above, configured.
        let u = &mut unsafe { U::on_this_thread() };
        for r0 in (0..m).step_by(ROWS) {
            let nr = (m - r0).min(ROWS);
            for r in 0..ROWS {
                for q in 0..pairs {
                    let at = |kk: usize| if r < nr && kk < k { a.data[(r0 + r) * a.ld + kk] } else { 0.0 };
                    let (even, odd) = (split(at(2 * q)), split(at(2 * q + 1)));
                    for part in 0..3 {
                        s.a[part][r * pairs + q] = pair(even[part], odd[part]);
                    }
                }
            }
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

/// `C[ka×n] += Aᵀ · B` with `A` `m × ka` and `B` `m × n`, on the tile unit `U` (see
/// [`super::Gemm::tn`]).
///
/// # Safety
/// As [`nn`]; `m`, `ka` and `n` are not zero.
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn tn<U: TileUnit>(m: usize, ka: usize, n: usize, a: Mat<'_>, b: Mat<'_>, c: &mut [f32], ldc: usize) {
    let row_tiles = ka.div_ceil(ROWS);
    let panels = n.div_ceil(COLS);
    SCRATCH.with_borrow_mut(|s| {
        let width = panels * COLS;
        zeros(&mut s.acc, row_tiles * ROWS * width);
        let mut tiles = [CTile([0.0; ROWS * COLS]), CTile([0.0; ROWS * COLS])];
        // SAFETY: the caller's contract makes the unit available; it is released below.
        unsafe { U::configure() };
        // SAFETY: as above, configured.
        let u = &mut unsafe { U::on_this_thread() };
        for r0 in (0..m).step_by(TN_ROWS) {
            let rows = (m - r0).min(TN_ROWS);
            let pairs = rows.div_ceil(2 * PAIRS) * PAIRS;
            let in_b = |r: usize, j: usize| if r < rows && j < n { b.data[(r0 + r) * b.ld + j] } else { 0.0 };
            pack_b(panels, pairs, &mut s.b, in_b);
            // Aᵀ: row `o`, pair `q` holds inputs (rows) `2q` and `2q + 1` of column `o`.
            s.a.iter_mut().for_each(|v| zeros(v, row_tiles * ROWS * pairs));
            for q in 0..pairs.min(rows.div_ceil(2)) {
                for o in 0..ka {
                    let at = |r: usize| if r < rows { a.data[(r0 + r) * a.ld + o] } else { 0.0 };
                    let (even, odd) = (split(at(2 * q)), split(at(2 * q + 1)));
                    for part in 0..3 {
                        s.a[part][o * pairs + q] = pair(even[part], odd[part]);
                    }
                }
            }
            for t in 0..row_tiles {
                let a_parts = [0, 1, 2].map(|part| s.a[part][t * ROWS * pairs..].as_ptr());
                for p0 in (0..panels).step_by(2) {
                    let two = p0 + 1 < panels;
                    // SAFETY: configured; row tile `t` of each part has 16 rows of `pairs` slots.
                    unsafe { row_tile(u, (a_parts, pairs), &s.b, (p0, two), pairs, &mut tiles) };
                    for (pj, tile) in tiles.iter().enumerate().take(1 + usize::from(two)) {
                        for r in 0..ROWS {
                            let row = &mut s.acc[(t * ROWS + r) * width + (p0 + pj) * COLS..][..COLS];
                            for (acc, v) in row.iter_mut().zip(&tile.0[r * COLS..(r + 1) * COLS]) {
                                *acc += v;
                            }
                        }
                    }
                }
            }
        }
        // SAFETY: configured above on this thread.
        unsafe { U::release() };
        for o in 0..ka {
            for (cv, v) in c[o * ldc..o * ldc + n].iter_mut().zip(&s.acc[o * width..]) {
                *cv += v;
            }
        }
    });
}
