//! `hood train`: a training run in a folder (checkpoint, exported model, logs), resumable.

use crate::progress::Progress;
use clap::Args;
use hood::io::{json, write_atomic};
use hood::model::ModelBytes;
use hood::train::config::PullStart;
use hood::train::{Dataset, IterationReport, TrainConfig, Trainer, ValidationReport};
use serde::Serialize;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[derive(Args)]
pub struct TrainArgs {
    /// Run folder: `checkpoint.safetensors`, `model.hood`, `log.jsonl`, `validation.jsonl`,
    /// `config.json`. A run already there is resumed. Create a file `STOP` in it to end the run
    /// cleanly at the next iteration.
    #[arg(long, default_value = "~/hood-train/compact")]
    dir: String,
    /// Config file (JSON; every key optional, see `hood::train::TrainConfig`). Ignored when
    /// resuming from a checkpoint (its own config is used).
    #[arg(long)]
    config: Option<PathBuf>,
    /// When resuming, train from now on on the scenes of this config instead of the run's own
    /// (a deliberate fork of the data: weights, optimiser state, schedule and the rest carry
    /// on; `config.json` and later checkpoints record the new scenes). Keep the run's first
    /// scenes first: the periodic validation rolls out the first ones.
    #[arg(long)]
    scenes_from: Option<PathBuf>,
    /// Carried rollouts `TRACKS,RESET` (config key `carry`), overriding the config's, also when
    /// resuming: TRACKS rollouts continue from where they last ended, each restarted from the
    /// skinned garment with probability RESET when drawn (`0,0` turns carrying off).
    #[arg(long, value_parser = parse_carry)]
    carry: Option<(usize, f64)>,
    /// Probability that a fresh sample starts from a state of its scene's reference rollout
    /// (config key `reference_states`), overriding the config's, also when resuming. The
    /// reference rollouts (implicit steps of the training objective) are computed once and kept
    /// in `DIR/reference/`.
    #[arg(long, value_parser = parse_probability)]
    reference_states: Option<f64>,
    /// The supervised pull toward the implicit step's optimum `WEIGHT,UNTIL,ITERATIONS` (config
    /// key `supervised`), overriding the config's, also when resuming: weight, the iteration at
    /// which the pull ends (the objective alone after it), L-BFGS iterations per optimum. For
    /// example `0,0,30` continues a supervised run on the objective alone.
    #[arg(long, value_parser = parse_supervised)]
    supervised: Option<(f64, u64, usize)>,
    /// Where the supervised pull's L-BFGS starts (config key `supervised_start`), overriding the
    /// config's, also when resuming: `coasting` (the pull's target is the step's optimum) or
    /// `prediction` (the target is the network's own prediction refined by those iterations).
    #[arg(long, value_parser = parse_pull_start)]
    supervised_start: Option<PullStart>,
    /// Base learning rate (config key `learning_rate`), overriding the config's, also when
    /// resuming (a deliberate fork: the schedule's halvings so far still apply, so the rate in
    /// force becomes `BASE · (0.5^halvings + 0.01)`; it is printed).
    #[arg(long)]
    learning_rate: Option<f64>,
    /// Decay of the moving average of the weights that exports and validation use (config key
    /// `ema`, e.g. 0.999; 0 turns it off), overriding the config's, also when resuming (the
    /// average then starts at the current weights unless the checkpoint holds one).
    #[arg(long)]
    ema: Option<f64>,
    /// Train bf16-exact weights from now on (config key `bf16_weights`), also when resuming:
    /// the passes use the weights that bf16 precision runs in bf16 rounded to bf16, and exports
    /// hold them rounded, so that the exported model runs the same weights in f32 and bf16.
    #[arg(long)]
    bf16_weights: bool,
    /// Start from an exported model's weights and statistics when the folder has no
    /// checkpoint (for example a committed `models/*.hood`).
    #[arg(long)]
    from_model: Option<PathBuf>,
    /// Override the total number of iterations.
    #[arg(long)]
    iterations: Option<u64>,
    /// Threads of this run, overriding the config's (also when resuming: results do not depend
    /// on the thread count).
    #[arg(long)]
    threads: Option<usize>,
    /// Stop (with a checkpoint) after this many hours of wall time.
    #[arg(long)]
    hours: Option<f64>,
    /// Also copy the exported model here at every checkpoint.
    #[arg(long)]
    export: Option<PathBuf>,
    /// Keep the exported model of every N-th iteration as `DIR/snapshots/ITERATION.hood`, for
    /// `hood validate` to compare. A snapshot is written once: a resumed run that passes the
    /// same iteration again leaves it as it is.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    snapshot_every: Option<u64>,
    /// The assets folder (MakeHuman body, garments, motion clips; default: $HOOD_ASSETS, else
    /// `shared/assets` in the working directory or a parent). Without one, the scenes that need
    /// it are skipped with a warning.
    #[arg(long)]
    assets: Option<PathBuf>,
    /// Start afresh even when the folder holds a checkpoint.
    #[arg(long)]
    fresh: bool,
}

fn parse_probability(text: &str) -> Result<f64, String> {
    let p: f64 = text.parse().map_err(|e| format!("{e}"))?;
    hood::train::config::probability(p, "reference_states").map_err(|e| e.to_string())
}

fn parse_carry(text: &str) -> Result<(usize, f64), String> {
    hood::train::config::parse_carry(text).map_err(|e| e.to_string())
}

fn parse_supervised(text: &str) -> Result<(f64, u64, usize), String> {
    hood::train::config::parse_supervised(text).map_err(|e| e.to_string())
}

fn parse_pull_start(text: &str) -> Result<PullStart, String> {
    PullStart::parse(text).map_err(|e| e.to_string())
}

fn expand(dir: &str) -> PathBuf {
    match (dir.strip_prefix("~/"), std::env::var_os("HOME")) {
        (Some(rest), Some(home)) => PathBuf::from(home).join(rest),
        _ => PathBuf::from(dir),
    }
}

/// One step of a `log.jsonl` line.
#[derive(Serialize)]
struct StepLine {
    total: f32,
    stretching: f32,
    bending: f32,
    inertia: f32,
    gravity: f32,
    collision: f32,
    friction: f32,
    supervised: f32,
    grad_norm: f64,
    startup: bool,
    skipped: bool,
}

/// A `log.jsonl` line: one training iteration.
#[derive(Serialize)]
struct IterationLine {
    iteration: u64,
    scene: usize,
    vertices: usize,
    warmup: bool,
    lr: f64,
    collision_weight: f64,
    carried_from: Option<usize>,
    reference: bool,
    seconds: f64,
    steps: Vec<StepLine>,
}

fn iteration_json(r: &IterationReport, seconds: f64) -> String {
    let steps = r
        .steps
        .iter()
        .map(|s| StepLine {
            total: s.total,
            stretching: s.terms.stretching,
            bending: s.terms.bending,
            inertia: s.terms.inertia,
            gravity: s.terms.gravity,
            collision: s.terms.collision,
            friction: s.terms.friction,
            supervised: s.supervised,
            grad_norm: s.grad_norm,
            startup: s.startup,
            skipped: s.skipped,
        })
        .collect();
    json::to_line(&IterationLine {
        iteration: r.iteration,
        scene: r.scene,
        vertices: r.vertices,
        warmup: r.warmup,
        lr: r.learning_rate,
        collision_weight: r.collision_weight,
        carried_from: r.carried_from,
        reference: r.from_reference,
        seconds: (seconds * 10.0).round() / 10.0,
        steps,
    })
}

/// One rollout of a `validation.jsonl` line (the numbers absent when it was not finite).
#[derive(Serialize)]
struct RolloutLine<'a> {
    scene: &'a str,
    finite: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    total: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    penetrating_percent: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    max_edge_strain: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    max_speed: Option<f64>,
}

/// A `validation.jsonl` line.
#[derive(Serialize)]
struct ValidationLine<'a> {
    iteration: u64,
    finite: bool,
    mean_total: f64,
    mean_penetrating_percent: f64,
    rollouts: Vec<RolloutLine<'a>>,
}

fn validation_json(v: &ValidationReport) -> String {
    let rollouts = v
        .rollouts
        .iter()
        .map(|(name, s)| RolloutLine {
            scene: name,
            finite: s.is_some(),
            total: s.as_ref().map(|s| s.mean.total),
            penetrating_percent: s.as_ref().map(|s| s.mean.penetrating_percent),
            max_edge_strain: s.as_ref().map(|s| s.frames.iter().map(|f| f.max_edge_strain).fold(0.0, f64::max)),
            max_speed: s.as_ref().map(|s| s.frames.iter().map(|f| f.max_speed).fold(0.0, f64::max)),
        })
        .collect();
    let (mean_total, mean_penetrating_percent) = v.means();
    json::to_line(&ValidationLine {
        iteration: v.iteration,
        finite: v.finite(),
        mean_total,
        mean_penetrating_percent,
        rollouts,
    })
}

/// Keeps the lines of a JSON-lines log whose `iteration` is below `limit` (so that a resumed
/// run's log reads as if it had never stopped). Lines that do not parse are dropped.
fn truncate_log(path: &Path, limit: u64) -> hood::Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else { return Ok(()) };
    let keep: Vec<&str> = text
        .lines()
        .filter(|l| {
            json::parse_lenient(l)
                .ok()
                .and_then(|v| v.get("iteration").and_then(json::Value::as_u64))
                .is_some_and(|n| n < limit)
        })
        .collect();
    let mut out = keep.join("\n");
    if !out.is_empty() {
        out.push('\n');
    }
    std::fs::write(path, out).map_err(|e| hood::Error::io(path, e))
}

fn append(path: &Path, line: &str) -> hood::Result<()> {
    let mut f =
        std::fs::OpenOptions::new().create(true).append(true).open(path).map_err(|e| hood::Error::io(path, e))?;
    writeln!(f, "{line}").map_err(|e| hood::Error::io(path, e))
}

fn build_data(cfg: &TrainConfig, assets: &Path) -> hood::Result<Dataset> {
    let t = Instant::now();
    let bar = Progress::new("building scenes", "scenes", cfg.scenes.len() as u64, Duration::from_secs(10));
    let mut built = 0;
    let data = Dataset::build(cfg, assets, |name| {
        bar.set_position(built);
        bar.set_message(name);
        built += 1;
    })?;
    bar.finish();
    eprintln!("{} scenes built in {:.1} s", data.scenes.len(), t.elapsed().as_secs_f64());
    for (name, why) in &data.skipped {
        eprintln!("  skipped {name}: {why}");
    }
    Ok(data)
}

pub fn train(a: TrainArgs) -> hood::Result<()> {
    let dir = expand(&a.dir);
    std::fs::create_dir_all(&dir).map_err(|e| hood::Error::io(&dir, e))?;
    let assets = match hood::assets::locate(a.assets.as_deref()) {
        Ok(dir) => dir,
        Err(e) if a.assets.is_none() => {
            eprintln!("warning: {e}");
            PathBuf::from("assets")
        }
        Err(e) => return Err(e),
    };
    let ckpt = dir.join("checkpoint.safetensors");
    let log = dir.join("log.jsonl");
    let vlog = dir.join("validation.jsonl");
    let stop = dir.join("STOP");
    let _ = std::fs::remove_file(&stop);
    let mut t = if ckpt.exists() && !a.fresh {
        let st = hood::io::safetensors::SafeTensors::read(&ckpt)?;
        let mut cfg = hood::train::session::checkpoint_config(&st)?;
        if let Some(p) = &a.scenes_from {
            let other = TrainConfig::from_json(&std::fs::read_to_string(p).map_err(|e| hood::Error::io(p, e))?)?;
            eprintln!("scenes from {}: {} instead of {}", p.display(), other.scenes.len(), cfg.scenes.len());
            cfg.scenes = other.scenes;
        }
        let mut t = Trainer::resume(&ckpt, build_data(&cfg, &assets)?)?;
        t.cfg.scenes = cfg.scenes;
        eprintln!("resumed {} at iteration {}", ckpt.display(), t.iteration);
        t
    } else {
        if let Some(p) = &a.scenes_from {
            let message = "--scenes-from forks a run being resumed; a new run takes its scenes from --config";
            return Err(hood::Error::parse("--scenes-from", 0, format!("{}: {message}", p.display())));
        }
        let cfg = match &a.config {
            Some(p) => TrainConfig::from_json(&std::fs::read_to_string(p).map_err(|e| hood::Error::io(p, e))?)?,
            None => TrainConfig::default(),
        };
        let data = build_data(&cfg, &assets)?;
        match &a.from_model {
            Some(p) => {
                let bytes = ModelBytes::new(&std::fs::read(p).map_err(|e| hood::Error::io(p, e))?);
                let t = Trainer::from_model(cfg, data, &bytes.model()?)?;
                eprintln!("continuing from {} (iteration {}, fresh optimiser)", p.display(), t.iteration);
                t
            }
            None => Trainer::new(cfg, data)?,
        }
    };
    if let Some(n) = a.iterations {
        t.cfg.iterations = n;
    }
    if let Some(n) = a.threads {
        t.set_threads(n);
    }
    if let Some(c) = a.carry {
        t.set_carry(c);
    }
    if let Some(s) = a.supervised {
        t.cfg.supervised = s;
        eprintln!("supervised pull: weight {:e} until iteration {}, {} L-BFGS iterations", s.0, s.1, s.2);
    }
    if let Some(start) = a.supervised_start {
        t.cfg.supervised_start = start;
        eprintln!("supervised pull's L-BFGS starts from {}", start.name());
    }
    if let Some(d) = a.ema {
        t.set_ema(d)?;
    }
    if a.bf16_weights {
        t.cfg.bf16_weights = true;
    }
    if t.cfg.bf16_weights {
        eprintln!("bf16 weights: the passes and exports round every weight outside the encoders to bf16");
    }
    if let Some(p) = a.reference_states {
        t.cfg.reference_states = p;
    }
    if t.cfg.reference_states > 0.0 {
        let clock = Instant::now();
        let weight = t.cfg.collision_weight.1;
        let bar = Progress::new("reference rollout", "frames", 0, Duration::from_secs(10));
        let threads = t.cfg.threads;
        t.data.attach_reference_states(Some(&dir.join("reference")), weight, threads, |name, done, of| {
            bar.set_length(of as u64);
            bar.set_position(done as u64);
            bar.set_message(name);
        })?;
        bar.finish();
        for ((states, scene), name) in t.data.reference.iter().zip(&t.data.scenes).zip(&t.data.names) {
            if states.len() < scene.n_frames() {
                eprintln!(
                    "reference rollout of {name}: states before frame {0} (the garment has fallen off, or the step \
                     fails, at frame {0})",
                    states.len()
                );
            }
        }
        let frames: usize = t.data.reference.iter().map(|r| r.len()).sum();
        eprintln!(
            "reference states: {frames} frames over {} scenes ({:.0} s); {} of fresh samples start from one",
            t.data.reference.len(),
            clock.elapsed().as_secs_f64(),
            t.cfg.reference_states,
        );
    }
    if let Some(lr) = a.learning_rate {
        if !(lr.is_finite() && lr > 0.0) {
            return Err(hood::Error::parse("--learning-rate", 0, format!("{lr} is not a positive rate")));
        }
        t.cfg.learning_rate = lr;
        eprintln!("base learning rate {lr:e}: {:e} in force", t.cfg.learning_rate_at(t.optimiser_steps));
    }
    truncate_log(&log, t.iteration)?;
    truncate_log(&vlog, t.iteration + 1)?;
    write_atomic(&dir.join("config.json"), t.cfg.to_json().as_bytes())?;
    eprintln!(
        "training h = {}, {} parameters, {} scenes, to iteration {} in {}; matrix products on {}",
        t.cfg.latent,
        t.parameter_count(),
        t.data.scenes.len(),
        t.cfg.iterations,
        dir.display(),
        hood::train::Gemm::best().tier().name()
    );
    #[cfg(target_arch = "x86_64")]
    if let Some(choice) = hood::train::Gemm::tile_choice() {
        eprintln!("{}", choice.describe());
    }
    let started = Instant::now();
    let deadline = a.hours.map(|h| h * 3600.0);
    let mut last_print = Instant::now();
    let mut recent = 0.0f64;
    // Plain lines (stderr not a terminal: a log file) once a minute.
    let bar = Progress::new("train", "it", t.cfg.iterations, Duration::from_secs(60));
    bar.start_at(t.iteration);
    let snapshots = dir.join("snapshots");
    // The checkpoint, `model.hood` and the snapshot that are due, from one export.
    let save = |t: &Trainer, checkpoint: bool| -> hood::Result<()> {
        let snapshot = a
            .snapshot_every
            .filter(|n| t.iteration.is_multiple_of(*n))
            .map(|_| snapshots.join(format!("{}.hood", t.iteration)))
            .filter(|p| !p.exists());
        if !checkpoint && snapshot.is_none() {
            return Ok(());
        }
        let bytes = t.export(&[])?;
        if checkpoint {
            t.save_checkpoint(&ckpt)?;
            write_atomic(&dir.join("model.hood"), &bytes)?;
            if let Some(p) = &a.export {
                write_atomic(p, &bytes)?;
            }
        }
        if let Some(p) = snapshot {
            std::fs::create_dir_all(&snapshots).map_err(|e| hood::Error::io(&snapshots, e))?;
            write_atomic(&p, &bytes)?;
        }
        Ok(())
    };
    while t.iteration < t.cfg.iterations {
        let it_start = Instant::now();
        let r = t.iteration()?;
        t.seconds += it_start.elapsed().as_secs_f64();
        append(&log, &iteration_json(&r, t.seconds))?;
        if let Some(s) = r.steps.iter().rev().find(|s| !s.skipped) {
            let per_vertex = s.total as f64 / r.vertices.max(1) as f64;
            recent = if recent == 0.0 { per_vertex } else { 0.98 * recent + 0.02 * per_vertex };
        }
        if t.iteration % t.cfg.validate_every == 0 {
            let v = t.validate()?;
            append(&vlog, &validation_json(&v))?;
            let (total, pen) = v.means();
            bar.println(format!(
                "validation at {}: finite {}, mean objective {total:.4e}, penetrating {pen:.2} %",
                t.iteration,
                v.finite()
            ));
        }
        let out_of_time = deadline.is_some_and(|d| started.elapsed().as_secs_f64() > d);
        let stopping = out_of_time || stop.exists();
        save(&t, t.iteration % t.cfg.checkpoint_every == 0 || stopping || t.iteration == t.cfg.iterations)?;
        if last_print.elapsed().as_secs_f64() > 1.0 {
            bar.set_message(format!("loss {recent:.3e}"));
            bar.set_position(t.iteration);
            last_print = Instant::now();
        }
        if stopping {
            bar.finish();
            eprintln!("stopped at iteration {} (checkpoint written)", t.iteration);
            return Ok(());
        }
    }
    bar.set_message(format!("loss {recent:.3e}"));
    bar.set_position(t.iteration);
    bar.finish();
    eprintln!("done: {} iterations, {} optimiser steps, {:.0} s", t.iteration, t.optimiser_steps, t.seconds);
    Ok(())
}
