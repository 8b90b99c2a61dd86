//! The `hood` command line (feature `cli`).

use clap::{Args, Parser, Subcommand};
use hood::bench::{bench_step, core_to_core_ns, machine_peak, BenchRow};
use hood::model::{write_model, ModelBytes, ModelSpec, Params};
use hood::sim::{Precision, StepMode};
use hood::workloads::{workload, NAMES};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `println!` for the command's output, without its panic: a closed stdout (`hood info m.hood |
/// head`) ends the program quietly, any other write error with a message and status 1.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let mut out = std::io::stdout().lock();
        if let Err(e) = writeln!(out, $($arg)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
            eprintln!("hood: writing to stdout: {e}");
            std::process::exit(1);
        }
    }};
}

#[path = "cmd/objective.rs"]
mod objective;
#[path = "cmd/plot.rs"]
mod plot;
#[path = "cmd/progress.rs"]
mod progress;
#[path = "cmd/report.rs"]
mod report;
#[path = "cmd/simulate.rs"]
mod simulate;
#[cfg(feature = "train")]
#[path = "cmd/train.rs"]
mod train_cmd;
#[path = "cmd/validate.rs"]
mod validate;
#[path = "cmd/verdict.rs"]
mod verdict;

#[derive(Parser)]
#[command(name = "hood", version, about = "HOOD-style neural cloth: simulate, measure, train")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a model on a scene (default: the shipped model, dress on the walking mannequin):
    /// OBJ sequence, PNG preview strip, per-step timing and objective.
    Simulate(simulate::SimulateArgs),
    /// Accuracy against time: variants x workloads -> docs/report.md and docs/report.svg.
    Report(report::ReportArgs),
    /// Step latency per workload, model size, precision and thread count (EVALUATION.md).
    Bench(BenchArgs),
    /// Convert a reference HOOD checkpoint's state dict (as safetensors) into a `.hood` file.
    Convert(ConvertArgs),
    /// Print a model file's shape, provenance and normaliser statistics.
    Info(InfoArgs),
    /// The model cards' validation: the four 300-frame scenes (skirt, dress, t-shirt, jeans),
    /// gap on the own rollout and from common states, penetration, strain; a Markdown table and
    /// PNG strips.
    Validate(validate::ValidateArgs),
    /// Average the weights of several models of one shape (e.g. snapshots of one training run).
    Average(AverageArgs),
    /// Train a model from physics alone (feature `train`); resumes the run in `--dir`.
    #[cfg(feature = "train")]
    Train(train_cmd::TrainArgs),
    /// Draw a training run's curves (validation objective and % penetrating, training loss)
    /// from its logs as an SVG.
    Plot(plot::PlotArgs),
}

#[derive(Args)]
struct InfoArgs {
    /// The `.hood` file.
    model: PathBuf,
}

fn info(a: InfoArgs) -> hood::Result<()> {
    let bytes = ModelBytes::new(&std::fs::read(&a.model).map_err(|e| hood::Error::io(&a.model, e))?);
    let m = bytes.model()?;
    let spec = m.spec();
    say!(
        "{}: h = {}, {} blocks, {} levels, {} parameters, bf16 weights: {}",
        a.model.display(),
        spec.latent,
        spec.blocks.len(),
        spec.levels,
        spec.parameter_count(),
        m.has_bf16()
    );
    let show = |name: &str, (mean, std): (&[f32], &[f32])| {
        let f = |v: &[f32]| v.iter().map(|x| format!("{x:.3e}")).collect::<Vec<_>>().join(" ");
        say!("{name} mean [{}]\n{name} std  [{}]", f(mean), f(std));
    };
    show("node", m.node_stats());
    show("edge", m.edge_stats());
    show("body edge", m.body_edge_stats());
    show("output", m.output_stats());
    for (k, v) in m.provenance() {
        say!("{k}: {v}");
    }
    Ok(())
}

#[derive(Args)]
struct ConvertArgs {
    /// The state dict as safetensors (keys of `Model.state_dict()`, with or without `model.`).
    state_dict: PathBuf,
    /// Output `.hood` file.
    #[arg(long, short)]
    out: PathBuf,
    /// Leave out the bf16 copy of the weights (smaller file; f32 only).
    #[arg(long)]
    no_bf16: bool,
}

fn convert(a: ConvertArgs) -> hood::Result<()> {
    use hood::model::reference::{latent_width, params_from_state_dict};
    let st = hood::io::safetensors::SafeTensors::read(&a.state_dict)?;
    let spec = ModelSpec::hood(latent_width(&st)?);
    let params = params_from_state_dict(&st, &spec)?;
    let source = a.state_dict.display().to_string();
    let bytes =
        write_model(&params, !a.no_bf16, &[("converted_from", source.as_str()), ("architecture", "HOOD postcvpr")])?;
    ModelBytes::new(&bytes).model()?; // what we write must load
    std::fs::write(&a.out, &bytes).map_err(|e| hood::Error::io(&a.out, e))?;
    eprintln!("wrote {} ({} parameters, h = {}, {} bytes)", a.out.display(), params.count(), spec.latent, bytes.len());
    Ok(())
}

#[derive(Args)]
struct AverageArgs {
    /// The `.hood` files (same shape). The normaliser statistics and provenance are the last
    /// file's, with an `averaged_from` entry added.
    #[arg(required = true)]
    models: Vec<PathBuf>,
    /// Output `.hood` file.
    #[arg(long, short)]
    out: PathBuf,
}

fn average(a: AverageArgs) -> hood::Result<()> {
    let files: Vec<ModelBytes> = a
        .models
        .iter()
        .map(|p| std::fs::read(p).map(|b| ModelBytes::new(&b)).map_err(|e| hood::Error::io(p, e)))
        .collect::<Result<_, _>>()?;
    let models: Vec<hood::model::Model<'_>> = files.iter().map(|f| f.model()).collect::<Result<_, _>>()?;
    let params: Vec<Params> = models.iter().map(|m| m.to_params()).collect();
    let mean = Params::average(&params)?;
    let sources: Vec<String> = a
        .models
        .iter()
        .zip(&models)
        .map(|(p, m)| {
            let its = m.provenance().find(|(k, _)| *k == "iterations").map_or("?", |(_, v)| v);
            format!("{} ({its} it.)", p.display())
        })
        .collect();
    let sources = sources.join(", ");
    let last = models.last().expect("clap requires one model at least");
    let mut prov: Vec<(&str, &str)> = last.provenance().filter(|(k, _)| *k != "averaged_from").collect();
    prov.push(("averaged_from", &sources));
    let bytes = write_model(&mean, last.has_bf16(), &prov)?;
    ModelBytes::new(&bytes).model()?; // what we write must load
    std::fs::write(&a.out, &bytes).map_err(|e| hood::Error::io(&a.out, e))?;
    eprintln!("wrote {}: mean of {} models", a.out.display(), params.len());
    Ok(())
}

#[derive(Args)]
struct BenchArgs {
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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(a) => simulate::simulate(a),
        Command::Report(a) => report::report(a),
        Command::Bench(a) => bench(a),
        Command::Convert(a) => convert(a),
        Command::Info(a) => info(a),
        Command::Average(a) => average(a),
        Command::Validate(a) => validate::validate(a),
        Command::Plot(a) => plot::plot(a),
        #[cfg(feature = "train")]
        Command::Train(a) => train_cmd::train(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hood: {e}");
            ExitCode::FAILURE
        }
    }
}

fn random_model(spec: &ModelSpec) -> hood::Result<ModelBytes> {
    let mut p = Params::init(spec, 0)?;
    p.normalisers = hood::model::Normalisers::unit_scale(1);
    Ok(ModelBytes::new(&write_model(&p, true, &[("kind", "random, for timing")])?))
}

fn bench(a: BenchArgs) -> hood::Result<()> {
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
    if precisions.contains(&Precision::Bf16) {
        eprintln!("{}", hood::kernels::bf16_choice().describe());
    }
    if a.threads.iter().any(|&t| t > 1) {
        if let Some(ns) = core_to_core_ns() {
            eprintln!("core-to-core latency: {ns:.0} ns one way (about 35: threads share an L3; 170-200: across chiplets, slower 2-thread steps; more: a busy machine)");
        }
    }
    let mut rows: Vec<BenchRow> = Vec::new();
    let mut push = |r: BenchRow| {
        if !a.json {
            print_row(&r, rows.is_empty());
        }
        rows.push(r);
    };
    for w in &workloads {
        for mb in &models {
            let model = mb.model()?;
            for &p in &precisions {
                for &t in &a.threads {
                    push(bench_step(w, &model, StepMode::Network, p, t, a.warmup, a.steps, &peak)?);
                }
            }
        }
        if let Some(mb) = models.first() {
            let model = mb.model()?;
            for &iterations in &a.solver {
                for &t in &a.threads {
                    let solver = StepMode::Solver { iterations };
                    push(bench_step(w, &model, solver, Precision::F32, t, a.warmup, a.steps, &peak)?);
                }
            }
        }
    }
    if a.json {
        say!("{}", to_json(&rows, &peak));
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
            "{:<9} {:>6} {:>6} {:>10} {:>4} {:>5} {:>10} {:>3} {:>10} {:>10} {:>9} {:>8} {:>6}",
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
            "eff"
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
        "{:<9} {:>6} {:>6} {:>10} {:>4} {:>5} {:>10} {:>3} {:>10.2} {:>10} {:>9} {:>8} {:>6}",
        r.workload,
        r.vertices,
        r.body_edges,
        step_name(r.step),
        h,
        if r.precision == Precision::Bf16 { "bf16" } else { "f32" },
        if network { r.tier.name() } else { "-" },
        r.threads,
        r.median_ms,
        flops,
        gflops,
        peak,
        eff
    );
}

/// `hood bench --json`: the machine's peak and one object per row.
fn to_json(rows: &[BenchRow], peak: &hood::kernels::peak::Peak) -> String {
    #[derive(serde::Serialize)]
    struct Peak {
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
    }
    #[derive(serde::Serialize)]
    struct Bench<'a> {
        peak: Peak,
        rows: Vec<Row<'a>>,
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
            precision: if r.precision == Precision::Bf16 { "bf16" } else { "f32" },
            tier: r.tier.name(),
            threads: r.threads,
            median_ms: r.median_ms,
            min_ms: r.min_ms,
            flops: r.flops,
            gflops: r.gflops,
            peak_gflops: r.peak_gflops,
            efficiency: r.efficiency,
        })
        .collect();
    let peak = Peak { tier: peak.tier.name(), f32_gflops: peak.f32_gflops, bf16_gflops: peak.bf16_gflops };
    hood::io::json::to_line(&Bench { peak, rows })
}
