//! The scans: points eight at a time against one query, each lane keeping its lowest
//! `(squared distance, index)`; the portable lanes, their AVX2 twin and the CPU probe.

use super::{dist2, fmin, LANES, NONE};
use crate::kernels::{Kernels, Tier};

/// Eight candidate `(squared distance, index)` pairs, one per lane, each the lexicographic
/// minimum of the points offered to its lane; the answer is the minimum over the lanes. A lane
/// starts at `(limit², NONE)`, so that a point exactly at the limit is taken (inclusive).
#[derive(Clone, Copy)]
pub(super) struct Lanes {
    d2: [f32; LANES],
    index: [u32; LANES],
}

/// The running answer of one search: candidates `(squared distance, index)` whose lexicographic
/// minimum is the answer, starting at `(limit², NONE)` (a point exactly at the limit is taken).
/// Two implementations, [`Lanes`] (portable) and `x86::Avx2Best`, give identical answers.
pub(super) trait Best {
    fn new(limit2: f32) -> Self;
    /// Offers one point.
    fn offer(&mut self, d2: f32, i: u32);
    /// Offers every point of `pts` (a multiple of `LANES` long); returns the new bound.
    fn scan(&mut self, pts: ScanPoints<'_>, q: [f32; 3]) -> f32;
    /// As [`scan`](Self::scan), faster when few points beat the bound (a tight bound); `bound` is
    /// the current [`bound`](Self::bound), which the caller already holds.
    fn scan_tight(&mut self, pts: ScanPoints<'_>, q: [f32; 3], _bound: f32) -> f32 {
        self.scan(pts, q)
    }
    /// The smallest squared distance held: no farther point can win.
    fn bound(&self) -> f32;
    /// The winner `(index, squared distance)`: lowest distance, then lowest index.
    fn best(&self) -> (u32, f32);
}

impl Best for Lanes {
    #[inline(always)]
    fn new(limit2: f32) -> Lanes {
        Lanes { d2: [limit2; LANES], index: [NONE; LANES] }
    }
    #[inline(always)]
    fn offer(&mut self, d2: f32, i: u32) {
        self.take(0, d2, i);
    }
    #[inline(always)]
    fn scan(&mut self, pts: ScanPoints<'_>, q: [f32; 3]) -> f32 {
        scan_portable(pts, q, self)
    }
    #[inline(always)]
    fn bound(&self) -> f32 {
        self.d2.iter().fold(f32::INFINITY, |m, &d| fmin(m, d))
    }
    #[inline(always)]
    fn best(&self) -> (u32, f32) {
        lexicographic_min(&self.d2, &self.index)
    }
}

/// The lowest `(d2, index)` over eight lanes.
#[inline(always)]
fn lexicographic_min(d2: &[f32; LANES], index: &[u32; LANES]) -> (u32, f32) {
    let mut best = (index[0], d2[0]);
    for l in 1..LANES {
        if d2[l] < best.1 || (d2[l] == best.1 && index[l] < best.0) {
            best = (index[l], d2[l]);
        }
    }
    best
}

impl Lanes {
    /// Offers one point to lane `l`.
    #[inline(always)]
    fn take(&mut self, l: usize, d2: f32, i: u32) {
        if d2 < self.d2[l] || (d2 == self.d2[l] && i < self.index[l]) {
            self.d2[l] = d2;
            self.index[l] = i;
        }
    }
}

/// Sorted coordinates `x, y, z` and point indices of one scan, a multiple of `LANES` long.
pub(super) type ScanPoints<'a> = (&'a [f32], &'a [f32], &'a [f32], &'a [u32]);

/// The portable twin of the AVX2 scan (`x86::Avx2Best`): the same lane updates, one lane at a
/// time.
#[inline(always)]
fn scan_portable((xs, ys, zs, idx): ScanPoints<'_>, q: [f32; 3], lanes: &mut Lanes) -> f32 {
    let groups = xs.chunks_exact(LANES).zip(ys.chunks_exact(LANES)).zip(zs.chunks_exact(LANES));
    for (((x, y), z), i) in groups.zip(idx.chunks_exact(LANES)) {
        for l in 0..LANES {
            lanes.take(l, dist2([x[l], y[l], z[l]], q), i[l]);
        }
    }
    lanes.bound()
}

/// Whether the scans may use AVX2: when the kernels' tier ([`Kernels::best`], probed once and
/// capped by `HOOD_KERNEL_TIER` / [`force_tier`](crate::kernels::force_tier)) is AVX2 or above,
/// so one setting picks the SIMD paths of the whole library.
pub(in crate::body) fn has_avx2() -> bool {
    Kernels::best().tier() >= Tier::Avx2Fma
}

#[cfg(target_arch = "x86_64")]
pub(super) mod x86 {
    use super::{Best, ScanPoints, LANES, NONE};
    use core::arch::x86_64::*;

    /// [`super::Lanes`] in two AVX2 registers. Only made inside functions compiled with AVX2
    /// (the `*_avx2` entry points of the grid, reached only when the CPU has it), into which all
    /// of its methods inline.
    #[derive(Clone, Copy)]
    pub(in super::super) struct Avx2Best {
        d2: __m256,
        index: __m256i,
    }

    impl Best for Avx2Best {
        #[inline(always)]
        fn new(limit2: f32) -> Avx2Best {
            // SAFETY (every `unsafe` of this impl): AVX2 instructions, executed only on a CPU
            // that has them (see the type's comment); loads and stores as commented.
            unsafe { Avx2Best { d2: _mm256_set1_ps(limit2), index: _mm256_set1_epi32(NONE as i32) } }
        }

        #[inline(always)]
        fn offer(&mut self, d2: f32, i: u32) {
            // Every lane takes the point if it is better: the minimum over lanes is the same.
            unsafe {
                (self.d2, self.index) = merge(self.d2, self.index, _mm256_set1_ps(d2), _mm256_set1_epi32(i as i32));
            }
        }

        /// [`super::scan_portable`] eight points at a time. Distances are `(dx² + dy²) + dz²` in
        /// that order, without FMA, so they equal the scalar ones bit for bit.
        #[inline(always)]
        fn scan(&mut self, (xs, ys, zs, idx): ScanPoints<'_>, q: [f32; 3]) -> f32 {
            let n = xs.len().min(ys.len()).min(zs.len()).min(idx.len()) / LANES * LANES;
            // Loads read `k..k + 8` with `k + 8 <= n`, inside all four slices.
            unsafe {
                let (qx, qy, qz) = (_mm256_set1_ps(q[0]), _mm256_set1_ps(q[1]), _mm256_set1_ps(q[2]));
                // A macro rather than a closure: closures do not inline into the AVX2 callers.
                macro_rules! group {
                    ($k:expr) => {{
                        let k = $k;
                        let dx = _mm256_sub_ps(_mm256_loadu_ps(xs.as_ptr().add(k)), qx);
                        let dy = _mm256_sub_ps(_mm256_loadu_ps(ys.as_ptr().add(k)), qy);
                        let dz = _mm256_sub_ps(_mm256_loadu_ps(zs.as_ptr().add(k)), qz);
                        let d = _mm256_add_ps(
                            _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                            _mm256_mul_ps(dz, dz),
                        );
                        (d, _mm256_loadu_si256(idx.as_ptr().add(k).cast()))
                    }};
                }
                let (mut bd, mut bi) = (self.d2, self.index);
                // Two accumulators, so that consecutive groups do not wait on each other's blends.
                let (mut bd1, mut bi1) = (bd, bi);
                let mut k = 0;
                while k + 2 * LANES <= n {
                    let (d, i) = group!(k);
                    (bd, bi) = merge(bd, bi, d, i);
                    let (d, i) = group!(k + LANES);
                    (bd1, bi1) = merge(bd1, bi1, d, i);
                    k += 2 * LANES;
                }
                if k < n {
                    let (d, i) = group!(k);
                    (bd, bi) = merge(bd, bi, d, i);
                }
                (self.d2, self.index) = merge(bd, bi, bd1, bi1);
            }
            self.bound()
        }

        /// Groups with no point within the bound cost one compare; only the others are merged
        /// into the lanes (a point beyond the lowest lane can never be the answer).
        #[inline(always)]
        fn scan_tight(&mut self, (xs, ys, zs, idx): ScanPoints<'_>, q: [f32; 3], bound: f32) -> f32 {
            let n = xs.len().min(ys.len()).min(zs.len()).min(idx.len()) / LANES * LANES;
            // Loads read `k..k + 8` with `k + 8 <= n`, inside all four slices.
            unsafe {
                let (qx, qy, qz) = (_mm256_set1_ps(q[0]), _mm256_set1_ps(q[1]), _mm256_set1_ps(q[2]));
                // The caller's copy of the bound: no horizontal minimum before the first group.
                let mut bound = _mm256_set1_ps(bound);
                let mut k = 0;
                while k < n {
                    let dx = _mm256_sub_ps(_mm256_loadu_ps(xs.as_ptr().add(k)), qx);
                    let dy = _mm256_sub_ps(_mm256_loadu_ps(ys.as_ptr().add(k)), qy);
                    let dz = _mm256_sub_ps(_mm256_loadu_ps(zs.as_ptr().add(k)), qz);
                    let d = _mm256_add_ps(
                        _mm256_add_ps(_mm256_mul_ps(dx, dx), _mm256_mul_ps(dy, dy)),
                        _mm256_mul_ps(dz, dz),
                    );
                    if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(d, bound)) != 0 {
                        let i = _mm256_loadu_si256(idx.as_ptr().add(k).cast());
                        (self.d2, self.index) = merge(self.d2, self.index, d, i);
                        bound = _mm256_set1_ps(self.bound());
                    }
                    k += LANES;
                }
                _mm256_cvtss_f32(bound)
            }
        }

        #[inline(always)]
        fn bound(&self) -> f32 {
            unsafe {
                let d = self.d2;
                let m = _mm_min_ps(_mm256_castps256_ps128(d), _mm256_extractf128_ps::<1>(d));
                let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
                _mm_cvtss_f32(_mm_min_ss(m, _mm_shuffle_ps::<1>(m, m)))
            }
        }

        /// Merges the lanes with themselves permuted (halves, pairs, neighbours swapped): every
        /// lane then holds the minimum, without branches.
        #[inline(always)]
        fn best(&self) -> (u32, f32) {
            unsafe {
                let (mut d, mut i) = (self.d2, self.index);
                (d, i) = merge(d, i, _mm256_permute2f128_ps::<0x01>(d, d), _mm256_permute2f128_si256::<0x01>(i, i));
                (d, i) = merge(d, i, _mm256_permute_ps::<0x4E>(d), _mm256_shuffle_epi32::<0x4E>(i));
                (d, i) = merge(d, i, _mm256_permute_ps::<0xB1>(d), _mm256_shuffle_epi32::<0xB1>(i));
                (_mm256_extract_epi32::<0>(i) as u32, _mm256_cvtss_f32(d))
            }
        }
    }

    /// Lane-wise lexicographic minimum of `(bd, bi)` and `(d, i)`.
    #[inline(always)]
    pub(in super::super) unsafe fn merge(bd: __m256, bi: __m256i, d: __m256, i: __m256i) -> (__m256, __m256i) {
        // SAFETY: AVX2 instructions, only reached on a CPU that has them.
        unsafe {
            let sign = _mm256_set1_epi32(i32::MIN);
            let lt = _mm256_cmp_ps::<_CMP_LT_OQ>(d, bd);
            let eq = _mm256_cmp_ps::<_CMP_EQ_OQ>(d, bd);
            // Unsigned `i < bi` as a signed compare of sign-flipped values.
            let lower = _mm256_cmpgt_epi32(_mm256_xor_si256(bi, sign), _mm256_xor_si256(i, sign));
            let take = _mm256_or_ps(lt, _mm256_and_ps(eq, _mm256_castsi256_ps(lower)));
            let bd = _mm256_blendv_ps(bd, d, take);
            let bi = _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(bi), _mm256_castsi256_ps(i), take));
            (bd, bi)
        }
    }
}
