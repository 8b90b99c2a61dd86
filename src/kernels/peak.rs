//! Single-core peak arithmetic throughput (feature `tools`), measured (not looked up): the
//! denominator of every efficiency figure in the benches and `hood bench`.
//!
//! f32: a loop of independent FMA chains (12 accumulators, enough to cover FMA latency × ports
//! on current x86 cores) on the widest vectors the tier has; on the portable tier chains of
//! eight-lane multiply-adds in plain Rust, as its kernels compute them, vectorised by the
//! compiler for the target (the best of 4, 8 and 12 chains). bf16: the same with `vdpbf16ps`
//! where the CPU has AVX-512-BF16, four independent `tdpbf16ps` on the AMX tier; elsewhere the
//! bf16 kernels run on f32 FMAs, so their peak is the f32 peak. Runs are timed on thread CPU
//! time where available ([`Stopwatch`]), so other processes on a shared machine do not count
//! against the loop. One FLOP is one multiply or one add (an FMA lane counts 2, a `vdpbf16ps`
//! lane 4).

pub use super::stopwatch::{thread_cpu_seconds, Stopwatch};
use super::{Kernels, Tier};

/// Measured single-core peaks, GFLOP/s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peak {
    /// The tier the loops ran on.
    pub tier: Tier,
    /// f32 multiply-add throughput.
    pub f32_gflops: f64,
    /// bf16 dot-product throughput (f32 accumulation); equal to `f32_gflops` when the tier has
    /// no native bf16 instruction.
    pub bf16_gflops: f64,
    /// Whether `bf16_gflops` was measured with a native bf16 instruction.
    pub bf16_native: bool,
}

/// Best of `reps` timed runs of `f(iters)` that performs `flops_per_iter` per iteration, sized to
/// last about `target_ms` each.
///
/// Every call passes its count through [`std::hint::black_box`]: the loops are pure functions
/// of their arguments, and with the same count in every repetition the optimiser may otherwise
/// run one and reuse its result for the rest, which then time nothing.
fn best_gflops(flops_per_iter: f64, target_ms: f64, reps: usize, mut f: impl FnMut(usize) -> f32) -> f64 {
    let iters = calibrate(target_ms, &mut f);
    let mut best = 0.0f64;
    for _ in 0..reps {
        let t = Stopwatch::start();
        std::hint::black_box(f(std::hint::black_box(iters)));
        let s = t.seconds();
        best = best.max(flops_per_iter * iters as f64 / s / 1e9);
    }
    best
}

/// Iterations of `f` that last about `target_ms` (grown until a run takes at least 2 ms, then
/// scaled).
fn calibrate(target_ms: f64, mut f: impl FnMut(usize) -> f32) -> usize {
    let mut iters = 1usize << 12;
    loop {
        let t = Stopwatch::start();
        std::hint::black_box(f(std::hint::black_box(iters)));
        let s = t.seconds();
        if s > 2e-3 || iters > 1 << 30 {
            return ((iters as f64) * (target_ms * 1e-3 / s.max(1e-9))).max(1.0) as usize;
        }
        iters *= 4;
    }
}

/// Scalar multiply-add chains (the scalar tier's peak): `iters · 8 · 2` FLOPs.
fn scalar_loop(iters: usize, a: f32, b: f32) -> f32 {
    let mut acc: [f32; 8] = core::array::from_fn(|i| i as f32);
    for _ in 0..iters {
        for c in acc.iter_mut() {
            *c = *c * a + b;
        }
        acc = std::hint::black_box(acc);
    }
    acc.iter().sum()
}

/// The portable tier's multiply-adds (a product then a sum, as its kernels compute them) on `C`
/// chains of eight lanes, which the compiler vectorises: `iters · C · 8 · 2` FLOPs.
fn portable_loop<const C: usize>(iters: usize, a: f32, b: f32) -> f32 {
    let mut acc: [[f32; 8]; C] = core::array::from_fn(|i| [i as f32; 8]);
    for _ in 0..iters {
        for c in acc.iter_mut() {
            for v in c.iter_mut() {
                *v = *v * a + b;
            }
        }
    }
    acc.iter().flatten().sum()
}

/// The portable tier's peak: the best of 4, 8 and 12 chains. How many chains the target's
/// registers hold unspilled is the compiler's affair (x86-64's sixteen SSE registers hold four
/// chains and their operands; twelve spilled and read a quarter of the kernels' own rate), so
/// the loop is run at each and the fastest kept.
fn portable_peak(target_ms: f64, reps: usize, a: f32, b: f32) -> f64 {
    let flops = |chains: f64| chains * 8.0 * 2.0;
    best_gflops(flops(4.0), target_ms, reps, |n| portable_loop::<4>(n, a, b))
        .max(best_gflops(flops(8.0), target_ms, reps, |n| portable_loop::<8>(n, a, b)))
        .max(best_gflops(flops(12.0), target_ms, reps, |n| portable_loop::<12>(n, a, b)))
}

/// Measures the single-core peak of the path `k` runs (about `5 · target_ms` per precision, three
/// times that on the portable tier).
pub fn measure(k: Kernels, target_ms: f64) -> Peak {
    let (a, b) = (std::hint::black_box(0.999_f32), std::hint::black_box(1e-3_f32));
    let reps = 5;
    let tier = k.tier();
    let fma = FmaLoop::of(tier);
    let f32_gflops = match fma {
        FmaLoop::Portable => portable_peak(target_ms, reps, a, b),
        _ => best_gflops(fma.flops_per_iter(), target_ms, reps, |n| fma.run(n, a, b)),
    };
    #[cfg(target_arch = "x86_64")]
    let native = {
        use super::x86::{peak_loops, AmxBf16, Avx512Bf16};
        match tier {
            Tier::Avx512Bf16 => Avx512Bf16::new()
                .map(|t| best_gflops(12.0 * 16.0 * 4.0, target_ms, reps, |n| peak_loops::dpbf16(t, n, a, b))),
            Tier::Amx => AmxBf16::new()
                .map(|t| best_gflops(4.0 * 16.0 * 16.0 * 32.0 * 2.0, target_ms, reps, |n| super::amx::peak_loop(t, n))),
            _ => None,
        }
    };
    #[cfg(not(target_arch = "x86_64"))]
    let native: Option<f64> = None;
    Peak { tier, f32_gflops, bf16_gflops: native.unwrap_or(f32_gflops), bf16_native: native.is_some() }
}

/// The f32 multiply-add loop of a tier: FMA chains on its widest x86 vectors, eight-lane chains
/// in plain Rust on the portable tier (four of them; [`measure`] also tries more), scalar
/// chains on the scalar tier.
#[derive(Clone, Copy)]
enum FmaLoop {
    #[cfg(target_arch = "x86_64")]
    Avx2(super::x86::Avx2Fma),
    #[cfg(target_arch = "x86_64")]
    Avx512(super::x86::Avx512),
    Portable,
    Scalar,
}

impl FmaLoop {
    /// `tier`'s loop (the scalar one where the CPU lacks the tier's vectors).
    fn of(tier: Tier) -> FmaLoop {
        #[cfg(target_arch = "x86_64")]
        {
            use super::x86::{Avx2Fma, Avx512};
            let vector = match tier {
                Tier::Avx2Fma => Avx2Fma::new().map(FmaLoop::Avx2),
                Tier::Avx512 | Tier::Avx512Bf16 | Tier::Amx => Avx512::new().map(FmaLoop::Avx512),
                Tier::Scalar | Tier::Portable => None,
            };
            if let Some(vector) = vector {
                return vector;
            }
        }
        match tier {
            Tier::Portable => FmaLoop::Portable,
            _ => FmaLoop::Scalar,
        }
    }

    /// FLOPs of one iteration of [`FmaLoop::run`].
    fn flops_per_iter(self) -> f64 {
        match self {
            #[cfg(target_arch = "x86_64")]
            FmaLoop::Avx2(_) => 12.0 * 8.0 * 2.0,
            #[cfg(target_arch = "x86_64")]
            FmaLoop::Avx512(_) => 12.0 * 16.0 * 2.0,
            FmaLoop::Portable => 4.0 * 8.0 * 2.0,
            FmaLoop::Scalar => 8.0 * 2.0,
        }
    }

    /// `iters` iterations of the loop.
    fn run(self, iters: usize, a: f32, b: f32) -> f32 {
        match self {
            #[cfg(target_arch = "x86_64")]
            FmaLoop::Avx2(t) => super::x86::peak_loops::fma_avx2(t, iters, a, b),
            #[cfg(target_arch = "x86_64")]
            FmaLoop::Avx512(t) => super::x86::peak_loops::fma_avx512(t, iters, a, b),
            FmaLoop::Portable => portable_loop::<4>(iters, a, b),
            FmaLoop::Scalar => scalar_loop(iters, a, b),
        }
    }
}

/// The share of its lone f32 throughput each of two threads keeps while both run the path's
/// FMA loop at once (the mean of the two, best of three tries of about `target_ms`): near 1 on
/// two cores, near 0.5 on two hardware threads of one core, which share its FMA units (a
/// latency between the threads cannot tell those apart: on some CPUs two cores of one cache
/// pass a line as fast as one core's two threads). `None` when a second thread cannot start.
/// Threads run on CPU time ([`Stopwatch`]), so other processes' time slices do not count.
pub fn two_thread_share(k: Kernels, target_ms: f64) -> Option<f64> {
    if std::thread::available_parallelism().map_or(true, |n| n.get() < 2) {
        return None;
    }
    let (a, b) = (std::hint::black_box(0.999_f32), std::hint::black_box(1e-3_f32));
    let fma = FmaLoop::of(k.tier());
    let iters = calibrate(target_ms, |n| fma.run(n, a, b));
    let timed = || {
        let t = Stopwatch::start();
        std::hint::black_box(fma.run(std::hint::black_box(iters), a, b));
        t.seconds().max(1e-9)
    };
    let alone = (0..3).map(|_| timed()).fold(f64::INFINITY, f64::min);
    let barrier = std::sync::Barrier::new(2);
    let mut best: Option<f64> = None;
    for _ in 0..3 {
        let pair = std::thread::scope(|scope| {
            let other = std::thread::Builder::new()
                .spawn_scoped(scope, || {
                    barrier.wait();
                    timed()
                })
                .ok()?;
            barrier.wait();
            let mine = timed();
            Some((mine, other.join().ok()?))
        });
        let (mine, theirs) = pair?;
        let share = 0.5 * (alone / mine + alone / theirs);
        best = Some(best.map_or(share, |b| b.max(share)));
    }
    best
}

/// Measures the peak of [`Kernels::best`] with ~20 ms runs.
pub fn peak() -> Peak {
    measure(Kernels::best(), 20.0)
}
