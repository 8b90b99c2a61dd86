//! Edge-MLP chain, plain packed linear, a linear over three operands (the shape of a node MLP's
//! first layer: a latent and two aggregates) and one with LayerNorm and residual (its last), f32
//! and bf16, h = 128, 64, 32, at two sizes: 6,000 edges over 2,000 nodes (a garment of the
//! fixture t-shirt's size, whose buffers stay in a server core's L2 and L3 as in the step) and
//! 30,000 over 10,000 (buffers that outgrow the last-level cache, so that memory bandwidth
//! shows). Prints useful FLOPs (from shapes), GFLOP/s and efficiency against the single-core peak
//! measured in the same run, then hands the same closures to criterion.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use half::bf16;
use hood::bench::fastest;
use hood::kernels::{
    edge_mlp_scratch_len, linear_scratch_len, pack_bf16, pack_f32, packed_len_bf16, packed_len_f32,
    peak::{self, Stopwatch},
    EdgeInputs, EdgeMlp, Epilogue, Kernels, LayerNorm, Operand, PackedBf16, PackedF32, Tier, Weights,
};
use std::hint::black_box;

/// (edges, nodes) of each size; linear layers run on as many rows as there are edges.
const SIZES: [(usize, usize); 2] = [(6_000, 2_000), (30_000, 10_000)];

struct Rng(u64);
impl Rng {
    fn f(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }
    fn vec(&mut self, n: usize, a: f32) -> Vec<f32> {
        (0..n).map(|_| self.f() * a).collect()
    }
}

struct Packed {
    f: Vec<f32>,
    b: Vec<bf16>,
    k: usize,
    n: usize,
}
impl Packed {
    fn new(rng: &mut Rng, k: usize, n: usize) -> Packed {
        let w = rng.vec(k * n, 1.0 / (k as f32).sqrt());
        let mut f = vec![0.0; packed_len_f32(k, n)];
        pack_f32(&w, n, k, 0..k, &mut f).unwrap();
        let mut b = vec![bf16::ZERO; packed_len_bf16(k, n)];
        pack_bf16(&w, n, k, 0..k, &mut b).unwrap();
        Packed { f, b, k, n }
    }
    fn w(&self, bf: bool) -> Weights<'_> {
        if bf {
            Weights::Bf16(PackedBf16::new(&self.b, self.k, self.n).unwrap())
        } else {
            Weights::F32(PackedF32::new(&self.f, self.k, self.n).unwrap())
        }
    }
}

/// Fastest of `reps` runs after one warm-up, on thread CPU time where available (the peak is
/// measured the same way, so on a shared machine the ratio compares like with like).
fn best_secs(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Stopwatch::start();
            f();
            s.seconds()
        })
        .collect();
    fastest(&t)
}

/// One printed row: time, useful GFLOP, rate and its share of the peak (`peak` in GFLOP/s).
fn print_row(what: &str, secs: f64, flops: f64, peak: f64) {
    let rate = flops / secs / 1e9;
    println!(
        "kernels: {what} {:.2} ms, {:.2} GFLOP useful, {rate:.1} GFLOP/s, {:.0}% of peak",
        secs * 1e3,
        flops / 1e9,
        100.0 * rate / peak
    );
}

fn bench(c: &mut Criterion) {
    let k = Kernels::best();
    let p = peak::measure(k, 20.0);
    println!(
        "kernels: tier {}, single-core peak f32 {:.1} GFLOP/s, bf16 {:.1} GFLOP/s ({})",
        k.tier().name(),
        p.f32_gflops,
        p.bf16_gflops,
        match (p.bf16_native, k.tier()) {
            (true, Tier::Amx) => "the tile unit's tdpbf16ps",
            (true, _) => "vdpbf16ps",
            (false, _) => "bf16 runs on f32 FMAs",
        }
    );
    let clock = if Stopwatch::start().is_cpu_time() { "thread CPU time" } else { "wall time" };
    println!("kernels: figures below are the best of 15 runs, timed on {clock}");
    let mut rng = Rng(42);
    let mut g = c.benchmark_group("kernels");
    g.sample_size(10);
    for (edges, nodes) in SIZES {
        for h in [128usize, 64, 32] {
            let (l1, l2, l3) = (Packed::new(&mut rng, h, h), Packed::new(&mut rng, h, h), Packed::new(&mut rng, h, h));
            let (b1, b2, b3) = (rng.vec(h, 0.1), rng.vec(h, 0.1), rng.vec(h, 0.1));
            let (gamma, beta) = (rng.vec(h, 1.0), rng.vec(h, 0.1));
            let pt = rng.vec(nodes * h, 1.0);
            let ps = rng.vec(nodes * h, 1.0);
            let target: Vec<u32> = (0..edges).map(|e| (e * nodes / edges) as u32).collect();
            let source: Vec<u32> = (0..edges).map(|e| ((e * 7919) % nodes) as u32).collect();
            let latent0 = rng.vec(edges * h, 1.0);
            let mut latent = latent0.clone();
            let mut agg = vec![0.0f32; nodes * h];
            let mut scratch = vec![0.0f32; edge_mlp_scratch_len(h, h)];
            let x = rng.vec(edges * h, 1.0);
            let mut out = vec![0.0f32; edges * h];
            // bf16 operands need the larger scratch (room to widen weights where needed).
            let ops_f = [Operand { x: &x, w: l2.w(true) }];
            let mut lscratch = vec![0.0f32; linear_scratch_len(&ops_f, h)];
            for bf in [false, true] {
                let prec = if bf { "bf16" } else { "f32" };
                let peak_g = if bf { p.bf16_gflops } else { p.f32_gflops };
                let mlp = EdgeMlp {
                    w1_edge: l1.w(bf),
                    b1: &b1,
                    w2: l2.w(bf),
                    b2: &b2,
                    w3: l3.w(bf),
                    b3: &b3,
                    layer_norm: Some(LayerNorm { gamma: &gamma, beta: &beta }),
                };
                let inputs = EdgeInputs { p_target: &pt, p_source: &ps, target: &target, source: &source };
                let flops = (edges * 3 * 2 * h * h) as f64;
                // Latents are not reset between runs (a copy would be timed too); the residual sum only
                // grows them by O(1) LayerNorm outputs per run.
                latent.copy_from_slice(&latent0);
                let mut run_edge = || {
                    k.edge_mlp(&mlp, black_box(&inputs), &mut latent, &mut agg, &mut scratch).unwrap();
                };
                let s = best_secs(15, &mut run_edge);
                print_row(&format!("edge_mlp h={h:>3} {prec:>4} {edges:>6} edges:"), s, flops, peak_g);
                g.throughput(Throughput::Elements(flops as u64));
                g.bench_function(format!("edge_mlp_h{h}_{prec}_e{edges}"), |b| b.iter(&mut run_edge));

                let ops = [Operand { x: &x, w: l2.w(bf) }];
                let epi = Epilogue { relu: true, ..Epilogue::default() };
                let lflops = (edges * 2 * h * h) as f64;
                let mut run_lin = || k.linear(black_box(&ops), Some(&b2), &epi, &mut out, &mut lscratch).unwrap();
                let s = best_secs(15, &mut run_lin);
                print_row(&format!("linear   h={h:>3} {prec:>4} {edges:>6} rows: "), s, lflops, peak_g);
                g.throughput(Throughput::Elements(lflops as u64));
                g.bench_function(format!("linear_h{h}_{prec}_e{edges}"), |b| b.iter(&mut run_lin));

                let ops3 =
                    [Operand { x: &x, w: l1.w(bf) }, Operand { x: &x, w: l2.w(bf) }, Operand { x: &x, w: l3.w(bf) }];
                let mut lscratch3 = vec![0.0f32; linear_scratch_len(&ops3, h)];
                let mut run_lin3 = || k.linear(black_box(&ops3), Some(&b2), &epi, &mut out, &mut lscratch3).unwrap();
                let s = best_secs(15, &mut run_lin3);
                print_row(&format!("linear3  h={h:>3} {prec:>4} {edges:>6} rows: "), s, 3.0 * lflops, peak_g);
                g.throughput(Throughput::Elements(3 * lflops as u64));
                g.bench_function(format!("linear3_h{h}_{prec}_e{edges}"), |b| b.iter(&mut run_lin3));

                // A node MLP's last layer: LayerNorm, added to the residual (`out` only grows by
                // O(1) LayerNorm outputs per run, as the edge latents above).
                let ln = LayerNorm { gamma: &gamma, beta: &beta };
                let epi_ln = Epilogue { relu: false, layer_norm: Some(ln), residual: true };
                let mut run_ln = || k.linear(black_box(&ops), Some(&b2), &epi_ln, &mut out, &mut lscratch).unwrap();
                let s = best_secs(15, &mut run_ln);
                print_row(&format!("linear+ln h={h:>3} {prec:>4} {edges:>6} rows: "), s, lflops, peak_g);
                g.throughput(Throughput::Elements(lflops as u64));
                g.bench_function(format!("linear_ln_residual_h{h}_{prec}_e{edges}"), |b| b.iter(&mut run_ln));
            }
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
