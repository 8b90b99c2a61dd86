//! The `hood` command line (feature `cli`).

use clap::{Args, Parser, Subcommand};
use hood::model::{write_model, ModelBytes, ModelSpec, Params};
use std::path::PathBuf;
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

#[path = "cmd/bench.rs"]
mod bench;
#[path = "cmd/machine.rs"]
mod machine;
#[path = "cmd/objective.rs"]
mod objective;
#[path = "cmd/plot.rs"]
mod plot;
#[path = "cmd/progress.rs"]
mod progress;
#[path = "cmd/reference.rs"]
mod reference;
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
    Bench(bench::BenchArgs),
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
    /// Rewrite model files in this build's layout (format version, checksum, weights on cache
    /// lines), in place: the same weights, normalisers and provenance.
    Upgrade(UpgradeArgs),
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
        "{}: h = {}, {} blocks, {} levels, {} parameters, bf16 weights: {}{}",
        a.model.display(),
        spec.latent,
        spec.blocks.len(),
        spec.levels,
        spec.parameter_count(),
        m.has_bf16(),
        if m.bf16_exact() { " (bf16-exact: f32 runs the same weights)" } else { "" }
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
struct UpgradeArgs {
    /// The `.hood` files to rewrite.
    #[arg(required = true)]
    models: Vec<PathBuf>,
}

fn upgrade(a: UpgradeArgs) -> hood::Result<()> {
    for path in &a.models {
        let old = ModelBytes::read(path)?;
        let model = old.model()?;
        let params = model.to_params();
        let provenance: Vec<(&str, &str)> = model.provenance().collect();
        let bytes = write_model(&params, model.has_bf16(), &provenance)?;
        let new = ModelBytes::new(&bytes);
        if new.model()?.to_params() != params {
            return Err(hood::Error::CorruptData { reason: "an upgraded model file reads back different weights" });
        }
        // Written beside and renamed over, so an interrupted upgrade leaves the old file whole.
        let tmp = path.with_extension("hood.upgrade");
        std::fs::write(&tmp, &bytes).map_err(|e| hood::Error::io(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| hood::Error::io(path, e))?;
        eprintln!("{}: {} -> {} bytes", path.display(), old.as_bytes().len(), bytes.len());
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(a) => simulate::simulate(a),
        Command::Report(a) => report::report(a),
        Command::Bench(a) => bench::bench(a),
        Command::Convert(a) => convert(a),
        Command::Info(a) => info(a),
        Command::Average(a) => average(a),
        Command::Upgrade(a) => upgrade(a),
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
