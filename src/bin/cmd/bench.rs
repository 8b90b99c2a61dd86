//! `hood bench`: step latency per workload, model size, precision and thread count, printed as a
//! table or JSON and optionally written as a Markdown report.

use crate::machine::machine_line;
use crate::random_model;
use crate::reference::{Reference, ReferenceTime, DEFAULT_SCRIPT};
use clap::Args;
use hood::bench::{bench_step, core_to_core_ns, machine_peak, BenchRow, Placement};
use hood::kernels::peak::Peak;
use hood::model::{Model, ModelBytes, ModelSpec};
use hood::sim::{Precision, StepMode};
use hood::workloads::{workload, Workload, NAMES};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Args)]
pub(crate) struct BenchArgs {
    /// Workloads (comma-separated); default: every one whose files are present.
    #[arg(long, value_delimiter = ',')]
    workload: Vec<String>,
    /// Latent widths of the HOOD architecture to time (random weights: timing does not depend
    /// on their values).
    #[arg(long, value_delimiter = ',', default_value = "128,64,32")]
    latent: Vec<usize>,
    /// A model file to time instead of random models.
    #[arg(long)]
    model: Option<PathBuf>,
    /// The random models' block schedule instead of HOOD's (the form `TrainConfig`'s
    /// `schedule` takes, e.g. `f,c0 | d:c0,c1 | d:c1 | c1 | u:c0,c1 | u:f,c0`), to time a
    /// cheaper network before training it.
    #[arg(long)]
    schedule: Option<String>,
    /// Coarse levels of the random models with `--schedule`.
    #[arg(long, default_value_t = 3)]
    levels: usize,
    /// Also time the solver step mode (no network) at these L-BFGS iteration counts, on the
    /// same workloads and threads (f32), for the network's cost against the solver's in one run.
    #[arg(long, value_delimiter = ',')]
    solver: Vec<u32>,
    /// Precisions: f32, bf16.
    #[arg(long, value_delimiter = ',', default_value = "f32,bf16")]
    precision: Vec<String>,
    /// Thread counts.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    threads: Vec<usize>,
    /// Timed steps per configuration (the median is reported).
    #[arg(long, default_value_t = 15)]
    steps: usize,
    /// Untimed steps first.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// The assets folder; the tee workloads read the parity fixtures beside it (default:
    /// $HOOD_ASSETS, else `shared/assets` in the working directory or a parent).
    #[arg(long)]
    assets: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Also write the table as a Markdown report to this file, headed by the command, the
    /// machine and its load (as `docs/bench/report.md`).
    #[arg(long)]
    markdown: Option<PathBuf>,
    /// Also time the reference network's forward with this Python interpreter (torch, numpy
    /// and safetensors installed; `pip install torch==2.2.2 "numpy<2" safetensors`), on the
    /// workloads with the fixture's scene (`tee`, `tee-sub`) at the same threads, after the
    /// runtime's rows: the "x reference" column is its median over the row's.
    #[arg(long)]
    reference: Option<PathBuf>,
    /// The reference's script.
    #[arg(long, default_value = DEFAULT_SCRIPT)]
    reference_script: PathBuf,
    /// Timed forwards of the reference per thread count (after 3 untimed ones).
    #[arg(long, default_value_t = 10)]
    reference_runs: usize,
}

pub(crate) fn bench(a: BenchArgs) -> hood::Result<()> {
    let assets = hood::assets::locate(a.assets.as_deref());
    let names: Vec<String> =
        if a.workload.is_empty() { NAMES.iter().map(|s| s.to_string()).collect() } else { a.workload.clone() };
    let mut workloads = Vec::new();
    for n in &names {
        // Without an assets folder the procedural workloads still run.
        let built = match &assets {
            Ok(dir) => workload(n, dir),
            Err(e) => workload(n, Path::new("")).map_err(|_| e.clone()),
        };
        match built {
            Ok(w) => workloads.push(w),
            Err(e) if a.workload.is_empty() => eprintln!("skipping {n}: {e}"),
            Err(e) => return Err(e),
        }
    }
    let precisions: Vec<Precision> = a
        .precision
        .iter()
        .map(|p| match p.as_str() {
            "bf16" => Ok(Precision::Bf16),
            "f32" => Ok(Precision::F32),
            _ => Err(hood::Error::parse("precision", 0, format!("'{p}' (use f32 or bf16)"))),
        })
        .collect::<hood::Result<_>>()?;
    let models: Vec<ModelBytes> = match &a.model {
        Some(p) => vec![ModelBytes::read(p)?],
        None => a
            .latent
            .iter()
            .map(|&h| match &a.schedule {
                Some(s) => random_model(&ModelSpec::with_schedule(h, 2, a.levels, s)?),
                None => random_model(&ModelSpec::hood(h)),
            })
            .collect::<hood::Result<_>>()?,
    };
    let peak = machine_peak();
    eprintln!(
        "peak per core ({}): f32 {:.1} GFLOP/s, bf16 {:.1} GFLOP/s",
        peak.tier.name(),
        peak.f32_gflops,
        peak.bf16_gflops
    );
    let choices = tier_choices(&precisions);
    for c in &choices {
        eprintln!("{c}");
    }
    let mut core_to_core = None;
    if a.threads.iter().any(|&t| t > 1) {
        if let Some(ns) = core_to_core_ns() {
            eprintln!("core-to-core latency: {ns:.0} ns one way: {}", Placement::from_latency_ns(ns).describe());
            core_to_core = Some(ns);
        }
    }
    // Each multi-thread row carries the latency measured just before it: the host may move the
    // two threads between placements during a run.
    let mut rows: Vec<BenchRow> = Vec::new();
    let mut latencies: Vec<Option<f64>> = Vec::new();
    let reference = match (&a.reference, &assets) {
        (Some(python), Ok(dir)) => Some(Reference {
            python,
            script: &a.reference_script,
            weights: hood::assets::fixtures(dir).join("hood-parity/fixture_weights.safetensors"),
            runs: a.reference_runs.max(1),
            warmup: 3,
        }),
        (Some(_), Err(e)) => return Err(e.clone()),
        (None, _) => None,
    };
    let mut references: Vec<ReferenceTime> = Vec::new();
    let mut run = |w: &Workload, model: &Model<'_>, step, precision, threads: usize| -> hood::Result<()> {
        let latency = if threads > 1 { core_to_core_ns() } else { None };
        let r = bench_step(w, model, step, precision, threads, a.warmup, a.steps, &peak)?;
        if !a.json {
            print_row(&r, rows.is_empty());
        }
        rows.push(r);
        latencies.push(latency);
        Ok(())
    };
    for w in &workloads {
        for mb in &models {
            let model = mb.model()?;
            for &p in &precisions {
                for &t in &a.threads {
                    run(w, &model, StepMode::Network, p, t)?;
                }
            }
        }
        if let Some(mb) = models.first() {
            let model = mb.model()?;
            for &iterations in &a.solver {
                for &t in &a.threads {
                    run(w, &model, StepMode::Solver { iterations }, Precision::F32, t)?;
                }
            }
        }
        if let (Some(r), Some(_)) = (&reference, &w.fixed_state) {
            for t in r.time(w, &a.threads)? {
                if !a.json {
                    say!(
                        "{:<9} {:>6} reference forward (PyTorch {}), {} thread(s): median {:.2} ms, fastest {:.2} ms",
                        t.workload,
                        t.vertices,
                        t.torch,
                        t.threads,
                        t.median_ms,
                        t.min_ms
                    );
                }
                references.push(t);
            }
        }
    }
    if a.json {
        say!("{}", to_json(&rows, &references, &peak));
    }
    if let Some(path) = &a.markdown {
        let choices = (!choices.is_empty()).then(|| choices.join(". "));
        let text = markdown(&rows, &latencies, &references, &peak, choices.as_deref(), core_to_core);
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| hood::Error::io(dir, e))?;
        }
        std::fs::write(path, text).map_err(|e| hood::Error::io(path, e))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// A row's step in words: `network`, or `solver K` for the solver step mode.
fn step_name(step: StepMode) -> String {
    match step {
        StepMode::Solver { iterations } => format!("solver {iterations}"),
        _ => "network".into(),
    }
}

fn print_row(r: &BenchRow, header: bool) {
    if header {
        say!(
            "{:<9} {:>6} {:>6} {:>10} {:>4} {:>5} {:>10} {:>3} {:>10} {:>10} {:>9} {:>8} {:>6} {:>9}",
            "workload",
            "verts",
            "bodyE",
            "step",
            "h",
            "prec",
            "tier",
            "thr",
            "median ms",
            "GFLOP/step",
            "GFLOP/s",
            "peak",
            "eff",
            "hand-offs"
        );
    }
    let network = r.step == StepMode::Network;
    let (h, flops, gflops, peak, eff) = if network {
        (
            r.latent.to_string(),
            format!("{:.3}", r.flops as f64 / 1e9),
            format!("{:.1}", r.gflops),
            format!("{:.1}", r.peak_gflops),
            format!("{:.0}%", 100.0 * r.efficiency),
        )
    } else {
        ("-".into(), "-".into(), "-".into(), "-".into(), "-".into())
    };
    say!(
        "{:<9} {:>6} {:>6} {:>10} {:>4} {:>5} {:>10} {:>3} {:>10.2} {:>10} {:>9} {:>8} {:>6} {:>9}",
        r.workload,
        r.vertices,
        r.body_edges,
        step_name(r.step),
        h,
        r.precision.name(),
        if network { r.tier.name() } else { "-" },
        r.threads,
        r.median_ms,
        flops,
        gflops,
        peak,
        eff,
        r.handoffs
    );
}

/// `hood bench --json`: the machine's peak and one object per row.
fn to_json(rows: &[BenchRow], references: &[ReferenceTime], peak: &Peak) -> String {
    #[derive(serde::Serialize)]
    struct PeakJson {
        tier: &'static str,
        f32_gflops: f64,
        bf16_gflops: f64,
    }
    #[derive(serde::Serialize)]
    struct Row<'a> {
        workload: &'a str,
        step: String,
        vertices: usize,
        body_edges: usize,
        latent: usize,
        blocks: usize,
        precision: &'static str,
        tier: &'static str,
        threads: usize,
        median_ms: f64,
        min_ms: f64,
        flops: u64,
        gflops: f64,
        peak_gflops: f64,
        efficiency: f64,
        handoffs: u64,
    }
    #[derive(serde::Serialize)]
    struct Reference<'a> {
        workload: &'a str,
        vertices: usize,
        threads: usize,
        median_ms: f64,
        min_ms: f64,
        torch: &'a str,
    }
    #[derive(serde::Serialize)]
    struct Bench<'a> {
        peak: PeakJson,
        rows: Vec<Row<'a>>,
        reference: Vec<Reference<'a>>,
    }
    let rows = rows
        .iter()
        .map(|r| Row {
            workload: &r.workload,
            step: step_name(r.step),
            vertices: r.vertices,
            body_edges: r.body_edges,
            latent: r.latent,
            blocks: r.blocks,
            precision: r.precision.name(),
            tier: r.tier.name(),
            threads: r.threads,
            median_ms: r.median_ms,
            min_ms: r.min_ms,
            flops: r.flops,
            gflops: r.gflops,
            peak_gflops: r.peak_gflops,
            efficiency: r.efficiency,
            handoffs: r.handoffs,
        })
        .collect();
    let reference = references
        .iter()
        .map(|t| Reference {
            workload: &t.workload,
            vertices: t.vertices,
            threads: t.threads,
            median_ms: t.median_ms,
            min_ms: t.min_ms,
            torch: &t.torch,
        })
        .collect();
    let peak = PeakJson { tier: peak.tier.name(), f32_gflops: peak.f32_gflops, bf16_gflops: peak.bf16_gflops };
    hood::io::json::to_line(&Bench { peak, rows, reference })
}

/// Which tier each timed precision runs on and why ([`hood::kernels::f32_choice`],
/// [`hood::kernels::bf16_choice`]), a sentence each.
fn tier_choices(precisions: &[Precision]) -> Vec<String> {
    let mut lines = Vec::new();
    if precisions.contains(&Precision::F32) {
        lines.push(hood::kernels::f32_choice().describe());
    }
    if precisions.contains(&Precision::Bf16) {
        lines.push(hood::kernels::bf16_choice().describe());
    }
    lines
}

/// The report `--markdown` writes: the command, the machine, the peaks, then one row per step
/// timed, with the speed-up of each multi-thread row over the same step on one thread.
fn markdown(
    rows: &[BenchRow],
    latencies: &[Option<f64>],
    references: &[ReferenceTime],
    peak: &Peak,
    choices: Option<&str>,
    core_to_core_ns: Option<f64>,
) -> String {
    let mut s = String::new();
    let command: Vec<String> = std::env::args().skip(1).collect();
    let _ = writeln!(
        s,
        "# Step latency
"
    );
    let _ = writeln!(
        s,
        "Generated by `hood {}` ([performance.md](../performance.md) says how to read it).\n",
        command.join(" ")
    );
    let _ = writeln!(s, "{}\n", machine_line());
    let _ = write!(
        s,
        "Peak per core measured in the same run ({} tier): f32 {:.1} GFLOP/s, bf16 {:.1} GFLOP/s.",
        peak.tier.name(),
        peak.f32_gflops,
        peak.bf16_gflops
    );
    if let Some(choices) = choices {
        let _ = write!(s, " {choices}.");
    }
    if let Some(ns) = core_to_core_ns {
        let _ = write!(
            s,
            " Core-to-core latency at the start {ns:.0} ns one way: {}.",
            Placement::from_latency_ns(ns).describe()
        );
    }
    let _ = writeln!(
        s,
        "\n\nmedian ms: median wall time of one step (fastest ms: the fastest; far apart, the machine was \
         busy elsewhere); GFLOP/step: the network's useful floating-point work \
         (matrix products); efficiency: achieved GFLOP/s over the peak times the threads; x 1 thread: the \
         same step on one thread over this one; latency: the core-to-core latency measured just before a \
         multi-thread row (under about 25 ns: one core's two hardware threads; over 120 ns: farther \
         apart than a shared cache); hand-offs: jobs of the step split between threads (each a \
         synchronisation, costlier the farther apart the cores); x reference: the reference forward's \
         median at the same threads over this row's (below the table).\n"
    );
    let _ = writeln!(
        s,
        "| workload | vertices | body edges | step | h | precision | tier | threads | median ms | fastest ms | GFLOP/step | GFLOP/s | efficiency | x 1 thread | latency ns | hand-offs | x reference |"
    );
    let _ = writeln!(s, "|---|---:|---:|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (r, latency) in rows.iter().zip(latencies) {
        let network = r.step == StepMode::Network;
        let single = rows.iter().find(|o| {
            o.threads == 1
                && o.workload == r.workload
                && o.step == r.step
                && o.latent == r.latent
                && o.blocks == r.blocks
                && o.precision == r.precision
        });
        let speedup = match single {
            Some(o) if r.threads > 1 && r.median_ms > 0.0 => format!("{:.2}", o.median_ms / r.median_ms),
            _ => "-".into(),
        };
        let dash = || "-".to_string();
        let reference = references.iter().find(|t| t.workload == r.workload && t.threads == r.threads);
        let vs_reference = match reference {
            Some(t) if network && r.median_ms > 0.0 => format!("{:.1}", t.median_ms / r.median_ms),
            _ => dash(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {} | {} | {} | {} | {} | {} | {} |",
            r.workload,
            r.vertices,
            r.body_edges,
            step_name(r.step),
            if network { r.latent.to_string() } else { dash() },
            r.precision.name(),
            if network { r.tier.name() } else { "-" },
            r.threads,
            r.median_ms,
            r.min_ms,
            if network { format!("{:.2}", r.flops as f64 / 1e9) } else { dash() },
            if network { format!("{:.1}", r.gflops) } else { dash() },
            if network { format!("{:.0} %", 100.0 * r.efficiency) } else { dash() },
            speedup,
            latency.map_or_else(dash, |ns| format!("{ns:.0}")),
            if r.threads > 1 { r.handoffs.to_string() } else { dash() },
            vs_reference
        );
    }
    if !references.is_empty() {
        let _ = writeln!(
            s,
            "\nThe reference: HOOD's network forward in PyTorch {} (`tools/reference/forward.py`, checked against \
             the parity fixtures; the work of HOOD's `model(batch)`, every body vertex through every block's node \
             MLP), with the fixture's weights (h = 128) on the same scene, timed in the same run after the rows \
             above.\n",
            references[0].torch
        );
        let _ = writeln!(s, "| workload | vertices | threads | median ms | fastest ms |");
        let _ = writeln!(s, "|---|---:|---:|---:|---:|");
        for t in references {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.1} | {:.1} |",
                t.workload, t.vertices, t.threads, t.median_ms, t.min_ms
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::markdown;
    use crate::reference::ReferenceTime;
    use hood::bench::BenchRow;
    use hood::kernels::peak::Peak;
    use hood::kernels::Tier;
    use hood::sim::{Precision, StepMode};

    fn row(workload: &str, step: StepMode, precision: Precision, threads: usize, median_ms: f64) -> BenchRow {
        BenchRow {
            workload: workload.into(),
            step,
            vertices: 1311,
            body_edges: 1309,
            latent: 128,
            blocks: 15,
            precision,
            tier: Tier::Scalar,
            threads,
            median_ms,
            min_ms: median_ms,
            flops: 23_851_000_000,
            gflops: 23.851 / median_ms * 1e3,
            peak_gflops: 100.0 * threads as f64,
            efficiency: 0.5,
            handoffs: if threads > 1 { 180 } else { 0 },
        }
    }

    /// The table row of `workload` at `threads` threads and `precision` ("f32"/"bf16").
    fn line<'a>(text: &'a str, workload: &str, step: &str, precision: &str, threads: usize) -> &'a str {
        text.lines()
            .find(|l| {
                let cells: Vec<&str> = l.split('|').map(str::trim).collect();
                cells.len() > 8
                    && cells[1] == workload
                    && cells[4] == step
                    && cells[6] == precision
                    && cells[8] == threads.to_string()
            })
            .unwrap_or_else(|| panic!("no row {workload} {step} {precision} {threads} in\n{text}"))
    }

    #[test]
    fn the_report_gives_each_multi_thread_row_its_speed_up_over_one_thread() {
        let rows = [
            row("tee", StepMode::Network, Precision::F32, 1, 200.0),
            row("tee", StepMode::Network, Precision::F32, 2, 125.0),
            row("tee", StepMode::Network, Precision::Bf16, 2, 100.0),
            row("tee", StepMode::Network, Precision::Bf16, 1, 300.0),
            row("tee", StepMode::Solver { iterations: 30 }, Precision::F32, 1, 80.0),
            row("tee", StepMode::Solver { iterations: 30 }, Precision::F32, 2, 50.0),
        ];
        let peak = Peak { tier: Tier::Scalar, f32_gflops: 100.0, bf16_gflops: 100.0, bf16_native: false };
        let latencies = [None, Some(11.0), Some(60.0), None, None, Some(60.0)];
        let reference = |threads, median_ms| ReferenceTime {
            workload: "tee".into(),
            vertices: 1311,
            threads,
            median_ms,
            min_ms: median_ms,
            torch: "2.2.2".into(),
        };
        let references = [reference(1, 1000.0), reference(2, 750.0)];
        let text = markdown(&rows, &latencies, &references, &peak, Some("bf16 widened"), Some(40.0));
        assert!(text.starts_with("# Step latency\n"));
        assert!(text.contains("\nMachine: "), "{text}");
        assert!(text.contains("f32 100.0 GFLOP/s") && text.contains("bf16 widened.") && text.contains("40 ns"));
        // The reference's median over the row's, at the row's threads.
        assert!(line(&text, "tee", "network", "f32", 1).ends_with("| - | - | - | 5.0 |"));
        assert!(line(&text, "tee", "network", "f32", 2).ends_with("| 1.60 | 11 | 180 | 6.0 |"));
        // Matched by precision, whatever the order of the rows.
        assert!(line(&text, "tee", "network", "bf16", 2).ends_with("| 3.00 | 60 | 180 | 7.5 |"));
        // A solver row has no network figures (nor a reference) and its own one-thread row.
        let solver = line(&text, "tee", "solver 30", "f32", 2);
        assert!(solver.ends_with("| - | f32 | - | 2 | 50.00 | 50.00 | - | - | - | 1.60 | 60 | 180 | - |"), "{solver}");
        assert!(text.contains("| tee | 1311 | 2 | 750.0 | 750.0 |"), "{text}");
    }
}
