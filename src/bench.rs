//! Step latency measurement shared by `hood bench`, the criterion benches and the report:
//! median wall time per step, useful FLOPs, GFLOP/s and efficiency against the machine's peak
//! measured in the same run.

use crate::error::Result;
use crate::kernels::{peak, Kernels};
use crate::model::file::Model;
use crate::sim::{BodyDesc, Precision, Sim, SimConfig};
use crate::workloads::Workload;
use std::string::String;
use std::time::Instant;
use std::vec::Vec;

/// One measured configuration.
#[derive(Clone, Debug)]
pub struct BenchRow {
    /// Workload name.
    pub workload: String,
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
    /// Threads.
    pub threads: usize,
    /// Median wall time per step, ms.
    pub median_ms: f64,
    /// Fastest step, ms.
    pub min_ms: f64,
    /// Useful FLOPs per step (matrix products, split first layer).
    pub flops: u64,
    /// Achieved GFLOP/s at the median.
    pub gflops: f64,
    /// Peak GFLOP/s for this precision and thread count (single-core peak x threads).
    pub peak_gflops: f64,
    /// `gflops / peak_gflops`.
    pub efficiency: f64,
}

/// Measures the machine's single-core peak (f32, bf16) once.
pub fn machine_peak() -> peak::Peak {
    peak::measure(Kernels::best(), 200.0)
}

/// Steps `w` with `model` `steps` times after `warmup` untimed steps and reports the median.
///
/// # Errors
/// Errors of [`Sim::new`] and [`Sim::step`].
pub fn bench_step(
    w: &Workload,
    model: &Model<'_>,
    precision: Precision,
    threads: usize,
    warmup: usize,
    steps: usize,
    peak: &peak::Peak,
) -> Result<BenchRow> {
    let cfg = SimConfig { precision, threads, startup: w.startup(), ..SimConfig::default() };
    let body = w.body.as_ref().map(|(mesh, frames)| BodyDesc { mesh, positions: &frames[0] });
    let mut sim = match &w.graph {
        Some(g) => Sim::with_graph(model, &w.garment, g.clone(), body, cfg)?,
        None => Sim::new(model, &w.garment, body, cfg)?,
    };
    let mut times = Vec::with_capacity(steps);
    for t in 0..warmup + steps {
        let next = w.prepare_step(&mut sim, t)?;
        let start = Instant::now();
        sim.step(next)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        if t >= warmup {
            times.push(ms);
        }
    }
    times.sort_by(f64::total_cmp);
    let median_ms = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
    let flops = sim.last_step_flops();
    let gflops = flops as f64 / (median_ms * 1e-3) / 1e9;
    let per_core = if precision == Precision::Bf16 { peak.bf16_gflops } else { peak.f32_gflops };
    let peak_gflops = per_core * threads as f64;
    Ok(BenchRow {
        workload: w.name.clone(),
        vertices: w.garment.n_vertices(),
        body_edges: sim.last_body_counts().0,
        latent: model.spec().latent,
        blocks: model.spec().blocks.len(),
        precision,
        threads,
        median_ms,
        min_ms: times.first().copied().unwrap_or(f64::NAN),
        flops,
        gflops,
        peak_gflops,
        efficiency: gflops / peak_gflops,
    })
}
