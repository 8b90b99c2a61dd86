//! The portable tier: the frame's [`Simd`] vocabulary in plain Rust, on arrays of eight `f32`
//! lanes. It uses no intrinsics and no target features: the compiler vectorises the lane loops
//! with the target's baseline instructions (NEON on aarch64, SSE2 on x86-64), so every
//! architecture runs the register tiles, row tails and partial panels of the x86 tiers.
//!
//! A multiply-add is a product then a sum, rounded twice, as in the scalar reference (Rust never
//! fuses `a * b + c` on its own). bf16 weights take the path of the x86 tiers without bf16 dot
//! products (`SLOTS_PER_PAIR = 2`): the frame widens them once per call to f32 panels and rounds
//! the activations to bf16, so the products are those of every other tier.

use super::frame::{self, Simd};
use super::{EdgeInputs, EdgeMlp, Epilogue, Operand};

/// f32 lanes per vector: two NEON or SSE registers, one AVX register.
const LANES: usize = 8;

/// One vector.
type Lanes = [f32; LANES];

/// The portable tier's token. Every CPU runs plain Rust, so it proves nothing and anyone in the
/// crate may make one.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Portable(());

/// `f` lane by lane: eight independent operations, which the compiler turns into vector
/// instructions.
#[inline(always)]
fn lanewise(a: Lanes, b: Lanes, f: impl Fn(f32, f32) -> f32) -> Lanes {
    let mut r = [0.0; LANES];
    for i in 0..LANES {
        r[i] = f(a[i], b[i]);
    }
    r
}

/// A bf16 value (its 16 bits) widened to f32, exactly.
#[inline(always)]
fn widen(b: u16) -> f32 {
    f32::from_bits((b as u32) << 16)
}

impl Portable {
    pub(crate) fn new() -> Self {
        Portable(())
    }

    /// [`frame::linear`] on this tier.
    pub(crate) fn linear(
        self,
        ops: &[Operand<'_>],
        bias: Option<&[f32]>,
        epi: &Epilogue<'_>,
        out: &mut [f32],
        scratch: &mut [f32],
    ) {
        // SAFETY: `Kernels::linear` validated every shape.
        unsafe { frame::linear(self, ops, bias, epi, out, scratch) }
    }

    /// [`frame::edge_mlp`] on this tier.
    pub(crate) fn edge_mlp(
        self,
        mlp: &EdgeMlp<'_>,
        edges: &EdgeInputs<'_>,
        latent: &mut [f32],
        aggregate: &mut [f32],
        scratch: &mut [f32],
    ) {
        // SAFETY: `Kernels::edge_mlp` validated every shape and index.
        unsafe { frame::edge_mlp(self, mlp, edges, latent, aggregate, scratch) }
    }
}

impl Simd for Portable {
    const LANES: usize = LANES;
    // Unused: the frame runs 8-lane tiers one panel (two vectors) at a time.
    const TILE_PANELS: usize = 1;
    const SLOTS_PER_PAIR: usize = 2;
    type V = Lanes;
    /// The even and the odd input of `LANES` columns, widened.
    type WP = (Lanes, Lanes);
    /// The two activations of an input pair.
    type XP = (f32, f32);

    #[inline(always)]
    fn zero(self) -> Lanes {
        [0.0; LANES]
    }
    #[inline(always)]
    fn splat(self, v: f32) -> Lanes {
        [v; LANES]
    }
    #[inline(always)]
    fn fma(self, a: Lanes, b: Lanes, c: Lanes) -> Lanes {
        let mut r = c;
        for i in 0..LANES {
            r[i] = a[i] * b[i] + c[i];
        }
        r
    }
    #[inline(always)]
    fn add(self, a: Lanes, b: Lanes) -> Lanes {
        lanewise(a, b, |x, y| x + y)
    }
    #[inline(always)]
    fn max(self, a: Lanes, b: Lanes) -> Lanes {
        lanewise(a, b, f32::max)
    }
    #[inline(always)]
    fn dot2(self, acc: Lanes, w: (Lanes, Lanes), x: (f32, f32)) -> Lanes {
        // The order of the x86 tiers' two FMAs: the even input first.
        let even = self.fma(w.0, self.splat(x.0), acc);
        self.fma(w.1, self.splat(x.1), even)
    }

    #[inline(always)]
    unsafe fn load(self, p: *const f32) -> Lanes {
        // SAFETY: the caller guarantees 8 readable floats at `p`; `[f32; 8]` has the alignment
        // of `f32`.
        unsafe { p.cast::<Lanes>().read() }
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f32, v: Lanes) {
        // SAFETY: the caller guarantees 8 writable floats at `p`; alignment as in `load`.
        unsafe { p.cast::<Lanes>().write(v) }
    }
    #[inline(always)]
    unsafe fn prefetch(self, _p: *const u8) {
        // A hint only; plain Rust has no stable way to give it.
    }
    #[inline(always)]
    unsafe fn load_w2(self, p: *const u16) -> (Lanes, Lanes) {
        // SAFETY: the caller guarantees 16 readable bf16 at `p`; `[u16; 16]` has the alignment
        // of `u16`.
        let w = unsafe { p.cast::<[u16; 2 * LANES]>().read() };
        (core::array::from_fn(|j| widen(w[2 * j])), core::array::from_fn(|j| widen(w[2 * j + 1])))
    }
    #[inline(always)]
    unsafe fn load_w_half(self, p: *const u16, half: usize) -> Lanes {
        // SAFETY: as `load_w2`.
        let w = unsafe { p.cast::<[u16; 2 * LANES]>().read() };
        // Any non-zero `half` is the odd input, as on the x86 tiers (and no index can pass 15).
        let odd = usize::from(half != 0);
        core::array::from_fn(|j| widen(w[2 * j + odd]))
    }
    #[inline(always)]
    unsafe fn bcast_x2(self, p: *const f32) -> (f32, f32) {
        // SAFETY: the caller guarantees 2 readable floats at `p`.
        unsafe { (*p, *p.add(1)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::{pack_bf16, packed_len_bf16, PackedBf16, PANEL};
    use alloc::vec;
    use half::bf16;

    #[test]
    fn kernels_portable_register_ops_are_lanewise() {
        let s = Portable::new();
        let a: Lanes = core::array::from_fn(|i| i as f32 - 3.5);
        let b: Lanes = core::array::from_fn(|i| 0.25 * i as f32 + 1.0);
        let c: Lanes = core::array::from_fn(|i| -(i as f32) * 0.5);
        assert_eq!(s.zero(), [0.0; 8]);
        assert_eq!(s.splat(2.5), [2.5; 8]);
        for i in 0..LANES {
            assert_eq!(s.fma(a, b, c)[i], a[i] * b[i] + c[i]);
            assert_eq!(s.add(a, b)[i], a[i] + b[i]);
            assert_eq!(s.max(a, s.zero())[i], a[i].max(0.0));
            let d = s.dot2(c, (a, b), (0.75, -1.25));
            assert_eq!(d[i], b[i] * -1.25 + (a[i] * 0.75 + c[i]));
        }
    }

    /// The pointer methods read and write exactly `LANES` values, and the bf16 ones take the
    /// packed pair layout apart as [`PackedBf16::get`] defines it.
    #[test]
    fn kernels_portable_pointer_ops_follow_the_layouts() {
        let s = Portable::new();
        let src: vec::Vec<f32> = (0..20).map(|i| i as f32 * 1.5 - 4.0).collect();
        let mut dst = vec![f32::NAN; 20];
        // SAFETY: offsets 3..11 and 5..13 are inside both 20-float buffers; the prefetch reads
        // nothing.
        let (v, pair) = unsafe {
            s.prefetch(src.as_ptr() as *const u8);
            let v = s.load(src.as_ptr().add(3));
            s.store(dst.as_mut_ptr().add(5), v);
            (v, s.bcast_x2(src.as_ptr().add(7)))
        };
        assert_eq!(v[..], src[3..11]);
        assert!(dst[..5].iter().chain(&dst[13..]).all(|x| x.is_nan()));
        assert_eq!(dst[5..13], src[3..11]);
        assert_eq!(pair, (src[7], src[8]));

        let (k, n) = (5, 20);
        let w: vec::Vec<f32> = (0..n * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let mut packed = vec![bf16::ZERO; packed_len_bf16(k, n)];
        pack_bf16(&w, n, k, 0..k, &mut packed).unwrap();
        let pw = PackedBf16::new(&packed, k, n).unwrap();
        let kp = k.next_multiple_of(2);
        let bits: vec::Vec<u16> = packed.iter().map(|b| b.to_bits()).collect();
        for o0 in (0..n.next_multiple_of(PANEL)).step_by(LANES) {
            for pr in 0..kp / 2 {
                let at = (o0 / PANEL) * PANEL * kp + pr * 2 * PANEL + (o0 % PANEL) * 2;
                // SAFETY: a pair-panel row holds `2 · PANEL` bf16 from `at - (o0 % PANEL) · 2`,
                // so 16 from `at` stay inside `bits`.
                let (both, even, odd) = unsafe {
                    let p = bits.as_ptr().add(at);
                    (s.load_w2(p), s.load_w_half(p, 0), s.load_w_half(p, 1))
                };
                assert_eq!((both.0, both.1), (even, odd));
                for j in 0..LANES {
                    let o = o0 + j;
                    let want = |kk: usize| if o < n && kk < k { pw.get(kk, o) } else { 0.0 };
                    assert_eq!(even[j], want(2 * pr), "o={o} pair {pr}");
                    assert_eq!(odd[j], want(2 * pr + 1), "o={o} pair {pr}");
                }
            }
        }
    }

    /// A bf16 product is exact in f32, so a fused and a separate multiply-add agree on it: with
    /// the same frame (the same summation order), the portable tier computes bf16 layers bit for
    /// bit as the x86 tiers that widen bf16 weights.
    #[test]
    fn kernels_portable_bf16_is_bitwise_the_widened_x86_tiers() {
        #[cfg(target_arch = "x86_64")]
        {
            use crate::kernels::{
                edge_mlp_scratch_len, linear_scratch_len, EdgeInputs, EdgeMlp, Epilogue, Kernels, LayerNorm, Operand,
                Tier, Weights,
            };
            use alloc::vec::Vec;
            let mut rng = crate::rng::Rng::new(5);
            let mut vals = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect() };
            let packed = |w: &[f32], k: usize, n: usize| {
                let mut b = vec![bf16::ZERO; packed_len_bf16(k, n)];
                pack_bf16(w, n, k, 0..k, &mut b).unwrap();
                b
            };
            let (n, rows, k1, k2) = (40, 13, 9, 16);
            let (w1, w2) = (packed(&vals(n * k1), k1, n), packed(&vals(n * k2), k2, n));
            let (x1, x2, bias, gamma, beta, out0) =
                (vals(rows * k1), vals(rows * k2), vals(n), vals(n), vals(n), vals(rows * n));
            let (h, k_e, edges, nodes) = (20, 9, 100, 7);
            let (e1, e2, e3) =
                (packed(&vals(h * k_e), k_e, h), packed(&vals(h * h), h, h), packed(&vals(k_e * h), h, k_e));
            let (b1, b2, b3, g3, be3) = (vals(h), vals(h), vals(k_e), vals(k_e), vals(k_e));
            let (pt, ps, latent0, agg0) = (vals(nodes * h), vals(nodes * h), vals(edges * k_e), vals(nodes * k_e));
            let target: Vec<u32> = (0..edges).map(|e| (e * nodes / edges) as u32).collect();
            let source: Vec<u32> = (0..edges).map(|e| ((e * 5) % nodes) as u32).collect();
            fn wb(b: &[bf16], k: usize, n: usize) -> Weights<'_> {
                Weights::Bf16(PackedBf16::new(b, k, n).unwrap())
            }
            let run = |k: Kernels| {
                let ops = [Operand { x: &x1, w: wb(&w1, k1, n) }, Operand { x: &x2, w: wb(&w2, k2, n) }];
                let ln = Some(LayerNorm { gamma: &gamma, beta: &beta });
                let mut got = Vec::new();
                for epi in [Epilogue::default(), Epilogue { relu: true, layer_norm: ln, residual: true }] {
                    let mut out = out0.clone();
                    let mut scratch = vec![0.0; linear_scratch_len(&ops, n)];
                    k.linear(&ops, Some(&bias), &epi, &mut out, &mut scratch).unwrap();
                    got.extend(out);
                }
                let mlp = EdgeMlp {
                    w1_edge: wb(&e1, k_e, h),
                    b1: &b1,
                    w2: wb(&e2, h, h),
                    b2: &b2,
                    w3: wb(&e3, h, k_e),
                    b3: &b3,
                    layer_norm: Some(LayerNorm { gamma: &g3, beta: &be3 }),
                };
                let inputs = EdgeInputs { p_target: &pt, p_source: &ps, target: &target, source: &source };
                let (mut latent, mut agg) = (latent0.clone(), agg0.clone());
                let mut scratch = vec![0.0; edge_mlp_scratch_len(k_e, h)];
                k.edge_mlp(&mlp, &inputs, &mut latent, &mut agg, &mut scratch).unwrap();
                got.extend(latent.into_iter().chain(agg));
                got.into_iter().map(f32::to_bits).collect::<Vec<u32>>()
            };
            let want = run(Kernels::with_tier(Tier::Portable).unwrap());
            for t in [Tier::Avx2Fma, Tier::Avx512] {
                match Kernels::with_tier(t) {
                    Some(k) => assert!(run(k) == want, "bf16 on {} differs from the portable tier", t.name()),
                    None => {
                        std::println!("kernels_portable_bf16_is_bitwise_the_widened_x86_tiers: SKIPPED {}", t.name())
                    }
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        std::println!("kernels_portable_bf16_is_bitwise_the_widened_x86_tiers: SKIPPED (no x86 tier here)");
    }
}
