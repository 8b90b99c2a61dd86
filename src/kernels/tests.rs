//! Every available tier against the scalar reference, on seeded random data and awkward sizes.

use alloc::format;
use alloc::vec;
use alloc::vec::Vec;
use std::println;

use half::bf16;

use super::*;

struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[-a, a)`, never exactly zero in practice.
    fn uniform(&mut self, a: f32) -> f32 {
        ((self.next_u64() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * a
    }
    fn vec(&mut self, len: usize, a: f32) -> Vec<f32> {
        (0..len).map(|_| self.uniform(a)).collect()
    }
}

const ROWS: [usize; 7] = [0, 1, 5, 15, 17, 33, 100];
/// Inputs: odd counts (a padded pair), and 40 and 66 (20 and 33 pairs: whole AMX tiles of 16
/// pairs with some left over, which that tier adds with `vdpbf16ps`).
const K_SET: [usize; 11] = [3, 9, 12, 24, 32, 40, 64, 66, 128, 384, 512];
/// Outputs: partial panels of 16 columns, and 17 and 40 (a second AMX output tile that is
/// partial).
const N_SET: [usize; 8] = [3, 9, 17, 32, 40, 64, 128, 144];

/// SIMD tiers this host runs; prints the ones it must skip. Without AMX, the AMX path runs on
/// the software model of the tiles where the CPU has AVX-512-BF16 (its vector half).
fn simd_tiers(test: &str) -> Vec<Kernels> {
    let mut v = Vec::new();
    for t in Tier::ALL.into_iter().skip(1) {
        match Kernels::with_tier(t) {
            Some(k) => v.push(k),
            #[cfg(target_arch = "x86_64")]
            None if t == Tier::Amx && Kernels::amx_emulated().is_some() => {
                println!("{test}: tier amx on emulated tiles (this CPU lacks AMX)");
                v.extend(Kernels::amx_emulated());
            }
            None => println!("{test}: SKIPPED tier {} (this CPU lacks it)", t.name()),
        }
    }
    v
}

/// A random `[n, k]` weight matrix with PyTorch-like scale, packed in both precisions.
struct Layer {
    w: Vec<f32>,
    f: Vec<f32>,
    b: Vec<bf16>,
    k: usize,
    n: usize,
}

impl Layer {
    fn new(rng: &mut Rng, k: usize, n: usize) -> Layer {
        let w = rng.vec(n * k, 1.0 / (k as f32).sqrt());
        let mut f = vec![0.0; packed_len_f32(k, n)];
        pack_f32(&w, n, k, 0..k, &mut f).unwrap();
        let mut b = vec![bf16::ZERO; packed_len_bf16(k, n)];
        pack_bf16(&w, n, k, 0..k, &mut b).unwrap();
        Layer { w, f, b, k, n }
    }
    fn weights(&self, bf: bool) -> Weights<'_> {
        if bf {
            Weights::Bf16(PackedBf16::new(&self.b, self.k, self.n).unwrap())
        } else {
            Weights::F32(PackedF32::new(&self.f, self.k, self.n).unwrap())
        }
    }
}

#[track_caller]
fn assert_close(what: &str, got: &[f32], want: &[f32], tol: f32) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(g.is_finite(), "{what}: element {i} is {g}");
        assert!((g - w).abs() <= tol * (1.0 + w.abs()), "{what}: element {i}: got {g}, want {w} (tol {tol})");
    }
}

fn epilogues<'a>(gamma: &'a [f32], beta: &'a [f32]) -> Vec<Epilogue<'a>> {
    let mut v = Vec::new();
    for relu in [false, true] {
        for ln in [false, true] {
            for residual in [false, true] {
                let layer_norm = ln.then_some(LayerNorm { gamma, beta });
                v.push(Epilogue { relu, layer_norm, residual });
            }
        }
    }
    v
}

fn run_linear(k: &Kernels, ops: &[Operand<'_>], bias: Option<&[f32]>, epi: &Epilogue<'_>, out0: &[f32]) -> Vec<f32> {
    let n = ops[0].w.n();
    let mut out = out0.to_vec();
    let mut scratch = vec![f32::NAN; linear_scratch_len(ops, n)];
    k.linear(ops, bias, epi, &mut out, &mut scratch).unwrap();
    out
}

fn check_linear_tiers(bf: bool, test: &str) {
    let tiers = simd_tiers(test);
    let mut rng = Rng(if bf { 0xB16 } else { 0xF32 });
    let mut cases = 0;
    for &k_in in &K_SET {
        for &n in &N_SET {
            let layer = Layer::new(&mut rng, k_in, n);
            let bias = rng.vec(n, 0.5);
            let gamma = rng.vec(n, 1.0);
            let beta = rng.vec(n, 0.5);
            // Every epilogue on a few sizes, plain and LayerNorm on all row counts.
            let all_epi = epilogues(&gamma, &beta);
            for &rows in &ROWS {
                let x = rng.vec(rows * k_in, 1.0);
                let out0 = rng.vec(rows * n, 1.0);
                let ops = [Operand { x: &x, w: layer.weights(bf) }];
                let epis: &[Epilogue<'_>] = if k_in <= 64 || rows == 17 { &all_epi } else { &all_epi[..1] };
                for epi in epis {
                    for b in [Some(&bias[..]), None] {
                        let want = run_linear(&Kernels::scalar(), &ops, b, epi, &out0);
                        for t in &tiers {
                            let got = run_linear(t, &ops, b, epi, &out0);
                            let what = format!("{test} {} k={k_in} n={n} rows={rows} {epi:?}", t.tier().name());
                            assert_close(&what, &got, &want, 5e-5);
                            cases += 1;
                        }
                    }
                }
            }
        }
    }
    println!("{test}: {cases} tier/case comparisons");
}

#[test]
fn kernels_report_tiers() {
    println!("detected tier: {}", detected_tier().name());
    for t in Tier::ALL {
        let status = if Kernels::with_tier(t).is_some() { "available" } else { "SKIPPED (host lacks it)" };
        println!("tier {:>10}: {status}", t.name());
    }
    assert!(Kernels::with_tier(Tier::Scalar).is_some());
    assert!(Kernels::with_tier(detected_tier()).is_some());
    // The portable tier runs everywhere and is the best off x86-64.
    assert!(Kernels::with_tier(Tier::Portable).is_some());
    assert!(detected_tier() >= Tier::Portable);
    if cfg!(not(target_arch = "x86_64")) {
        assert_eq!(detected_tier(), Tier::Portable);
    }
}

/// Tiers order by capability, not by their numeric values (stable; the portable tier, added
/// last, is 6): it sits between the scalar tier and every x86 tier, so `>= Tier::Avx2Fma` never
/// takes it for AVX2, and a cap of `portable` on an x86 CPU selects it.
#[test]
fn kernels_tiers_order_by_capability() {
    assert!(Tier::ALL.windows(2).all(|w| w[0] < w[1]), "Tier::ALL is lowest first");
    assert_eq!(Tier::ALL.map(|t| t as u8), [1, 6, 2, 3, 4, 5]);
    assert!(Tier::Scalar < Tier::Portable && Tier::Portable < Tier::Avx2Fma);
    assert_eq!(Tier::Amx.min(Tier::Portable), Tier::Portable);
    for t in Tier::ALL {
        assert_eq!(Tier::from_name(t.name()), Some(t));
        assert_eq!(Tier::from_u8(t as u8), Some(t));
    }
    assert_eq!(Tier::from_name(" Portable\n"), Some(Tier::Portable));
    assert_eq!(Tier::from_name("AVX2"), Some(Tier::Avx2Fma));
}

#[test]
fn kernels_force_tier_caps_best() {
    let _guard = CAP_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    // Restores the cap it found (a run under HOOD_KERNEL_TIER keeps it for the other tests).
    let before = super::tier_cap();
    force_tier(Some(Tier::Scalar));
    assert_eq!(Kernels::best().tier(), Tier::Scalar);
    // Capped at portable: the kernels (bf16 weights too) and the trainer's products leave AVX2.
    force_tier(Some(Tier::Portable));
    assert_eq!(Kernels::best().tier(), Tier::Portable);
    assert_eq!((bf16_choice().tier, Kernels::best_bf16().tier()), (Tier::Portable, Tier::Portable));
    assert_eq!((f32_choice().tier, Kernels::best_f32().tier()), (Tier::Portable, Tier::Portable));
    assert_eq!(f32_choice().reason, ChoiceReason::Capped);
    #[cfg(feature = "train")]
    assert!(!crate::train::gemm::Gemm::best().is_simd(), "the trainer's GEMM uses SIMD under the portable cap");
    #[cfg(feature = "train")]
    if detected_tier() >= Tier::Avx512 {
        force_tier(Some(Tier::Avx2Fma));
        assert_eq!(crate::train::gemm::Gemm::best().tier(), Tier::Avx2Fma, "the trainer's GEMM above the AVX2 cap");
        force_tier(None);
        // AVX-512 unless AVX2 measured faster, or the AMX tiles where they are usable and
        // measured faster still.
        let tiles = crate::train::gemm::Gemm::tile_choice();
        assert_eq!(tiles.is_some(), detected_tier() == Tier::Amx);
        let expected = if tiles.is_some_and(|c| c.chosen) { Tier::Amx } else { f32_choice().tier.min(Tier::Avx512) };
        assert_eq!(crate::train::gemm::Gemm::best().tier(), expected);
        if detected_tier() == Tier::Amx {
            force_tier(Some(Tier::Amx));
            assert_eq!(crate::train::gemm::Gemm::best().tier(), Tier::Amx, "the trainer's GEMM under the AMX cap");
            force_tier(Some(Tier::Avx512Bf16));
            assert_eq!(crate::train::gemm::Gemm::best().tier(), Tier::Avx512, "the trainer's GEMM below the AMX cap");
            force_tier(None);
        }
    }
    force_tier(None);
    assert_eq!(Kernels::best().tier(), detected_tier());
    force_tier(before);
}

#[test]
fn kernels_pack_layout_matches_definition() {
    let mut rng = Rng(7);
    for (n_out, n_in, cols) in [(3usize, 9usize, 0..9), (16, 12, 0..12), (33, 40, 5..28), (128, 384, 256..384)] {
        let w = rng.vec(n_out * n_in, 1.0);
        let k = cols.len();
        let mut f = vec![f32::NAN; packed_len_f32(k, n_out)];
        pack_f32(&w, n_out, n_in, cols.clone(), &mut f).unwrap();
        let mut b = vec![bf16::NAN; packed_len_bf16(k, n_out)];
        pack_bf16(&w, n_out, n_in, cols.clone(), &mut b).unwrap();
        let (pf, pb) = (PackedF32::new(&f, k, n_out).unwrap(), PackedBf16::new(&b, k, n_out).unwrap());
        let kp = k.next_multiple_of(2);
        for o in 0..padded_cols(n_out) {
            for kk in 0..kp {
                let want = if o < n_out && kk < k { w[o * n_in + cols.start + kk] } else { 0.0 };
                let (p, j) = (o / PANEL, o % PANEL);
                if kk < k {
                    assert_eq!(f[p * PANEL * k + kk * PANEL + j], want);
                    assert_eq!(pf.get(kk, o), want);
                }
                let bv = b[p * PANEL * kp + (kk / 2) * 2 * PANEL + 2 * j + kk % 2];
                assert_eq!(bv, bf16::from_f32(want), "bf16 o={o} kk={kk}");
            }
        }
        assert!(f.iter().all(|v| v.is_finite()) && b.iter().all(|v| v.is_finite()));
        assert_eq!(pb.get(0, 0), bf16::from_f32(w[cols.start]).to_f32());
        // Widened once: the f32 layout of exactly the bf16 values, padding zero.
        let mut wide = vec![f32::NAN; packed_len_f32(k, n_out)];
        let pw = pb.widen_into(&mut wide).unwrap();
        assert_eq!((pw.k(), pw.n()), (k, n_out));
        for o in 0..padded_cols(n_out) {
            for kk in 0..k {
                assert_eq!(pw.get(kk, o).to_bits(), pb.get(kk, o).to_bits(), "widened o={o} kk={kk}");
            }
        }
        assert!(pb.widen_into(&mut wide[1..]).is_err());
    }
    // Bad inputs are errors.
    let w = vec![1.0; 12];
    assert!(pack_f32(&w, 3, 4, 0..4, &mut [0.0; 15]).is_err());
    assert!(pack_f32(&w, 3, 4, 2..5, &mut [0.0; 48]).is_err());
    assert!(pack_f32(&w, 4, 4, 0..4, &mut [0.0; 64]).is_err());
    assert!(PackedF32::new(&[0.0; 10], 1, 16).is_err());
}

#[test]
fn kernels_round_bf16_matches_half() {
    let mut rng = Rng(3);
    for _ in 0..100_000 {
        let x = f32::from_bits(rng.next_u64() as u32);
        if x.is_finite() {
            assert_eq!(frame::round_bf16(x).to_bits(), bf16::from_f32(x).to_f32().to_bits(), "x = {x:e}");
        }
    }
}

/// The native pairing of bf16 activations (`vcvtneps2bf16`) writes the same slots as the
/// portable one, for every length up to several blocks plus odd tails, on random bit patterns
/// of every normal magnitude (subnormals are flushed by the instruction, as documented).
#[test]
fn kernels_bf16_pair_prep_matches_portable() {
    #[cfg(target_arch = "x86_64")]
    {
        use super::frame::Simd;
        let Some(tok) = x86::Avx512Bf16::new() else {
            println!("kernels_bf16_pair_prep_matches_portable: SKIPPED (no AVX-512-BF16 here)");
            return;
        };
        let mut rng = Rng(17);
        for len in 0..=70usize {
            for _ in 0..50 {
                let src: Vec<f32> = (0..len)
                    .map(|_| loop {
                        let x = f32::from_bits(rng.next_u64() as u32);
                        if x.is_normal() {
                            break x;
                        }
                    })
                    .collect();
                let slots = len.div_ceil(2);
                let (mut native, mut portable) = (vec![f32::NAN; slots + 3], vec![f32::NAN; slots + 3]);
                tok.prep_bf16(&src, &mut native);
                frame::pack_bf16_pairs(&src, &mut portable);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&native), bits(&portable), "len {len}");
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    println!("kernels_bf16_pair_prep_matches_portable: SKIPPED (not x86-64)");
}

/// Row-batched LayerNorm statistics (the portable entry, and each x86 tier's four-row 256-bit
/// form) are bitwise the one-row statistics, for widths with and without a tail and row counts around the batch of 4.
#[test]
fn kernels_layer_norm_stats_rows_match_one_row() {
    use super::frame::{layer_norm_stats, layer_norm_stats_rows, Simd};
    type Bits = Vec<(u32, u32)>;
    fn bits(v: &[(f32, f32)]) -> Bits {
        v.iter().map(|(m, s)| (m.to_bits(), s.to_bits())).collect()
    }
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn tier<S: Simd>(name: &str, tok: Option<S>, y: &[f32], width: usize, want: &Bits) {
        let Some(t) = tok else {
            println!("kernels_layer_norm_stats_rows_match_one_row: {name} SKIPPED");
            return;
        };
        let mut got = vec![(f32::NAN, f32::NAN); want.len()];
        t.layer_norm_stats_rows(y, width, &mut got);
        assert_eq!(&bits(&got), want, "{name}, width {width}, rows {}", want.len());
    }
    let mut rng = Rng(23);
    for width in [1usize, 3, 7, 8, 9, 16, 31, 64, 128, 131] {
        for rows in [0usize, 1, 3, 4, 5, 9, 96] {
            let y: Vec<f32> = (0..rows * width).map(|i| rng.uniform(2.0) + (i % 5) as f32).collect();
            let one: Vec<(f32, f32)> = y.chunks_exact(width).map(layer_norm_stats).collect();
            let want = bits(&one);
            let mut got = vec![(f32::NAN, f32::NAN); rows];
            layer_norm_stats_rows(&y, width, &mut got);
            assert_eq!(bits(&got), want, "portable, width {width}, rows {rows}");
            #[cfg(target_arch = "x86_64")]
            {
                tier("avx2", x86::Avx2Fma::new(), &y, width, &want);
                tier("avx512", x86::Avx512::new(), &y, width, &want);
                tier("avx512bf16", x86::Avx512Bf16::new(), &y, width, &want);
            }
        }
    }
}

#[test]
fn kernels_linear_f32_tiers_match_scalar() {
    check_linear_tiers(false, "kernels_linear_f32_tiers_match_scalar");
}

#[test]
fn kernels_linear_bf16_tiers_match_scalar() {
    check_linear_tiers(true, "kernels_linear_bf16_tiers_match_scalar");
}

/// The scalar reference itself against a from-the-definition product on unpacked `W`, and bf16
/// against f32 within the stated bound: `|y_bf16 - y_f32| <= 2^-8 · Σ|x_k w_k| + 1e-5` (each
/// product's two bf16 roundings are relative errors of at most 2^-9 each).
#[test]
fn kernels_linear_scalar_matches_definition_and_bf16_bound() {
    let mut rng = Rng(11);
    for (k_in, n, rows) in [(9, 3, 7), (24, 128, 17), (384, 128, 5), (12, 64, 33)] {
        let layer = Layer::new(&mut rng, k_in, n);
        let bias = rng.vec(n, 0.5);
        let x = rng.vec(rows * k_in, 1.0);
        let epi = Epilogue::default();
        let zeros = vec![0.0; rows * n];
        let f =
            run_linear(&Kernels::scalar(), &[Operand { x: &x, w: layer.weights(false) }], Some(&bias), &epi, &zeros);
        let b = run_linear(&Kernels::scalar(), &[Operand { x: &x, w: layer.weights(true) }], Some(&bias), &epi, &zeros);
        for r in 0..rows {
            for o in 0..n {
                let xs = &x[r * k_in..(r + 1) * k_in];
                let ws = &layer.w[o * k_in..(o + 1) * k_in];
                let exact: f64 = bias[o] as f64 + xs.iter().zip(ws).map(|(a, b)| *a as f64 * *b as f64).sum::<f64>();
                let abs: f32 = xs.iter().zip(ws).map(|(a, b)| (a * b).abs()).sum();
                let y = f[r * n + o];
                assert!((y as f64 - exact).abs() <= 1e-5 * (1.0 + abs as f64), "f32 {y} vs {exact}");
                let yb = b[r * n + o];
                assert!((yb - y).abs() <= abs / 256.0 + 1e-5, "bf16 {yb} vs f32 {y}, bound {}", abs / 256.0);
            }
        }
    }
}

/// Several operands (a concatenated input, never materialised) equal one operand over the concat.
#[test]
fn kernels_linear_operands_sum_like_concat() {
    let mut rng = Rng(21);
    let (n, rows) = (64, 23);
    let widths = [64usize, 64, 9, 12];
    let k_total: usize = widths.iter().sum();
    let w = rng.vec(n * k_total, 0.1);
    let xs: Vec<Vec<f32>> = widths.iter().map(|&k| rng.vec(rows * k, 1.0)).collect();
    let mut concat = vec![0.0; rows * k_total];
    let mut parts = Vec::new();
    let mut c0 = 0;
    for (i, &k) in widths.iter().enumerate() {
        for r in 0..rows {
            concat[r * k_total + c0..r * k_total + c0 + k].copy_from_slice(&xs[i][r * k..(r + 1) * k]);
        }
        let mut f = vec![0.0; packed_len_f32(k, n)];
        pack_f32(&w, n, k_total, c0..c0 + k, &mut f).unwrap();
        let mut b = vec![bf16::ZERO; packed_len_bf16(k, n)];
        pack_bf16(&w, n, k_total, c0..c0 + k, &mut b).unwrap();
        parts.push((f, b, k));
        c0 += k;
    }
    let full = {
        let mut f = vec![0.0; packed_len_f32(k_total, n)];
        pack_f32(&w, n, k_total, 0..k_total, &mut f).unwrap();
        f
    };
    let bias = rng.vec(n, 0.5);
    let gamma = rng.vec(n, 1.0);
    let beta = rng.vec(n, 1.0);
    let epi = Epilogue { relu: true, layer_norm: Some(LayerNorm { gamma: &gamma, beta: &beta }), residual: true };
    let out0 = rng.vec(rows * n, 1.0);
    let one = [Operand { x: &concat, w: Weights::F32(PackedF32::new(&full, k_total, n).unwrap()) }];
    let want = run_linear(&Kernels::scalar(), &one, Some(&bias), &epi, &out0);
    let f32_ops: Vec<Operand<'_>> = parts
        .iter()
        .zip(&xs)
        .map(|((f, _, k), x)| Operand { x, w: Weights::F32(PackedF32::new(f, *k, n).unwrap()) })
        .collect();
    let bf_ops: Vec<Operand<'_>> = parts
        .iter()
        .zip(&xs)
        .map(|((_, b, k), x)| Operand { x, w: Weights::Bf16(PackedBf16::new(b, *k, n).unwrap()) })
        .collect();
    let bf_want = run_linear(&Kernels::scalar(), &bf_ops, Some(&bias), &epi, &out0);
    let mut tiers = simd_tiers("kernels_linear_operands_sum_like_concat");
    tiers.insert(0, Kernels::scalar());
    for t in &tiers {
        assert_close("operands f32", &run_linear(t, &f32_ops, Some(&bias), &epi, &out0), &want, 5e-5);
        assert_close("operands bf16", &run_linear(t, &bf_ops, Some(&bias), &epi, &out0), &bf_want, 5e-5);
    }
    // bf16 LayerNorm outputs are O(1): loose agreement with f32.
    assert_close("operands bf16 vs f32", &bf_want, &want, 3e-2);
}

struct EdgeCase {
    l1: Layer,
    l2: Layer,
    l3: Layer,
    b1: Vec<f32>,
    b2: Vec<f32>,
    b3: Vec<f32>,
    gamma: Vec<f32>,
    beta: Vec<f32>,
    pt: Vec<f32>,
    ps: Vec<f32>,
    tgt: Vec<u32>,
    src: Vec<u32>,
    latent: Vec<f32>,
    n_t: usize,
}

impl EdgeCase {
    fn new(rng: &mut Rng, k_e: usize, h: usize, edges: usize) -> EdgeCase {
        let (n_t, n_s) = (edges / 3 + 2, edges / 2 + 3);
        let mut tgt: Vec<u32> = (0..edges).map(|_| (rng.next_u64() % n_t as u64) as u32).collect();
        tgt.sort_unstable();
        EdgeCase {
            l1: Layer::new(rng, k_e, h),
            l2: Layer::new(rng, h, h),
            l3: Layer::new(rng, h, k_e),
            b1: rng.vec(h, 0.3),
            b2: rng.vec(h, 0.3),
            b3: rng.vec(k_e, 0.3),
            gamma: rng.vec(k_e, 1.0),
            beta: rng.vec(k_e, 0.5),
            pt: rng.vec(n_t * h, 1.0),
            ps: rng.vec(n_s * h, 1.0),
            src: (0..edges).map(|_| (rng.next_u64() % n_s as u64) as u32).collect(),
            tgt,
            latent: rng.vec(edges * k_e, 1.0),
            n_t,
        }
    }
    fn mlp(&self, bf: bool, ln: bool) -> EdgeMlp<'_> {
        EdgeMlp {
            w1_edge: self.l1.weights(bf),
            b1: &self.b1,
            w2: self.l2.weights(bf),
            b2: &self.b2,
            w3: self.l3.weights(bf),
            b3: &self.b3,
            layer_norm: ln.then_some(LayerNorm { gamma: &self.gamma, beta: &self.beta }),
        }
    }
    fn inputs(&self) -> EdgeInputs<'_> {
        EdgeInputs { p_target: &self.pt, p_source: &self.ps, target: &self.tgt, source: &self.src }
    }
    /// (updated latents, aggregate) after one call with a non-zero starting aggregate.
    fn run(&self, k: &Kernels, bf: bool, ln: bool) -> (Vec<f32>, Vec<f32>) {
        let k_e = self.l1.k;
        let mut latent = self.latent.clone();
        let mut agg: Vec<f32> = (0..self.n_t * k_e).map(|i| (i % 7) as f32 * 0.25).collect();
        let mut scratch = vec![f32::NAN; edge_mlp_scratch_len(k_e, self.l1.n)];
        k.edge_mlp(&self.mlp(bf, ln), &self.inputs(), &mut latent, &mut agg, &mut scratch).unwrap();
        (latent, agg)
    }
}

#[test]
fn kernels_edge_mlp_tiers_match_scalar() {
    let tiers = simd_tiers("kernels_edge_mlp_tiers_match_scalar");
    let mut rng = Rng(0xED6E);
    for (k_e, h) in [(32, 32), (64, 64), (128, 128), (12, 32), (9, 48)] {
        for edges in [0usize, 1, 15, 17, 33, 250] {
            let case = EdgeCase::new(&mut rng, k_e, h, edges);
            for bf in [false, true] {
                for ln in [true, false] {
                    let (want_l, want_a) = case.run(&Kernels::scalar(), bf, ln);
                    // bf16 chains round hidden activations: a 1-ulp flip of one bf16 input moves
                    // an output by ~1e-4, so the chained bf16 tolerance is looser than f32's.
                    let tol = if bf { 2e-3 } else { 5e-5 };
                    for t in &tiers {
                        let (l, a) = case.run(t, bf, ln);
                        let what = format!("{} k_e={k_e} h={h} edges={edges} bf16={bf} ln={ln}", t.tier().name());
                        assert_close(&format!("{what} latent"), &l, &want_l, tol);
                        assert_close(&format!("{what} aggregate"), &a, &want_a, tol * 4.0);
                    }
                    if bf && ln {
                        // Loose: bf16 messages are LayerNorm outputs (O(1)); 3e-2 of that.
                        let (fl, _) = case.run(&Kernels::scalar(), false, ln);
                        assert_close("edge bf16 vs f32", &want_l, &fl, 3e-2);
                    }
                }
            }
        }
    }
}

/// The portable tier, chosen through the public selection, against the scalar reference on small
/// shapes that reach every path of the frame: row tails (1 to 5 rows past whole 6-row tiles),
/// partial last panels (`n` not a multiple of 16), odd `k`, several operands, every epilogue with
/// and without bias, f32 and bf16 weights, and the edge MLP and its aggregate across a block
/// boundary. Small enough for Miri to check the frame's pointer arithmetic (docs/reliability.md).
#[test]
fn kernels_portable_tier_covers_the_frame() {
    let k = Kernels::with_tier(Tier::Portable).expect("every CPU runs the portable tier");
    assert_eq!(k.tier(), Tier::Portable);
    let mut rng = Rng(0x9047);
    // Between them the shapes have every row tail (0 to 5 rows past whole tiles).
    let shapes = [(&[3usize][..], 3usize, [0usize, 3, 13]), (&[5, 16], 17, [2, 5, 6]), (&[9, 2, 7], 40, [1, 4, 17])];
    for (widths, n, row_counts) in shapes {
        let layers: Vec<Layer> = widths.iter().map(|&kw| Layer::new(&mut rng, kw, n)).collect();
        let (bias, gamma, beta) = (rng.vec(n, 0.5), rng.vec(n, 1.0), rng.vec(n, 0.5));
        for (r, rows) in row_counts.into_iter().enumerate() {
            let xs: Vec<Vec<f32>> = widths.iter().map(|&kw| rng.vec(rows * kw, 1.0)).collect();
            let out0 = rng.vec(rows * n, 1.0);
            for bf in [false, true] {
                let ops: Vec<Operand<'_>> =
                    xs.iter().zip(&layers).map(|(x, l)| Operand { x, w: l.weights(bf) }).collect();
                // Every epilogue, with and without bias in turn.
                for (e, epi) in epilogues(&gamma, &beta).iter().enumerate() {
                    let b = ((e + r) % 2 == 0).then_some(&bias[..]);
                    let want = run_linear(&Kernels::scalar(), &ops, b, epi, &out0);
                    let what =
                        format!("portable k={widths:?} n={n} rows={rows} bf16={bf} bias={} {epi:?}", b.is_some());
                    assert_close(&what, &run_linear(&k, &ops, b, epi, &out0), &want, 5e-5);
                }
            }
        }
    }
    for (k_e, h, edges) in [(9, 20, 7), (4, 3, 1), (16, 33, 100), (9, 20, 0)] {
        let case = EdgeCase::new(&mut rng, k_e, h, edges);
        for (bf, ln) in [(false, true), (false, false), (true, true), (true, false)] {
            let (want_l, want_a) = case.run(&Kernels::scalar(), bf, ln);
            let (l, a) = case.run(&k, bf, ln);
            let tol = if bf { 2e-3 } else { 5e-5 };
            let what = format!("portable k_e={k_e} h={h} edges={edges} bf16={bf} ln={ln}");
            assert_close(&format!("{what} latent"), &l, &want_l, tol);
            assert_close(&format!("{what} aggregate"), &a, &want_a, tol * 4.0);
        }
    }
}

/// The split first layer `P_t[r] + P_s[s] + e·W_eᵀ` (with `P = H·Wᵀ` from `linear`) equals the
/// reference's `[h_r, h_s, e]·W1ᵀ`, and the aggregate equals the CSR sum of the messages.
#[test]
fn kernels_split_first_layer_matches_concat() {
    let mut rng = Rng(99);
    let (h, nodes, edges) = (32usize, 20usize, 57usize);
    let w1 = rng.vec(h * 3 * h, 0.1);
    let hid = rng.vec(nodes * h, 1.0);
    let pack = |cols: core::ops::Range<usize>| {
        let mut f = vec![0.0; packed_len_f32(h, h)];
        pack_f32(&w1, h, 3 * h, cols, &mut f).unwrap();
        f
    };
    let (wt, ws, we) = (pack(0..h), pack(h..2 * h), pack(2 * h..3 * h));
    let mut case = EdgeCase::new(&mut rng, h, h, edges);
    case.l1.f = we;
    case.n_t = nodes;
    case.tgt = (0..edges).map(|e| (e * nodes / edges) as u32).collect();
    case.src = (0..edges).map(|_| (rng.next_u64() % nodes as u64) as u32).collect();
    let k = Kernels::best();
    let mut scratch = vec![0.0; linear_scratch_len(&[Operand { x: &hid, w: case.l1.weights(false) }], h)];
    for (dst, wp) in [(&mut case.pt, &wt), (&mut case.ps, &ws)] {
        *dst = vec![0.0; nodes * h];
        let op = [Operand { x: &hid, w: Weights::F32(PackedF32::new(wp, h, h).unwrap()) }];
        k.linear(&op, None, &Epilogue::default(), dst, &mut scratch).unwrap();
    }
    let (lat, agg) = case.run(&k, false, true);
    // Reference: concat input, unsplit W1, scalar layers, messages, then CSR aggregation.
    let mut msgs = vec![0.0; edges * h];
    for e in 0..edges {
        let (r, s) = (case.tgt[e] as usize, case.src[e] as usize);
        let mut cat = Vec::new();
        cat.extend_from_slice(&hid[r * h..(r + 1) * h]);
        cat.extend_from_slice(&hid[s * h..(s + 1) * h]);
        cat.extend_from_slice(&case.latent[e * h..(e + 1) * h]);
        let z1: Vec<f32> = (0..h)
            .map(|o| (case.b1[o] + (0..3 * h).map(|i| cat[i] * w1[o * 3 * h + i]).sum::<f32>()).max(0.0))
            .collect();
        let z2: Vec<f32> =
            (0..h).map(|o| (case.b2[o] + (0..h).map(|i| z1[i] * case.l2.w[o * h + i]).sum::<f32>()).max(0.0)).collect();
        let mut m: Vec<f32> =
            (0..h).map(|o| case.b3[o] + (0..h).map(|i| z2[i] * case.l3.w[o * h + i]).sum::<f32>()).collect();
        frame::layer_norm_row(&mut m, &case.gamma, &case.beta);
        msgs[e * h..(e + 1) * h].copy_from_slice(&m);
    }
    let want_lat: Vec<f32> = case.latent.iter().zip(&msgs).map(|(a, b)| a + b).collect();
    assert_close("split latent", &lat, &want_lat, 1e-4);
    let mut offsets = vec![0u32; nodes + 1];
    for &t in &case.tgt {
        offsets[t as usize + 1] += 1;
    }
    for i in 0..nodes {
        offsets[i + 1] += offsets[i];
    }
    let mut want_agg: Vec<f32> = (0..nodes * h).map(|i| (i % 7) as f32 * 0.25).collect();
    aggregate(&msgs, h, &offsets, &mut want_agg, true).unwrap();
    assert_close("split aggregate", &agg, &want_agg, 2e-4);
}

#[test]
fn kernels_aggregate_matches_naive() {
    let mut rng = Rng(5);
    let (width, nodes) = (9usize, 13usize);
    let counts: Vec<u32> = (0..nodes).map(|i| if i % 4 == 1 { 0 } else { (rng.next_u64() % 5) as u32 }).collect();
    let mut offsets = vec![0u32];
    for c in &counts {
        offsets.push(offsets.last().unwrap() + c);
    }
    let edges = *offsets.last().unwrap() as usize;
    let msgs = rng.vec(edges * width, 1.0);
    let mut out = rng.vec(nodes * width, 1.0);
    aggregate(&msgs, width, &offsets, &mut out, false).unwrap();
    for r in 0..nodes {
        for c in 0..width {
            let mut s = 0.0;
            for e in offsets[r]..offsets[r + 1] {
                s += msgs[e as usize * width + c];
            }
            assert_eq!(out[r * width + c], s);
        }
    }
    let bad = [0u32, 3, 2];
    assert!(aggregate(&msgs, width, &bad, &mut out[..2 * width], false).is_err());
    let past = [0u32, edges as u32 + 1];
    assert!(aggregate(&msgs, width, &past, &mut out[..width], false).is_err());
}

#[test]
fn kernels_reject_bad_shapes() {
    let mut rng = Rng(8);
    let case = EdgeCase::new(&mut rng, 32, 32, 10);
    let k = Kernels::best();
    let mut latent = case.latent.clone();
    let mut agg = vec![0.0; case.n_t * 32];
    let mut scratch = vec![0.0; edge_mlp_scratch_len(32, 32)];
    let mlp = case.mlp(false, true);
    let mut bad_tgt = case.tgt.clone();
    bad_tgt[3] = case.n_t as u32;
    let bad = EdgeInputs { target: &bad_tgt, ..case.inputs() };
    assert!(matches!(
        k.edge_mlp(&mlp, &bad, &mut latent, &mut agg, &mut scratch),
        Err(Error::IndexOutOfRange { at: 3, .. })
    ));
    assert!(k.edge_mlp(&mlp, &case.inputs(), &mut latent[1..], &mut agg, &mut scratch).is_err());
    assert!(k.edge_mlp(&mlp, &case.inputs(), &mut latent, &mut agg, &mut scratch[1..]).is_err());
    let mixed = EdgeMlp { w2: case.l2.weights(true), ..mlp };
    assert!(k.edge_mlp(&mixed, &case.inputs(), &mut latent, &mut agg, &mut scratch).is_err());
    assert_eq!(latent, case.latent, "a refused call leaves the latents alone");
    let x = vec![1.0; 3 * 32];
    let op = [Operand { x: &x, w: case.l1.weights(false) }];
    let mut s = vec![0.0; linear_scratch_len(&op, 32)];
    assert!(k.linear(&op, None, &Epilogue::default(), &mut [0.0; 2 * 32], &mut s).is_err());
    assert!(k.linear(&op, Some(&[0.0; 31]), &Epilogue::default(), &mut [0.0; 3 * 32], &mut s).is_err());
    assert!(k.linear(&op, None, &Epilogue::default(), &mut [0.0; 3 * 32], &mut s[..10]).is_err());
    assert!(k.linear(&[], None, &Epilogue::default(), &mut [0.0; 3 * 32], &mut s).is_err());
    // A shape whose packed length overflows (16 · 2^60 wraps to 0) is refused, not taken as an
    // empty matrix that the kernels would then read 2^60 inputs of.
    assert!(matches!(PackedF32::new(&[], 1 << 60, 16), Err(Error::OutOfRange { .. })));
    assert!(matches!(PackedBf16::new(&[], 1 << 60, 16), Err(Error::OutOfRange { .. })));
}

#[cfg(feature = "tools")]
#[test]
#[cfg_attr(miri, ignore = "measures speed, which an interpreter does not have")]
fn kernels_peak_is_a_rate_a_core_can_reach() {
    // No core runs f32 multiply-adds or vdpbf16ps faster than 1,000 GFLOP/s (a 6 GHz core
    // with two 512-bit FMA ports does 384), nor AMX's tiles faster than 20,000 (Sapphire Rapids
    // peaks near 7,000): a larger figure is a loop the optimiser removed, not a fast core.
    for tier in Tier::ALL {
        let Some(k) = Kernels::with_tier(tier) else { continue };
        let p = peak::measure(k, 2.0);
        println!(
            "peak on {}: f32 {:.1} GFLOP/s, bf16 {:.1} GFLOP/s (native {})",
            p.tier.name(),
            p.f32_gflops,
            p.bf16_gflops,
            p.bf16_native
        );
        let bf16_bound = if p.tier == Tier::Amx { 20_000.0 } else { 1_000.0 };
        assert!(p.f32_gflops > 0.1 && p.f32_gflops < 1_000.0, "{}: f32 peak {}", tier.name(), p.f32_gflops);
        assert!(p.bf16_gflops > 0.1 && p.bf16_gflops < bf16_bound, "{}: bf16 peak {}", tier.name(), p.bf16_gflops);
    }
}

/// A node-projection or message buffer that is not a whole number of rows is refused with the
/// lengths it has and needs (not a made-up zero).
#[test]
fn kernels_ragged_buffers_name_their_lengths() {
    let got = aggregate(&[0.0; 7], 3, &[0, 1, 2], &mut [0.0; 6], false).unwrap_err();
    assert_eq!(got, Error::SizeMismatch { what: "aggregate messages (a multiple of width)", expected: 9, got: 7 });
}
