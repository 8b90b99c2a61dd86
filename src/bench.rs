//! Step latency measurement (feature `tools`) shared by `hood bench`, the criterion benches and the
//! report: median wall time per step, useful FLOPs, GFLOP/s and efficiency against the machine's
//! peak measured in the same run, with the steps of the configurations compared taken in turns
//! and their ratios taken round by round.

use crate::error::Result;
use crate::exec::{Executor, ThreadPool};
pub use crate::kernels::peak::two_thread_share;
use crate::kernels::{peak, Kernels, Tier};
use crate::model::file::Model;
use crate::sim::{BodyDesc, Precision, Sim, SimConfig, StepMode};
use crate::workloads::Workload;
use std::string::String;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;
use std::vec::Vec;

/// One measured configuration.
#[derive(Clone, Debug)]
pub struct BenchRow {
    /// Workload name.
    pub workload: String,
    /// What computed the step: the network, or the solver alone (then the model's figures,
    /// `latent`, `blocks` and the FLOPs, are those of a network the row does not run).
    pub step: StepMode,
    /// Garment vertices.
    pub vertices: usize,
    /// Body edges in the timed step.
    pub body_edges: usize,
    /// Latent width.
    pub latent: usize,
    /// Processor blocks.
    pub blocks: usize,
    /// Arithmetic.
    pub precision: Precision,
    /// The kernel path the step ran on ([`crate::kernels::f32_choice`], [`crate::kernels::bf16_choice`]).
    pub tier: Tier,
    /// Threads.
    pub threads: usize,
    /// Median wall time per step, ms.
    pub median_ms: f64,
    /// Fastest step, ms.
    pub min_ms: f64,
    /// Every timed step's wall time, ms, in the order taken (one per round of `hood bench`).
    pub times_ms: Vec<f64>,
    /// Useful FLOPs per step (matrix products, split first layer).
    pub flops: u64,
    /// Achieved GFLOP/s at the median.
    pub gflops: f64,
    /// Peak GFLOP/s for this precision and thread count (single-core peak x threads).
    pub peak_gflops: f64,
    /// `gflops / peak_gflops`.
    pub efficiency: f64,
    /// Jobs of two or more tasks the step handed to its threads (each wakes or signals the
    /// other threads and waits for the last task): the synchronisation points of a step, whose
    /// cost grows with the core-to-core latency. 0 on one thread.
    pub handoffs: u64,
    /// Fraction (0-1) of the step's wall time inside those jobs (the rest runs on the calling
    /// thread alone), over the timed steps. 0 on one thread.
    pub in_jobs: f64,
    /// Fraction (0-1) of the pool threads' time inside those jobs that their tasks ran (the
    /// rest is waiting: hand-offs, wake-ups and uneven splits), over the timed steps. 0 on one
    /// thread.
    pub busy_in_jobs: f64,
}

/// What a [`CountingPool`] has seen so far, in totals the bench reads before and after a step.
#[derive(Default)]
struct JobClock {
    /// Jobs of two or more tasks.
    handoffs: AtomicU64,
    /// Wall time inside those jobs, from the hand-off to the last task's end, ns.
    wall_ns: AtomicU64,
    /// Time the tasks of those jobs ran, summed over tasks, ns.
    busy_ns: AtomicU64,
}

/// Totals of a [`JobClock`] at one moment.
#[derive(Clone, Copy, Default)]
struct JobTotals {
    handoffs: u64,
    wall_ns: u64,
    busy_ns: u64,
}

impl JobClock {
    fn totals(&self) -> JobTotals {
        JobTotals {
            handoffs: self.handoffs.load(Ordering::Relaxed),
            wall_ns: self.wall_ns.load(Ordering::Relaxed),
            busy_ns: self.busy_ns.load(Ordering::Relaxed),
        }
    }
}

impl core::ops::Sub for JobTotals {
    type Output = JobTotals;
    fn sub(self, b: JobTotals) -> JobTotals {
        JobTotals {
            handoffs: self.handoffs - b.handoffs,
            wall_ns: self.wall_ns - b.wall_ns,
            busy_ns: self.busy_ns - b.busy_ns,
        }
    }
}

/// A [`ThreadPool`] that counts the jobs of more than one task it is given and clocks them (the
/// job's wall time and its tasks' running time), into a clock the bench keeps while the sim
/// owns the pool: where a multi-thread step's time goes.
struct CountingPool {
    pool: ThreadPool,
    clock: Arc<JobClock>,
}

fn nanos(since: Instant) -> u64 {
    u64::try_from(since.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

// SAFETY: runs every job on the pool, whose contract is the executor's.
unsafe impl Executor for CountingPool {
    fn parallelism(&self) -> usize {
        self.pool.parallelism()
    }
    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        if n <= 1 {
            self.pool.run(n, task);
            return;
        }
        let c = &self.clock;
        c.handoffs.fetch_add(1, Ordering::Relaxed);
        let start = Instant::now();
        self.pool.run(n, &|i| {
            let t0 = Instant::now();
            task(i);
            c.busy_ns.fetch_add(nanos(t0), Ordering::Relaxed);
        });
        c.wall_ns.fetch_add(nanos(start), Ordering::Relaxed);
    }
}

/// Measures the machine's single-core peak (f32, bf16) once.
pub fn machine_peak() -> peak::Peak {
    peak::measure(Kernels::best(), 200.0)
}

/// Where two threads ran, as the share of its FMA rate each keeps while both compute
/// ([`two_thread_share`]) and their one-way core-to-core latency ([`core_to_core_ns`]) place
/// them. Two-thread step times depend on it: hyperthreads of one core share its FMA units, so a
/// step's two halves barely overlap; cores on different chiplets pay for every hand-off.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// Two hardware threads of one core (each keeps at most about 3/4 of its lone FMA rate; by
    /// latency alone, under about 25 ns).
    SameCore,
    /// Two cores that share a last-level cache (about 25–120 ns).
    SharedCache,
    /// Farther apart: different chiplets or sockets, or a host busy elsewhere (over 120 ns).
    Distant,
}

impl Placement {
    /// A thread sharing its core keeps at most this share of its lone FMA rate.
    pub const SHARED_CORE_SHARE: f64 = 0.75;

    /// The placement of two threads that each keep `share` of their lone FMA rate while both
    /// compute, `ns` nanoseconds apart one way: the share tells whether they share a core (two
    /// cores of one cache can pass a line as fast as one core's two threads: 16 ns on a Zen 4
    /// EPYC whose two threads each kept 99 % of their rate), the latency how far apart cores
    /// are. Without a share, the latency alone ([`Placement::from_latency_ns`]).
    pub fn from_measurements(share: Option<f64>, ns: f64) -> Placement {
        match share {
            Some(share) if share < Self::SHARED_CORE_SHARE => Placement::SameCore,
            Some(_) if ns <= 120.0 => Placement::SharedCache,
            Some(_) => Placement::Distant,
            None => Placement::from_latency_ns(ns),
        }
    }

    /// The placement a one-way latency of `ns` nanoseconds suggests.
    pub fn from_latency_ns(ns: f64) -> Placement {
        if ns < 25.0 {
            Placement::SameCore
        } else if ns <= 120.0 {
            Placement::SharedCache
        } else {
            Placement::Distant
        }
    }

    /// In words, for benchmark output.
    pub fn describe(self) -> &'static str {
        match self {
            Placement::SameCore => "two hardware threads of one core (expect little two-thread speed-up)",
            Placement::SharedCache => "two cores sharing a last-level cache",
            Placement::Distant => "cores on different chiplets or sockets, or a busy host (slower hand-offs)",
        }
    }
}

/// Where a run's two threads sit, measured at its start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThreadPair {
    /// [`two_thread_share`] of [`Kernels::best`]'s path, if a second thread could start.
    pub share: Option<f64>,
    /// [`core_to_core_ns`].
    pub latency_ns: f64,
}

impl ThreadPair {
    /// Measures both (about 0.6 s), or `None` when a second thread cannot run.
    pub fn measure() -> Option<ThreadPair> {
        let latency_ns = core_to_core_ns()?;
        Some(ThreadPair { share: two_thread_share(Kernels::best(), 50.0), latency_ns })
    }

    /// Where the measurements place the two threads.
    pub fn placement(&self) -> Placement {
        Placement::from_measurements(self.share, self.latency_ns)
    }
}

impl core::fmt::Display for ThreadPair {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if let Some(share) = self.share {
            write!(f, "computing at once, each keeps {:.0} % of its lone FMA rate; ", 100.0 * share)?;
        }
        write!(f, "core-to-core latency {:.0} ns one way: {}", self.latency_ns, self.placement().describe())
    }
}

/// One-way latency of a cache line between two threads, ns (median over five rounds of up to
/// 20,000 round trips through one atomic, 20 ms at most each), or `None` when a second thread
/// cannot run.
///
/// It says where two-thread timings were taken: about 15–40 ns when the threads' cores share
/// an L3 cache, 170–200 ns across chiplets (on two-core AMD EPYCs). On a virtual machine the
/// host may move the two virtual CPUs between such placements while a benchmark runs; steps that
/// hand data between threads (the trainer's above all) then run up to 1.6 times slower, so print
/// this beside two-thread figures.
pub fn core_to_core_ns() -> Option<f64> {
    use std::time::Duration;
    const TRIPS: u64 = 20_000;
    const ROUNDS: usize = 5;
    // On a busy machine the two spinning threads take turns a time slice at a time: cap a round.
    const ROUND_TIME: Duration = Duration::from_millis(20);
    const STOP: u64 = u64::MAX;
    if std::thread::available_parallelism().map_or(true, |n| n.get() < 2) {
        return None;
    }
    let flag = Arc::new(AtomicU64::new(0));
    let other = Arc::clone(&flag);
    // The partner answers every odd value with the next even one until it reads STOP.
    let partner = std::thread::Builder::new()
        .spawn(move || loop {
            match other.load(Ordering::Acquire) {
                STOP => return,
                v if !v.is_multiple_of(2) => other.store(v + 1, Ordering::Release),
                _ => core::hint::spin_loop(),
            }
        })
        .ok()?;
    let mut rounds = Vec::with_capacity(ROUNDS);
    let mut v = 1u64;
    for _ in 0..ROUNDS {
        let start = Instant::now();
        let mut trips = 0u64;
        while trips < TRIPS && (!trips.is_multiple_of(256) || start.elapsed() < ROUND_TIME) {
            flag.store(v, Ordering::Release);
            while flag.load(Ordering::Acquire) != v + 1 {
                core::hint::spin_loop();
            }
            v += 2;
            trips += 1;
        }
        rounds.push(start.elapsed().as_secs_f64() * 1e9 / (2 * trips) as f64);
    }
    flag.store(STOP, Ordering::Release);
    partner.join().ok()?;
    rounds.sort_by(f64::total_cmp);
    Some(rounds[ROUNDS / 2])
}

/// One configuration's sim, stepped one timed step at a time so that `hood bench` can take
/// the steps of several configurations in turns (rounds): noise from the rest of the machine then
/// falls on all of them alike, and ratios between them are taken step by step.
pub struct StepBench<'m> {
    sim: Sim<'m>,
    step: StepMode,
    precision: Precision,
    threads: usize,
    /// Threads the sim's pool has (the threads asked for, capped by the machine's).
    pool_threads: usize,
    /// The clock of the sim's pool (kept by the bench while the sim owns the pool).
    clock: Arc<JobClock>,
    /// Hand-offs of the last timed step.
    handoffs: u64,
    /// Wall time inside split jobs over the timed steps, ns.
    timed_wall_ns: u64,
    /// Time their tasks ran over the timed steps, ns.
    timed_busy_ns: u64,
    /// Steps taken, untimed ones included: the workload's step index.
    taken: usize,
    /// Wall time of each timed step, ms, in the order taken.
    times_ms: Vec<f64>,
}

impl<'m> StepBench<'m> {
    /// A sim stepping `w` with `model` (or, with `step` the solver, by the solver alone) at
    /// `precision` on `threads` threads, after `warmup` untimed steps.
    ///
    /// # Errors
    /// Errors of [`Sim::new`] and [`Sim::step`].
    pub fn new(
        w: &Workload,
        model: &'m Model<'m>,
        step: StepMode,
        precision: Precision,
        threads: usize,
        warmup: usize,
    ) -> Result<StepBench<'m>> {
        let cfg = SimConfig { precision, threads, startup: w.startup(), step, ..SimConfig::network() };
        let body = w.body.as_ref().map(|(mesh, frames)| BodyDesc { mesh, positions: &frames[0] });
        let mut sim = match &w.graph {
            Some(g) => Sim::with_graph(model, &w.garment, g.clone(), body, cfg)?,
            None => Sim::new(model, &w.garment, body, cfg)?,
        };
        let clock = Arc::new(JobClock::default());
        let mut pool_threads = 1;
        if threads > 1 {
            let pool = ThreadPool::new(crate::limits::cap_threads(threads));
            pool_threads = pool.parallelism();
            sim.set_executor(std::boxed::Box::new(CountingPool { pool, clock: clock.clone() }));
        }
        let mut b = StepBench {
            sim,
            step,
            precision,
            threads,
            pool_threads,
            clock,
            handoffs: 0,
            timed_wall_ns: 0,
            timed_busy_ns: 0,
            taken: 0,
            times_ms: Vec::new(),
        };
        for _ in 0..warmup {
            b.step_once(w)?;
        }
        Ok(b)
    }

    /// Takes one untimed step of `w`: before a timed step that follows other configurations',
    /// it leaves the caches as a run of this configuration alone would.
    ///
    /// # Errors
    /// Errors of [`Sim::step`].
    pub fn untimed_step(&mut self, w: &Workload) -> Result<()> {
        self.step_once(w).map(|_| ())
    }

    /// Takes one step of `w`, returning its wall time in ms and the pool's clock over it.
    fn step_once(&mut self, w: &Workload) -> Result<(f64, JobTotals)> {
        let next = w.prepare_step(&mut self.sim, self.taken)?;
        let before = self.clock.totals();
        let start = Instant::now();
        self.sim.step(next)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let jobs = self.clock.totals() - before;
        self.taken += 1;
        Ok((ms, jobs))
    }

    /// Takes one timed step of `w` (the workload the bench was made with) and records it.
    ///
    /// # Errors
    /// Errors of [`Sim::step`].
    pub fn time_step(&mut self, w: &Workload) -> Result<f64> {
        let (ms, jobs) = self.step_once(w)?;
        self.times_ms.push(ms);
        self.handoffs = jobs.handoffs;
        self.timed_wall_ns += jobs.wall_ns;
        self.timed_busy_ns += jobs.busy_ns;
        Ok(ms)
    }

    /// The row of the timed steps so far: their median and the figures at it.
    pub fn row(&self, w: &Workload, model: &Model<'_>, peak: &peak::Peak) -> BenchRow {
        let median_ms = median(&self.times_ms);
        let total_ms: f64 = self.times_ms.iter().sum();
        let flops = self.sim.last_step_flops();
        let gflops = flops as f64 / (median_ms * 1e-3) / 1e9;
        // The peak of the arithmetic the step ran: bf16 widened onto f32 FMAs peaks as f32 does.
        let tier = self.sim.tier();
        let native_bf16 = self.precision == Precision::Bf16 && tier >= Tier::Avx512Bf16 && peak.bf16_native;
        let per_core = if native_bf16 { peak.bf16_gflops } else { peak.f32_gflops };
        let peak_gflops = per_core * self.threads as f64;
        BenchRow {
            workload: w.name.clone(),
            step: self.step,
            vertices: w.garment.n_vertices(),
            body_edges: self.sim.last_body_counts().0,
            latent: model.spec().latent,
            blocks: model.spec().blocks.len(),
            precision: self.precision,
            tier,
            threads: self.threads,
            median_ms,
            min_ms: fastest(&self.times_ms),
            times_ms: self.times_ms.clone(),
            flops,
            gflops,
            peak_gflops,
            efficiency: gflops / peak_gflops,
            handoffs: self.handoffs,
            in_jobs: self.timed_wall_ns as f64 / (total_ms * 1e6),
            busy_in_jobs: if self.timed_wall_ns > 0 {
                self.timed_busy_ns as f64 / (self.pool_threads as f64 * self.timed_wall_ns as f64)
            } else {
                0.0
            },
        }
    }
}

/// The median of `v` (nearest rank, as [`crate::eval::percentile`] takes it for the
/// eval summaries' step times); NaN when `v` is empty.
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        crate::eval::percentile(&mut v.to_vec(), 0.5)
    }
}

/// The smallest of `v` (the fastest of a row's step times); NaN when `v` is empty.
pub fn fastest(v: &[f64]) -> f64 {
    v.iter().copied().reduce(f64::min).unwrap_or(f64::NAN)
}

/// The median over rounds of `num[i] / den[i]`: a ratio of two configurations timed in the same
/// rounds, taken round by round so that a slow spell of the machine, which falls on both steps
/// of a round, cancels. `None` when the two have no round in common.
pub fn paired_ratio(num: &[f64], den: &[f64]) -> Option<f64> {
    let ratios: Vec<f64> =
        num.iter().zip(den).filter(|(_, &d)| d > 0.0).map(|(&n, &d)| n / d).filter(|r| r.is_finite()).collect();
    (!ratios.is_empty()).then(|| median(&ratios))
}

/// The order in which round `round` takes the steps of `n` configurations: each round starts one
/// configuration further on, so that no configuration always runs first (after the others'
/// caches) or last.
pub fn round_order(n: usize, round: usize) -> impl Iterator<Item = usize> {
    (0..n).map(move |i| (i + round) % n.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_ratios_are_taken_round_by_round() {
        // The median of the rounds' ratios (2, 1.05, 4), not the ratio of the medians (2.1).
        assert_eq!(paired_ratio(&[100.0, 210.0, 400.0], &[50.0, 200.0, 100.0]), Some(2.0));
        // Unequal lengths pair the rounds both took; zero or non-finite times are left out.
        assert_eq!(paired_ratio(&[10.0, 30.0, 99.0], &[5.0, 0.0]), Some(2.0));
        assert_eq!(paired_ratio(&[f64::NAN], &[1.0]), None);
        assert_eq!(paired_ratio(&[], &[]), None);
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert!(median(&[]).is_nan());
        assert_eq!(fastest(&[3.0, 1.0, 2.0]), 1.0);
        assert!(fastest(&[]).is_nan());
    }

    #[test]
    fn bench_the_job_clock_sees_the_threads_wait_on_an_uneven_split() {
        let clock = Arc::new(JobClock::default());
        let pool = CountingPool { pool: ThreadPool::new(2), clock: clock.clone() };
        // One task runs 20 ms, the other nothing: the tasks ran 20 ms of the two threads' 2 x
        // (at least 20 ms) in the job, at most half of it.
        pool.run(2, &|i| {
            if i == 0 {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
        });
        let t = clock.totals();
        assert_eq!(t.handoffs, 1);
        assert!(t.wall_ns >= 20_000_000 && t.busy_ns >= 20_000_000, "{} {}", t.wall_ns, t.busy_ns);
        let busy = t.busy_ns as f64 / (2.0 * t.wall_ns as f64);
        assert!(busy <= 0.55, "busy {busy}");
        // A job of one task is no hand-off and is not clocked.
        let one = Arc::new(JobClock::default());
        let pool = CountingPool { pool: ThreadPool::new(2), clock: one.clone() };
        pool.run(1, &|_| std::thread::sleep(std::time::Duration::from_millis(5)));
        let t = one.totals();
        assert_eq!((t.handoffs, t.wall_ns, t.busy_ns), (0, 0, 0));
    }

    #[test]
    fn bench_rounds_start_one_configuration_further_on() {
        let orders: Vec<Vec<usize>> = (0..4).map(|r| round_order(3, r).collect()).collect();
        assert_eq!(orders, [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 1, 2]]);
        assert_eq!(round_order(0, 5).count(), 0);
    }

    #[test]
    fn bench_placement_follows_the_latency_bands() {
        assert_eq!(Placement::from_latency_ns(11.0), Placement::SameCore);
        assert_eq!(Placement::from_latency_ns(25.0), Placement::SharedCache);
        assert_eq!(Placement::from_latency_ns(54.0), Placement::SharedCache);
        assert_eq!(Placement::from_latency_ns(120.0), Placement::SharedCache);
        assert_eq!(Placement::from_latency_ns(185.0), Placement::Distant);
        assert_ne!(Placement::SameCore.describe(), Placement::Distant.describe());
    }

    #[test]
    fn bench_placement_asks_the_fma_share_whether_a_core_is_shared() {
        // A fast line between two cores that each keep their FMA rate: two cores, not one.
        assert_eq!(Placement::from_measurements(Some(0.99), 16.0), Placement::SharedCache);
        assert_eq!(Placement::from_measurements(Some(0.95), 185.0), Placement::Distant);
        // Halved rates: one core's two threads, however slow the line.
        assert_eq!(Placement::from_measurements(Some(0.52), 16.0), Placement::SameCore);
        assert_eq!(Placement::from_measurements(Some(0.6), 60.0), Placement::SameCore);
        assert_eq!(Placement::from_measurements(None, 16.0), Placement::SameCore);
        assert_eq!(Placement::from_measurements(None, 60.0), Placement::SharedCache);
    }

    #[test]
    fn bench_two_thread_share_is_a_share() {
        // On any machine: between a time-sliced single core (~0.5, or less when busy) and two
        // free cores (~1); never more than a little above 1.
        match two_thread_share(Kernels::best(), 5.0) {
            Some(share) => assert!(share.is_finite() && share > 0.05 && share < 1.3, "{share}"),
            None => assert!(std::thread::available_parallelism().map_or(true, |n| n.get() < 2)),
        }
    }

    #[test]
    fn bench_core_to_core_latency_is_a_latency() {
        // Two or more cores: a measured one-way latency, above the cost of a store and below a
        // round's time cap (on a busy machine the spinning threads may take turns a time slice
        // at a time, so anything up to the cap is a latency).
        if let Some(ns) = core_to_core_ns() {
            assert!(ns.is_finite() && ns > 1.0 && ns < 2e7, "{ns} ns");
        } else {
            assert!(std::thread::available_parallelism().map_or(true, |n| n.get() < 2));
        }
    }
}
