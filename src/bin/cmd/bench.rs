//! `hood bench`: step latency per workload, model size, precision and thread count, printed as a
//! table or JSON and optionally written as a Markdown report.

use crate::machine::machine_line;
use crate::progress::Progress;
use crate::random_model;
use crate::reference::{Forward, Reference, ReferenceTime, DEFAULT_SCRIPT};
use clap::Args;
use hood::bench::{core_to_core_ns, machine_peak, paired_ratio, round_order, BenchRow, StepBench, ThreadPair};
use hood::kernels::peak::Peak;
use hood::model::{Model, ModelBytes, ModelSpec};
use hood::sim::{Precision, StepMode};
use hood::workloads::{workload, NAMES};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

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
    /// Rounds: each takes one timed step of every configuration of a workload in turn, then one
    /// forward of the reference at each thread count, so that noise from the rest of the
    /// machine falls on all of them alike. The median is reported, and ratios are taken round
    /// by round.
    #[arg(long, default_value_t = 15)]
    steps: usize,
    /// Untimed steps of each configuration first.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Untimed steps of each configuration (and forwards of the reference) just before its timed
    /// one in every round, so that the timed step finds the caches as a run of that
    /// configuration alone leaves them; 0 times steps that follow other configurations' (colder
    /// caches; the run then takes about half as long).
    #[arg(long, default_value_t = 1)]
    round_warmup: usize,
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
    /// workloads with the fixture's scene (`tee`, `tee-sub`) at the same threads, one forward
    /// per thread count in each round: the "x reference" column is the median over rounds of
    /// its time over the row's.
    #[arg(long)]
    reference: Option<PathBuf>,
    /// The reference's script.
    #[arg(long, default_value = DEFAULT_SCRIPT)]
    reference_script: PathBuf,
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
    let multi_thread = a.threads.iter().any(|&t| t > 1);
    let pair = if multi_thread { ThreadPair::measure() } else { None };
    if let Some(pair) = &pair {
        eprintln!("two threads: {pair}");
    }
    let reference = match (&a.reference, &assets) {
        (Some(python), Ok(dir)) => Some(Reference {
            python,
            script: &a.reference_script,
            weights: hood::assets::fixtures(dir).join("hood-parity/fixture_weights.safetensors"),
            warmup: 3,
        }),
        (Some(_), Err(e)) => return Err(e.clone()),
        (None, _) => None,
    };
    let views: Vec<Model<'_>> = models.iter().map(|mb| mb.model()).collect::<hood::Result<_>>()?;
    let rounds = a.steps.max(1);
    // Each multi-thread row carries the median latency of its workload's rounds: the host may
    // move the two threads between placements during a run.
    let mut rows: Vec<BenchRow> = Vec::new();
    let mut latencies: Vec<Option<f64>> = Vec::new();
    let mut references: Vec<ReferenceTime> = Vec::new();
    for w in &workloads {
        // Every configuration of the workload, and the reference, stepped in turns: one timed
        // step of each per round, so that the machine's slow spells fall on all of them alike.
        let mut benches: Vec<(&Model<'_>, StepBench<'_>)> = Vec::new();
        for model in &views {
            for &p in &precisions {
                for &t in &a.threads {
                    benches.push((model, StepBench::new(w, model, StepMode::Network, p, t, a.warmup)?));
                }
            }
        }
        if let Some(model) = views.first() {
            for &iterations in &a.solver {
                for &t in &a.threads {
                    let step = StepMode::Solver { iterations };
                    benches.push((model, StepBench::new(w, model, step, Precision::F32, t, a.warmup)?));
                }
            }
        }
        let mut server = match (&reference, &w.fixed_state) {
            (Some(r), Some(_)) => Some(r.serve(w)?),
            _ => None,
        };
        let mut forwards: Vec<Vec<Forward>> = vec![Vec::new(); a.threads.len()];
        let mut round_latencies = Vec::new();
        let bar = Progress::new("bench", "rounds", rounds as u64, Duration::from_secs(10));
        bar.set_message(w.name.clone());
        for round in 0..rounds {
            if multi_thread {
                round_latencies.extend(core_to_core_ns());
            }
            for i in round_order(benches.len(), round) {
                for _ in 0..a.round_warmup {
                    benches[i].1.untimed_step(w)?;
                }
                benches[i].1.time_step(w)?;
            }
            if let Some(server) = &mut server {
                for (f, &t) in forwards.iter_mut().zip(&a.threads) {
                    for _ in 0..a.round_warmup {
                        server.forward(t)?;
                    }
                    f.push(server.forward(t)?);
                }
            }
            bar.inc(1);
        }
        bar.finish();
        drop(server);
        let latency = (!round_latencies.is_empty()).then(|| hood::bench::median(&round_latencies));
        for (model, b) in &benches {
            let r = b.row(w, model, &peak);
            if !a.json {
                print_row(&r, rows.is_empty());
            }
            latencies.push(if r.threads > 1 { latency } else { None });
            rows.push(r);
        }
        for f in &forwards {
            if let Some(t) = ReferenceTime::of(&w.name, f) {
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
        let text = markdown(&rows, &latencies, &references, &peak, choices.as_deref(), pair, a.round_warmup);
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
            "{:<9} {:>6} {:>6} {:>10} {:>4} {:>5} {:>10} {:>3} {:>10} {:>10} {:>9} {:>8} {:>6} {:>9} {:>7} {:>5}",
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
            "hand-offs",
            "in jobs",
            "busy"
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
        "{:<9} {:>6} {:>6} {:>10} {:>4} {:>5} {:>10} {:>3} {:>10.2} {:>10} {:>9} {:>8} {:>6} {:>9} {:>7} {:>5}",
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
        r.handoffs,
        percent_if_split(r, r.in_jobs),
        percent_if_split(r, r.busy_in_jobs)
    );
}

/// `share` as a whole percentage on a multi-thread row, else `-`.
fn percent_if_split(r: &BenchRow, share: f64) -> String {
    if r.threads > 1 {
        format!("{:.0}%", 100.0 * share)
    } else {
        "-".into()
    }
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
        times_ms: &'a [f64],
        flops: u64,
        gflops: f64,
        peak_gflops: f64,
        efficiency: f64,
        handoffs: u64,
        in_jobs: f64,
        busy_in_jobs: f64,
    }
    #[derive(serde::Serialize)]
    struct Reference<'a> {
        workload: &'a str,
        vertices: usize,
        threads: usize,
        median_ms: f64,
        min_ms: f64,
        times_ms: &'a [f64],
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
            times_ms: &r.times_ms,
            flops: r.flops,
            gflops: r.gflops,
            peak_gflops: r.peak_gflops,
            efficiency: r.efficiency,
            handoffs: r.handoffs,
            in_jobs: r.in_jobs,
            busy_in_jobs: r.busy_in_jobs,
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
            times_ms: &t.times_ms,
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
    pair: Option<ThreadPair>,
    round_warmup: usize,
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
    if let Some(pair) = pair {
        let _ = write!(s, " Two threads at the start: {pair}.");
    }
    let _ = writeln!(
        s,
        "\n\nEach workload is timed in rounds: a round takes one timed step of every row of the workload in \
         turn, each round starting one row further on, then (with the reference) one forward of it at each \
         thread count, so that the machine's slow spells fall on all rows alike; ratios between rows are the \
         median over rounds of the round's ratio. {}\n\n\
         median ms: median wall time of one step (fastest ms: the fastest; far apart, the machine was \
         busy elsewhere); GFLOP/step: the network's useful floating-point work \
         (matrix products); efficiency: achieved GFLOP/s over the peak times the threads; x 1 thread: the \
         same step on one thread over this one; x f32: the same step in f32 over this one in bf16; \
         latency: the median core-to-core latency measured at the start of the workload's rounds (over \
         120 ns: farther apart than a shared cache; whether the two threads share a core, the FMA share \
         above tells); \
         hand-offs: jobs of the step split between threads (each a synchronisation, costlier the farther \
         apart the cores); in jobs: the share of the step's time inside those jobs (the rest runs on one \
         thread); busy: the share of the threads' time in those jobs that their tasks ran (the rest is \
         hand-offs, wake-ups and uneven splits); x reference: the reference forward's time at the same threads over this row's \
         (below the table).\n",
        if round_warmup > 0 {
            format!(
                "Before its timed step in a round each row takes {round_warmup} untimed one(s) (the reference as \
                 many forwards), so that the timed step finds the caches as a run of that row alone leaves them."
            )
        } else {
            "The timed steps follow other rows' directly, with colder caches than a run of one row alone.".into()
        }
    );
    let _ = writeln!(
        s,
        "| workload | vertices | body edges | step | h | precision | tier | threads | median ms | fastest ms | GFLOP/step | GFLOP/s | efficiency | x 1 thread | x f32 | latency ns | hand-offs | in jobs | busy | x reference |"
    );
    let _ = writeln!(
        s,
        "|---|---:|---:|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for (r, latency) in rows.iter().zip(latencies) {
        let network = r.step == StepMode::Network;
        // The same step at another thread count or precision.
        let same = |threads: usize, precision: Precision| {
            rows.iter().find(|o| {
                o.threads == threads
                    && o.workload == r.workload
                    && o.step == r.step
                    && o.latent == r.latent
                    && o.blocks == r.blocks
                    && o.precision == precision
            })
        };
        let dash = || "-".to_string();
        let ratio = |of: &[f64]| paired_ratio(of, &r.times_ms);
        let speedup = match same(1, r.precision) {
            Some(o) if r.threads > 1 => ratio(&o.times_ms).map_or_else(dash, |x| format!("{x:.2}")),
            _ => dash(),
        };
        let over_f32 = match same(r.threads, Precision::F32) {
            Some(o) if r.precision == Precision::Bf16 => ratio(&o.times_ms).map_or_else(dash, |x| format!("{x:.2}")),
            _ => dash(),
        };
        let reference = references.iter().find(|t| t.workload == r.workload && t.threads == r.threads);
        let vs_reference = match reference {
            Some(t) if network => ratio(&t.times_ms).map_or_else(dash, |x| format!("{x:.1}")),
            _ => dash(),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
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
            over_f32,
            latency.map_or_else(dash, |ns| format!("{ns:.0}")),
            if r.threads > 1 { r.handoffs.to_string() } else { dash() },
            percent_if_split(r, r.in_jobs).replace('%', " %"),
            percent_if_split(r, r.busy_in_jobs).replace('%', " %"),
            vs_reference
        );
    }
    if !references.is_empty() {
        let _ = writeln!(
            s,
            "\nThe reference: HOOD's network forward in PyTorch {} (`tools/reference/forward.py`, checked against \
             the parity fixtures; the work of HOOD's `model(batch)`, every body vertex through every block's node \
             MLP), with the fixture's weights (h = 128) on the same scene, timed in the same rounds as the rows \
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
    use hood::bench::{BenchRow, ThreadPair};
    use hood::kernels::peak::Peak;
    use hood::kernels::Tier;
    use hood::sim::{Precision, StepMode};

    /// A row with one step time per round (three rounds).
    fn row(workload: &str, step: StepMode, precision: Precision, threads: usize, times_ms: [f64; 3]) -> BenchRow {
        let mut sorted = times_ms;
        sorted.sort_by(f64::total_cmp);
        let median_ms = sorted[1];
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
            min_ms: sorted[0],
            times_ms: times_ms.to_vec(),
            flops: 23_851_000_000,
            gflops: 23.851 / median_ms * 1e3,
            peak_gflops: 100.0 * threads as f64,
            efficiency: 0.5,
            handoffs: if threads > 1 { 180 } else { 0 },
            in_jobs: if threads > 1 { 0.9 } else { 0.0 },
            busy_in_jobs: if threads > 1 { 0.8 } else { 0.0 },
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
    fn the_report_takes_ratios_between_rows_round_by_round() {
        // The second round was slow for every row; f32 on two threads was also slowed in the
        // last round alone, which moves its median (140) but not the median of its ratios to
        // the others, taken round by round.
        let rows = [
            row("tee", StepMode::Network, Precision::F32, 1, [200.0, 400.0, 200.0]),
            row("tee", StepMode::Network, Precision::F32, 2, [125.0, 250.0, 140.0]),
            row("tee", StepMode::Network, Precision::Bf16, 2, [100.0, 200.0, 100.0]),
            row("tee", StepMode::Network, Precision::Bf16, 1, [300.0, 600.0, 300.0]),
            row("tee", StepMode::Solver { iterations: 30 }, Precision::F32, 1, [80.0, 160.0, 80.0]),
            row("tee", StepMode::Solver { iterations: 30 }, Precision::F32, 2, [50.0, 100.0, 50.0]),
        ];
        let peak = Peak { tier: Tier::Scalar, f32_gflops: 100.0, bf16_gflops: 100.0, bf16_native: false };
        let latencies = [None, Some(11.0), Some(60.0), None, None, Some(60.0)];
        let reference = |threads, median_ms: f64| ReferenceTime {
            workload: "tee".into(),
            vertices: 1311,
            threads,
            median_ms,
            min_ms: median_ms,
            times_ms: vec![median_ms, 2.0 * median_ms, median_ms],
            torch: "2.2.2".into(),
        };
        let references = [reference(1, 1000.0), reference(2, 750.0)];
        let pair = ThreadPair { share: Some(0.98), latency_ns: 40.0 };
        let text = markdown(&rows, &latencies, &references, &peak, Some("bf16 widened"), Some(pair), 1);
        assert!(text.starts_with("# Step latency\n"));
        assert!(text.contains("each row takes 1 untimed one(s)"), "{text}");
        assert!(text.contains("\nMachine: "), "{text}");
        assert!(
            text.contains("f32 100.0 GFLOP/s")
                && text.contains("bf16 widened.")
                && text.contains("40 ns")
                && text.contains("keeps 98 %")
        );
        // The reference's time over the row's, at the row's threads, round by round.
        assert!(line(&text, "tee", "network", "f32", 1).ends_with("| - | - | - | - | - | - | 5.0 |"));
        assert!(line(&text, "tee", "network", "f32", 2).ends_with("| 1.60 | - | 11 | 180 | 90 % | 80 % | 6.0 |"));
        // Matched by precision, whatever the order of the rows; bf16 against f32 at its threads.
        assert!(line(&text, "tee", "network", "bf16", 2).ends_with("| 3.00 | 1.25 | 60 | 180 | 90 % | 80 % | 7.5 |"));
        assert!(line(&text, "tee", "network", "bf16", 1).ends_with("| - | 0.67 | - | - | - | - | 3.3 |"));
        // A solver row has no network figures (nor a reference) and its own one-thread row.
        let solver = line(&text, "tee", "solver 30", "f32", 2);
        assert!(
            solver.ends_with("| - | f32 | - | 2 | 50.00 | 50.00 | - | - | - | 1.60 | - | 60 | 180 | 90 % | 80 % | - |"),
            "{solver}"
        );
        assert!(text.contains("| tee | 1311 | 2 | 750.0 | 750.0 |"), "{text}");
    }
}
