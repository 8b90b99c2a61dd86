//! `hood report`: accuracy against time (EVALUATION.md). Variants (models and their precisions,
//! models refined by the solver, the runtime's solver step mode and the f64 implicit solver at
//! several iteration counts) x workloads (garment and motion) -> a Markdown table per workload with
//! the Pareto front of time against gap marked and the off-body verdict, and an SVG plot of the
//! relative objective gap against ms per step.

use crate::objective::ObjectiveArg;
use crate::progress::Progress;
use clap::Args;
use hood::eval::{common_state_gaps, converged_solver, implicit_rollout, rollout, Animation, Method, Rollout};
use hood::eval::{Reference, RolloutOptions, Summary};
use hood::mesh::Material;
use hood::model::{write_model, ModelBytes, ModelSpec, Normalisers, Params};
use hood::rig::procedural::Mannequin;
use hood::scene::{procedural, GarmentKind, MotionKind, Scene};
use hood::sim::{Precision, SimConfig, StepMode, MAX_REFINE_ITERATIONS};
use hood::{Error, Result};
use std::path::{Path, PathBuf};
use std::time::Duration;

#[path = "report/markdown.rs"]
mod markdown;
#[path = "report/svg.rs"]
mod svg;

use markdown::{markdown, plot_file, replace_marked, which_step_table, workload_names};
use svg::svg_plot;

#[derive(Args)]
pub struct ReportArgs {
    /// Model files (comma-separated); default: every `models/*.hood` of the working directory, or untrained random models
    /// (timing only) when there is none.
    #[arg(long, value_delimiter = ',')]
    model: Vec<PathBuf>,
    /// Workloads `GARMENT[@VERTICES][:MOTION][/MATERIAL]`: skirt, dress, cape (procedural
    /// mannequin, about VERTICES vertices, default `--vertices`), tee, jeans (MakeHuman; skipped
    /// when the assets are absent); the motion as `hood simulate --motion` takes it (default:
    /// walk, for tee and jeans the CMU walk); the material one of default, soft-stretch,
    /// stiff-stretch, soft-bend, stiff-bend (the ends of the training ranges), e.g.
    /// `skirt@4000:run/stiff-bend,tee:jumps-1001`.
    #[arg(long, value_delimiter = ',', default_value = "skirt,jeans")]
    workload: Vec<String>,
    /// Vertices of the procedural garments (approximate).
    #[arg(long, default_value_t = 1000)]
    vertices: usize,
    /// Frames per rollout.
    #[arg(long, default_value_t = 30)]
    frames: usize,
    /// The gap is computed every this many frames (each costs a converged implicit step).
    #[arg(long, default_value_t = 5)]
    gap_every: usize,
    /// L-BFGS iteration counts of the implicit-solver variants.
    #[arg(long, value_delimiter = ',', default_value = "1,3,10,30,100")]
    iterations: Vec<usize>,
    /// Model and solver together: for every model (f32), also a variant whose every step is
    /// refined by this many L-BFGS iterations from the network's prediction (the runtime effect
    /// `SimConfig::refine`; comma-separated).
    #[arg(long, value_delimiter = ',')]
    refine: Vec<u32>,
    /// The runtime's solver step mode (`StepMode::Solver`, f32, no network) at these L-BFGS
    /// iteration counts per step (comma-separated): the solver a game would ship, beside the f64
    /// implicit solver of `--iterations`.
    #[arg(long, value_delimiter = ',')]
    solver: Vec<u32>,
    /// The runtime's solver step mode within a time budget (`StepMode::SolverBudget`): each
    /// step's solve ends after this many milliseconds (comma-separated, e.g. `5,15,40`), or
    /// after 1,000 iterations.
    #[arg(long, value_delimiter = ',')]
    solver_budget: Vec<f64>,
    /// Threads of the runtime's step (network, refinement and solver step mode).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Also score every variant one step at a time from common states (those of a converged
    /// implicit rollout of the training objective), on the frames `--gap-every` picks: a second
    /// table and `report-common.svg`.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    common_states: bool,
    /// Objective of the frames and of the gap.
    #[arg(long, value_enum, default_value_t = ObjectiveArg::Evaluation)]
    objective: ObjectiveArg,
    /// Output folder for `report.md` and `report.svg`.
    #[arg(long, short, default_value = "docs")]
    out: PathBuf,
    /// The assets folder: MakeHuman body, garments, motion clips (default: $HOOD_ASSETS, else
    /// `shared/assets` in the working directory or a parent).
    #[arg(long)]
    assets: Option<PathBuf>,
    /// Also write the "which step for your garment and budget" table into this Markdown file
    /// (the README), between the lines `<!-- which-step OUT begin -->` and
    /// `<!-- which-step OUT end -->`, OUT being `--out` as given. The file must hold both.
    #[arg(long)]
    readme: Option<PathBuf>,
}

/// One measured variant on one workload.
#[derive(Clone)]
struct Row {
    workload: String,
    vertices: usize,
    variant: String,
    implicit: bool,
    /// Scored one step at a time from common states rather than on its own rollout.
    common: bool,
    summary: Summary,
}

/// A model to report: its bytes and a label; `trained` false for random stand-ins.
struct Candidate {
    label: String,
    bytes: ModelBytes,
    trained: bool,
}

fn random(label: &str, spec: ModelSpec) -> Result<Candidate> {
    let mut p = Params::init(&spec, 0)?;
    p.normalisers = Normalisers::unit_scale(1);
    let bytes = ModelBytes::new(&write_model(&p, true, &[("kind", "random, untrained")])?);
    Ok(Candidate { label: format!("{label} (random)"), bytes, trained: false })
}

fn spec_label(s: &ModelSpec) -> String {
    format!("h={} blocks={} levels={}", s.latent, s.blocks.len(), s.levels)
}

fn candidates(a: &ReportArgs) -> Result<Vec<Candidate>> {
    let mut files = a.model.clone();
    if files.is_empty() {
        let dir = Path::new("models");
        if let Ok(rd) = std::fs::read_dir(dir) {
            files = rd
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "hood"))
                .collect();
            files.sort();
        }
    }
    if files.is_empty() {
        eprintln!("no model files: timing untrained random models (their gap is meaningless)");
        return Ok(vec![
            random("hood h=32", ModelSpec::hood(32))?,
            random("hood h=64", ModelSpec::hood(64))?,
            random("flat h=32", ModelSpec::with_schedule(32, 2, 0, &["f"; 15].join(" | "))?)?,
            random("5 blocks h=32", ModelSpec::with_schedule(32, 2, 3, "f,c0 | d:c0,c1 | d:c1 | u:c0,c1 | u:f,c0")?)?,
        ]);
    }
    files
        .iter()
        .map(|f| {
            let bytes = ModelBytes::read(f)?;
            let spec = bytes.model()?.spec().clone();
            let stem = f.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
            Ok(Candidate { label: format!("{stem} {}", spec_label(&spec)), bytes, trained: true })
        })
        .collect()
}

fn workload(a: &ReportArgs, name: &str, m: &Mannequin) -> Result<Option<Box<dyn Animation>>> {
    let seconds = (a.frames + 1) as f32 / 30.0 + 0.1;
    let bad = |what: String| Error::parse("workload", 0, format!("{what} in '{name}'"));
    let (rest, material) = match name.split_once('/') {
        Some((r, mat)) => {
            let known = Material::PRESETS.join(", ");
            (r, Some(Material::preset(mat).ok_or_else(|| bad(format!("unknown material '{mat}' (one of {known})")))?))
        }
        None => (name, None),
    };
    let (rest, vertices) = match rest.split_once('@') {
        Some((g, v)) => {
            let (v, tail) = v.split_once(':').map_or((v, None), |(v, t)| (v, Some(t)));
            let n: usize = v.parse().map_err(|_| bad(format!("bad vertex count '{v}'")))?;
            (tail.map_or(g.to_string(), |t| format!("{g}:{t}")), n)
        }
        None => (rest.to_string(), a.vertices),
    };
    let Some(mut scene) = scene_of(a, &rest, vertices, seconds, m)? else { return Ok(None) };
    if let Some(mat) = material {
        scene.garment = scene.garment_with_material(mat)?;
    }
    Ok(Some(Box::new(scene)))
}

/// The scene of `GARMENT[:MOTION]` (procedural garments at about `vertices` vertices).
fn scene_of(a: &ReportArgs, name: &str, vertices: usize, seconds: f32, m: &Mannequin) -> Result<Option<Scene>> {
    let (garment, motion) = match name.split_once(':') {
        Some((g, mo)) => {
            let motion = MotionKind::parse(mo)
                .ok_or_else(|| Error::parse("workload", 0, format!("unknown motion '{mo}' in '{name}'")))?;
            (g, Some(motion))
        }
        None => (name, None),
    };
    if let Some(kind) = GarmentKind::parse(garment) {
        let motion = motion.unwrap_or(MotionKind::Walk);
        return Ok(Some(procedural(m, kind, vertices, motion, seconds)?));
    }
    use hood::scene::{makehuman_on, MakeHumanGarment};
    let Some(which) = MakeHumanGarment::parse(garment) else {
        return Err(Error::parse("workload", 0, format!("unknown workload '{name}'")));
    };
    // The MakeHuman garments' walk is the CMU walk (no motion given).
    let motion = motion.filter(|&mo| mo != MotionKind::Walk);
    let scene =
        hood::assets::locate(a.assets.as_deref()).and_then(|dir| makehuman_on(&dir, which, motion, a.frames + 1));
    match scene {
        Ok(s) => Ok(Some(s)),
        Err(e @ Error::Io { .. }) => {
            eprintln!("skipping {name}: {e}");
            Ok(None)
        }
        Err(e) => Err(e),
    }
}

/// Runs `hood report`.
pub fn report(a: ReportArgs) -> Result<()> {
    let models = candidates(&a)?;
    let mannequin = Mannequin::new();
    let opts = RolloutOptions::default()
        .with_gap_every(a.gap_every.max(1))
        .with_inside_every(a.gap_every.max(1))
        .with_objective(a.objective.objective());
    let mut rows = Vec::new();
    // The total grows as each workload's variants are known.
    let bar = Progress::new("report", "rollouts", 0, Duration::from_secs(10));
    for name in &a.workload {
        let Some(anim) = workload(&a, name, &mannequin)? else { continue };
        let frames = a.frames.min(anim.n_frames() - 1);
        let verts = anim.garment().n_vertices();
        let mut push = |variant: String, implicit: bool, common: bool, r: Rollout| {
            let s = r.summary;
            bar.println(format!(
                "{name:<6} {variant:<40}{} {:>8.2} ms/step  gap mean {:>7}  p95 {:>7}  penetrating {:>5.2}%{}",
                if common { " (common states)" } else { "" },
                s.median_step_ms,
                fmt_opt(s.gap_mean),
                fmt_opt(s.gap_p95),
                s.mean_penetrating_percent,
                if s.finite { "" } else { "  NOT FINITE" }
            ));
            bar.inc(1);
            rows.push(Row { workload: name.clone(), vertices: verts, variant, implicit, common, summary: s });
        };
        let loaded: Vec<_> = models.iter().map(|c| c.bytes.model()).collect::<Result<_>>()?;
        // The variants: (label, method).
        let mut variants: Vec<(String, Method<'_>)> = Vec::new();
        for (c, model) in models.iter().zip(&loaded) {
            let precisions: &[Precision] =
                if model.has_bf16() { &[Precision::F32, Precision::Bf16] } else { &[Precision::F32] };
            for &p in precisions {
                let cfg = SimConfig::network().with_precision(p).with_threads(a.threads.max(1));
                let prec = p.name();
                variants.push((format!("{} {prec}", c.label), Method::Network { model, cfg }));
            }
            for &k in &a.refine {
                let cfg = SimConfig::network().with_threads(a.threads.max(1)).with_refine(Some(k.max(1)));
                variants.push((format!("{} f32 + refine {k} it.", c.label), Method::Network { model, cfg }));
            }
        }
        // The solver step mode runs no network; a Sim still borrows a model (any will do).
        if let Some(model) = loaded.first() {
            for &k in &a.solver {
                let step = StepMode::Solver { iterations: k.max(1) };
                let cfg = SimConfig::default().with_threads(a.threads.max(1)).with_step(step);
                variants.push((format!("solver step f32 {k} it."), Method::Network { model, cfg }));
            }
            for &ms in &a.solver_budget {
                let micros = (ms * 1e3).round().clamp(1.0, u32::MAX as f64) as u32;
                let step = StepMode::SolverBudget { micros, max_iterations: MAX_REFINE_ITERATIONS };
                let cfg = SimConfig::default().with_threads(a.threads.max(1)).with_step(step);
                variants.push((format!("solver step f32 within {ms} ms"), Method::Network { model, cfg }));
            }
        }
        for &k in &a.iterations {
            let solver = converged_solver().with_max_iterations(k.max(1));
            variants.push((format!("implicit L-BFGS {k} it. (f64)"), Method::Implicit(solver)));
        }
        bar.inc_length(variants.len() as u64 * if a.common_states { 2 } else { 1 });
        for (label, method) in &variants {
            bar.set_message(format!("{name}: {label}"));
            let r = match method {
                Method::Network { model, cfg } => rollout(model, &*anim, frames, *cfg, &opts)?,
                Method::Implicit(solver) => implicit_rollout(&*anim, frames, solver, &opts, &mut |_, _| Ok(()))?,
            };
            push(label.clone(), matches!(method, Method::Implicit(_)), false, r);
        }
        if a.common_states {
            let methods: Vec<Method<'_>> = variants.iter().map(|v| v.1).collect();
            let reference = Reference::Converged(ObjectiveArg::Training.objective());
            let out = common_state_gaps(&*anim, frames, &methods, reference, &opts)?;
            for ((label, method), r) in variants.iter().zip(out) {
                push(label.clone(), matches!(method, Method::Implicit(_)), true, r);
            }
        }
    }
    bar.finish();
    std::fs::create_dir_all(&a.out).map_err(|e| hood::Error::io(&a.out, e))?;
    let trained = models.iter().all(|m| m.trained);
    let md = markdown(&a, &rows, &models, trained);
    let (own, common): (Vec<Row>, Vec<Row>) = rows.into_iter().partition(|r| !r.common);
    let mut files = vec![("report.md".to_string(), md), ("report.svg".to_string(), svg_plot(&own))];
    if !common.is_empty() {
        files.push(("report-common.svg".to_string(), svg_plot(&common)));
    }
    let own_refs: Vec<&Row> = own.iter().collect();
    for name in workload_names(&own_refs) {
        let cell: Vec<Row> = own.iter().filter(|r| r.workload == name).cloned().collect();
        files.push((plot_file(name), svg_plot(&cell)));
    }
    for (file, text) in files {
        let p = a.out.join(file);
        std::fs::write(&p, text).map_err(|e| hood::Error::io(&p, e))?;
        say!("wrote {}", p.display());
    }
    if let Some(readme) = &a.readme {
        let key = a.out.display().to_string();
        let block = format!(
            "Generated by `{}` into [{key}/report.md]({key}/report.md) (the most accurate step mode that keeps the \
             garment on within each budget; gap, median ms/step on the machine that ran it):\n\n{}",
            command_line(&a),
            which_step_table(own.iter())
        );
        let text = std::fs::read_to_string(readme).map_err(|e| hood::Error::io(readme, e))?;
        let text = replace_marked(&text, &key, &block)
            .map_err(|why| hood::Error::io(readme, std::io::Error::new(std::io::ErrorKind::InvalidData, why)))?;
        std::fs::write(readme, text).map_err(|e| hood::Error::io(readme, e))?;
        say!("wrote the which-step table into {}", readme.display());
    }
    Ok(())
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.3}"))
}

/// The `hood report` command that writes this report (paths as given; the assets folder left out,
/// which `HOOD_ASSETS` can name).
fn command_line(a: &ReportArgs) -> String {
    let models = a.model.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(",");
    format!(
        "hood report{} --workload {} --vertices {} --frames {} --gap-every {} --iterations {}{}{}{} --threads {} \
         --objective {}{} -o {}{}",
        if models.is_empty() { String::new() } else { format!(" --model {models}") },
        a.workload.join(","),
        a.vertices,
        a.frames,
        a.gap_every,
        join(&a.iterations),
        if a.refine.is_empty() { String::new() } else { format!(" --refine {}", join(&a.refine)) },
        if a.solver.is_empty() { String::new() } else { format!(" --solver {}", join(&a.solver)) },
        if a.solver_budget.is_empty() { String::new() } else { format!(" --solver-budget {}", join(&a.solver_budget)) },
        a.threads,
        a.objective.name(),
        if a.common_states { "" } else { " --common-states false" },
        a.out.display(),
        a.readme.as_ref().map_or(String::new(), |r| format!(" --readme {}", r.display())),
    )
}

fn join<T: ToString>(ks: &[T]) -> String {
    ks.iter().map(|k| k.to_string()).collect::<Vec<_>>().join(",")
}

#[cfg(test)]
mod tests {
    use super::{command_line, ReportArgs};
    use clap::Parser;

    #[derive(Parser)]
    struct Report {
        #[command(flatten)]
        args: ReportArgs,
    }

    fn parse(line: &str) -> ReportArgs {
        Report::try_parse_from(line.split_whitespace().skip(1)).map(|r| r.args).unwrap()
    }

    /// The header's command writes the same report: every option that changes it survives the
    /// round trip, the model list among them.
    #[test]
    fn the_header_command_reproduces_the_report_arguments() {
        let given =
            "hood report --model models/a.hood,models/specialists/b.hood --workload skirt@1000:walk/stiff-bend,tee \
                     --vertices 900 --frames 60 --gap-every 15 --iterations 10,30 --refine 3 --solver 10,30 \
                     --solver-budget 5,15 --threads 2 --objective training --common-states false -o out/map \
                     --readme README.md";
        let line = command_line(&parse(given));
        assert!(line.starts_with("hood report --model models/a.hood,models/specialists/b.hood --workload "), "{line}");
        let again = parse(&line);
        assert_eq!(command_line(&again), line);
        assert_eq!(again.model.len(), 2);
        assert_eq!((again.vertices, again.frames, again.gap_every, again.threads), (900, 60, 15, 2));
        assert_eq!((again.refine.as_slice(), again.solver.as_slice()), (&[3][..], &[10, 30][..]));
        assert!(!again.common_states && again.readme.is_some());
        // Without models the default set is used, and the line says nothing of them.
        assert!(!command_line(&parse("hood report --workload skirt")).contains("--model"));
    }
}
