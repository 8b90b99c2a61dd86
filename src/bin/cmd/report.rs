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
use hood::model::spec::format_schedule;
use hood::model::{write_model, ModelBytes, ModelSpec, Normalisers, Params};
use hood::rig::procedural::Mannequin;
use hood::scene::{procedural, GarmentKind, MotionKind, Scene};
use hood::sim::{Precision, SimConfig, StepMode, MAX_REFINE_ITERATIONS};
use hood::{Error, Result};
use std::cmp::Ordering;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

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
                let prec = if p == Precision::Bf16 { "bf16" } else { "f32" };
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

/// The `hood report` command that writes this report (paths as given).
fn command_line(a: &ReportArgs) -> String {
    format!(
        "hood report --workload {} --vertices {} --frames {} --gap-every {} --iterations {}{}{}{} --threads {} \
         --objective {}{} -o {}{}",
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

fn markdown(a: &ReportArgs, rows: &[Row], models: &[Candidate], trained: bool) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Accuracy against time\n");
    let _ = writeln!(
        s,
        "Generated by `{}` (EVALUATION.md \"Accuracy against time\"; the figure is [report.svg](report.svg)).\n",
        command_line(a)
    );
    if !trained {
        let _ = writeln!(
            s,
            "**The models here are untrained random stand-ins** (no model file was found): their step times are \
             real, their gap (about 1, coasting) is not an accuracy figure. Rerun once `models/` holds trained models.\n"
        );
    }
    let _ = writeln!(
        s,
        "Gap: relative objective gap (E(x) - E(x*)) / (E(x_hat) - E(x*)) against the converged implicit step from the \
         same state (0: optimal, 1: no better than coasting), every {} frames, {} objective; \"of which \
         stretching\": the stretching term's part of it ((E_stretch(x) - E_stretch(x*)) / (E(x_hat) - E(x*)), the \
         parts of all terms add up to the gap); absolute gap: E(x) - E(x*) in mJ. Both are scored on each rollout's \
         own states: a rollout that keeps calmer states has less descent available, which raises its relative gap \
         at an equal absolute one, and one that blows up has more. ms/step: median wall time of one step on the machine that \
         wrote the report (the implicit solver in f64).\n",
        a.gap_every,
        a.objective.name()
    );
    if let Some(load) = load_average() {
        // Wall times mean little on a busy machine: say how busy it was.
        let _ = writeln!(s, "Load average when the report was written (1, 5, 15 min): {load}.\n");
    }
    if !a.refine.is_empty() {
        let _ = writeln!(
            s,
            "\"+ refine k it.\" rows are model and solver together (the runtime's solver refinement, \
             `SimConfig::refine`): every network step is refined by k L-BFGS iterations of the training-form \
             objective in f32, started from the network's prediction, and the rollout goes on from the refined \
             positions; ms/step includes both.\n"
        );
    }
    if !a.solver_budget.is_empty() {
        let _ = writeln!(
            s,
            "\"solver step f32 within t ms\" rows are the solver step mode with a time budget \
             (`StepMode::SolverBudget`): each step's L-BFGS starts no iteration that it predicts would end \
             past t ms (at least one runs), so their figures depend on the machine that ran the report.\n"
        );
    }
    if !a.solver.is_empty() {
        let _ = writeln!(
            s,
            "\"solver step f32 k it.\" rows are the runtime's solver step mode (`StepMode::Solver`): no network, \
             every step the implicit step of the training-form objective by k L-BFGS iterations in f32 from the \
             coasting guess, at the runtime's threads; the \"implicit L-BFGS\" rows are the f64 reference solver.\n"
        );
    }
    let _ = writeln!(
        s,
        "◆ marks the Pareto front of each workload: the variants that keep the garment on the body ({}) and \
         that no other such variant beats in both ms/step and gap mean. A garment lost is a failure \
         whatever its gap.\n",
        hood::eval::kept_rule()
    );
    if a.objective == ObjectiveArg::Evaluation {
        let _ = writeln!(
            s,
            "Under the evaluation objective the collision term (eps 1 mm, weight 1) is almost nil, so the converged \
             optimum lets the garment sink into the body: see the penetration of the implicit rows. \
             `--objective training` scores with the training collision weight instead.\n"
        );
    }
    for m in models {
        let spec = m.bytes.model().map(|x| x.spec().clone());
        if let Ok(spec) = spec {
            let _ = writeln!(s, "* `{}`: schedule `{}`", m.label, format_schedule(&spec.blocks));
        }
    }
    let _ = writeln!(s);
    which_step(&mut s, rows.iter().filter(|r| !r.common));
    let _ = writeln!(s, "\n## Own rollouts\n");
    table(&mut s, rows.iter().filter(|r| !r.common));
    if rows.iter().any(|r| r.common) {
        let _ = writeln!(
            s,
            "\n## One step from common states\n\n\
             The same variants, each stepped once from the same states: those of a rollout of the converged \
             implicit step under the training objective (collision-respecting states, the same for every variant), \
             on the frames the gap is computed on, scored against the converged step of the {} objective from \
             each of them. Every variant thus has the same descent available, and a model is not scored on the \
             states its own errors led to. The network starts each step from the state alone (past its start-up \
             step, no history); ms/step is the median of these single steps. The plot is \
             [report-common.svg](report-common.svg). Where the garment rests on the body the reference states \
             touch it at the collision margin, and coasting from them runs into the moving body: the descent \
             available there is mostly collision and large, which makes relative gaps small; the absolute gap \
             compares variants on a workload.\n",
            a.objective.name()
        );
        table(&mut s, rows.iter().filter(|r| r.common));
    }
    s
}

/// Which of `rows` (one workload's) are on the Pareto front of time against accuracy: kept the
/// garment on the body, finite, with a gap, and no other such row at most as slow and at most as
/// far from the optimum, and better in one.
fn pareto_front(rows: &[&Row]) -> Vec<bool> {
    let eligible = |r: &Row| r.summary.finite && r.summary.garment_kept() && r.summary.gap_mean.is_some();
    let point = |r: &Row| (r.summary.median_step_ms, r.summary.gap_mean.unwrap_or(f64::INFINITY));
    rows.iter()
        .map(|&r| {
            eligible(r) && {
                let (t, g) = point(r);
                !rows.iter().any(|&o| {
                    let (ot, og) = point(o);
                    eligible(o) && ot <= t && og <= g && (ot < t || og < g)
                })
            }
        })
        .collect()
}

/// Frame budgets of the "which step" table, ms.
const STEP_BUDGETS_MS: [f64; 3] = [5.0, 15.0, 40.0];

/// The workloads of `rows` in order of first appearance.
fn workload_names<'a>(rows: &[&'a Row]) -> Vec<&'a str> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.workload.as_str()) {
            names.push(&r.workload);
        }
    }
    names
}

/// File name of a workload's plot: `report-<workload>.svg`, the name's punctuation as `-`.
fn plot_file(workload: &str) -> String {
    let slug: String = workload.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '-' }).collect();
    format!("report-{slug}.svg")
}

/// "Which step for your garment and budget": per workload and frame budget, the runtime step
/// mode (no f64 reference solver row) with the lowest own-rollout gap mean among those that keep
/// the garment on, stay finite and take at most the budget (median ms/step).
fn which_step<'a>(s: &mut String, rows: impl Iterator<Item = &'a Row>) {
    let _ = writeln!(
        s,
        "## Which step for your garment and budget\n\n\
         Per workload and time budget per step: the most accurate of the runtime's step modes (network, network \
         + refine, solver; not the f64 reference solver) by gap mean on its own rollout, among those that keep the garment on the body, stay finite and take at most the budget (median ms/step, \
         on the machine that ran this report).\n"
    );
    s.push_str(&which_step_table(rows));
}

/// The table of [`which_step`].
fn which_step_table<'a>(rows: impl Iterator<Item = &'a Row>) -> String {
    let rows: Vec<&Row> = rows.collect();
    let mut s = String::new();
    let heads: Vec<String> = STEP_BUDGETS_MS.iter().map(|b| format!("{b} ms")).collect();
    let _ = writeln!(s, "| workload | vertices | {} |", heads.join(" | "));
    let _ = writeln!(s, "|---|---:|{}", "---|".repeat(STEP_BUDGETS_MS.len()));
    for name in workload_names(&rows) {
        let cell: Vec<&Row> = rows.iter().copied().filter(|r| r.workload == name).collect();
        let picks: Vec<String> = STEP_BUDGETS_MS
            .iter()
            .map(|&budget| {
                cell.iter()
                    .filter(|r| {
                        let m = &r.summary;
                        !r.implicit
                            && m.finite
                            && m.garment_kept()
                            && m.gap_mean.is_some()
                            && m.median_step_ms <= budget
                    })
                    .min_by(|x, y| x.summary.gap_mean.partial_cmp(&y.summary.gap_mean).unwrap_or(Ordering::Equal))
                    .map_or("none fits".to_string(), |r| {
                        format!("{} ({}, {:.1} ms)", r.variant, fmt_opt(r.summary.gap_mean), r.summary.median_step_ms)
                    })
            })
            .collect();
        let _ = writeln!(s, "| {name} | {} | {} |", cell[0].vertices, picks.join(" | "));
    }
    s
}

/// Replaces the lines between `<!-- which-step KEY begin -->` and `<!-- which-step KEY end -->`
/// of `text` with `block`.
///
/// # Errors
/// A message when `text` lacks either marker line or has them out of order.
fn replace_marked(text: &str, key: &str, block: &str) -> std::result::Result<String, String> {
    let (begin, end) = (format!("<!-- which-step {key} begin -->"), format!("<!-- which-step {key} end -->"));
    let line_at = |marker: &str| text.find(&format!("{marker}\n")).or_else(|| text.strip_suffix(marker).map(str::len));
    match (line_at(&begin), line_at(&end)) {
        (Some(b), Some(e)) if b < e => {
            let after_begin = b + begin.len() + 1;
            Ok(format!("{}{block}{}", &text[..after_begin], &text[e..]))
        }
        _ => Err(format!("needs the lines `{begin}` and `{end}`, in that order")),
    }
}

/// The Markdown tables of `rows`, one per workload, the Pareto front marked.
fn table<'a>(s: &mut String, rows: impl Iterator<Item = &'a Row>) {
    let rows: Vec<&Row> = rows.collect();
    for name in workload_names(&rows) {
        let cell: Vec<&Row> = rows.iter().copied().filter(|r| r.workload == name).collect();
        let front = pareto_front(&cell);
        let _ = writeln!(s, "\n### {name} ({} vertices)\n", cell[0].vertices);
        if !cell[0].common {
            let _ = writeln!(s, "Plot: [{0}]({0}).\n", plot_file(name));
        }
        let _ = writeln!(
            s,
            "| variant | front | ms/step | gap mean | of which stretching | gap p95 | absolute gap mean (mJ) | on the body | worn off % (max) | penetrating % (mean) | inside % (mean) | max strain | finite |"
        );
        let _ = writeln!(s, "|---|:-:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|");
        for (r, on_front) in cell.iter().zip(front) {
            let m = &r.summary;
            let on_body = crate::verdict::on_body_cell(m, "kept");
            let _ = writeln!(
                s,
                "| {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {:.2} | {} | {:.3} | {} |",
                r.variant,
                if on_front { "◆" } else { "" },
                m.median_step_ms,
                fmt_opt(m.gap_mean),
                fmt_opt(m.gap_by_term.map(|t| t.stretching)),
                fmt_opt(m.gap_p95),
                m.gap_abs_mean.map_or("-".to_string(), |g| format!("{:.2}", 1e3 * g)),
                on_body,
                m.off_body_max.map_or("-".to_string(), |v| format!("{v:.1}")),
                m.mean_penetrating_percent,
                m.inside_mean.map_or("-".to_string(), |v| format!("{v:.2}")),
                m.max_edge_strain,
                if m.finite { "yes" } else { "no" }
            );
        }
    }
}

/// Gap (mean, with a bar to the 95th percentile) against ms/step on a log axis.
fn svg_plot(rows: &[Row]) -> String {
    let (w, h) = (760.0f64, 460.0f64);
    let (l, r, t, b) = (70.0, 230.0, 30.0, 50.0);
    let pts: Vec<(&Row, f64, f64, f64)> = rows
        .iter()
        .filter_map(|row| {
            let s = &row.summary;
            Some((row, s.median_step_ms.max(1e-3), s.gap_mean?, s.gap_p95.unwrap_or(s.gap_mean?)))
        })
        .collect();
    let lx = |v: f64| v.log10();
    let (mut x0, mut x1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(lx(p.1)), b.max(lx(p.1))));
    if pts.is_empty() {
        (x0, x1) = (0.0, 1.0);
    }
    let (x0, x1) = (x0.floor(), x1.ceil().max(x0.floor() + 1.0));
    let y1 = pts.iter().map(|p| p.3).fold(1.1f64, f64::max).min(3.0);
    let px = |v: f64| l + (lx(v) - x0) / (x1 - x0) * (w - l - r);
    let py = |g: f64| t + (1.0 - g.clamp(0.0, y1) / y1) * (h - t - b);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    // Axes and grid.
    for e in (x0 as i32)..=(x1 as i32) {
        let x = px(10f64.powi(e));
        let _ = writeln!(s, r##"<line x1="{x:.1}" y1="{t}" x2="{x:.1}" y2="{}" stroke="#ddd"/>"##, h - b);
        let _ = writeln!(s, r#"<text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"#, h - b + 16.0, 10f64.powi(e));
    }
    let mut g = 0.0;
    while g <= y1 + 1e-9 {
        let y = py(g);
        let _ = writeln!(s, r##"<line x1="{l}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#ddd"/>"##, w - r);
        let _ = writeln!(s, r#"<text x="{}" y="{:.1}" text-anchor="end">{g:.1}</text>"#, l - 6.0, y + 4.0);
        g += 0.2;
    }
    let _ = writeln!(
        s,
        r#"<rect x="{l}" y="{t}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        w - l - r,
        h - t - b
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">ms per step (log)</text>"#,
        l + (w - l - r) / 2.0,
        h - 12.0
    );
    let _ = writeln!(
        s,
        r#"<text x="16" y="{}" text-anchor="middle" transform="rotate(-90 16 {})">relative objective gap (mean, bar to p95)</text>"#,
        t + (h - t - b) / 2.0,
        t + (h - t - b) / 2.0
    );
    // Points: colour per workload; squares for the implicit solver, circles for models.
    const COLOURS: [&str; 5] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
    let mut workloads: Vec<&str> = Vec::new();
    for row in rows {
        if !workloads.contains(&row.workload.as_str()) {
            workloads.push(&row.workload);
        }
    }
    for (i, (row, ms, mean, p95)) in pts.iter().enumerate() {
        let c = COLOURS[workloads.iter().position(|w| *w == row.workload).unwrap_or(0) % COLOURS.len()];
        let (x, y, yp) = (px(*ms), py(*mean), py(*p95));
        let _ = writeln!(s, r#"<line x1="{x:.1}" y1="{y:.1}" x2="{x:.1}" y2="{yp:.1}" stroke="{c}"/>"#);
        if row.implicit {
            let _ = writeln!(s, r#"<rect x="{:.1}" y="{:.1}" width="7" height="7" fill="{c}"/>"#, x - 3.5, y - 3.5);
        } else {
            let _ = writeln!(s, r#"<circle cx="{x:.1}" cy="{y:.1}" r="4" fill="{c}"/>"#);
        }
        let _ = writeln!(s, r#"<text x="{:.1}" y="{:.1}" fill="{c}" font-size="9">{}</text>"#, x + 6.0, y - 4.0, i + 1);
    }
    // Legend: numbered variants.
    for (i, (row, ..)) in pts.iter().enumerate() {
        let c = COLOURS[workloads.iter().position(|w| *w == row.workload).unwrap_or(0) % COLOURS.len()];
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{:.1}" fill="{c}" font-size="9">{}: {} {}</text>"#,
            w - r + 10.0,
            t + 10.0 + 11.0 * i as f64,
            i + 1,
            row.workload,
            row.variant
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The machine's load averages as `/proc/loadavg` gives them (Linux), if readable.
fn load_average() -> Option<String> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let fields: Vec<&str> = text.split_whitespace().take(3).collect();
    (fields.len() == 3).then(|| fields.join(", "))
}

fn join<T: ToString>(ks: &[T]) -> String {
    ks.iter().map(|k| k.to_string()).collect::<Vec<_>>().join(",")
}

#[cfg(test)]
mod tests {
    use super::replace_marked;

    #[test]
    fn the_which_step_block_replaces_only_its_own_markers() {
        let text = "# Title\n<!-- which-step docs/a begin -->\nold a\n<!-- which-step docs/a end -->\n\
                    <!-- which-step docs/b begin -->\nold b\n<!-- which-step docs/b end -->\ntail\n";
        let got = replace_marked(text, "docs/a", "new a\nline 2\n").unwrap();
        assert_eq!(
            got,
            "# Title\n<!-- which-step docs/a begin -->\nnew a\nline 2\n<!-- which-step docs/a end -->\n\
             <!-- which-step docs/b begin -->\nold b\n<!-- which-step docs/b end -->\ntail\n"
        );
        // Idempotent: a second run writes the same file.
        assert_eq!(replace_marked(&got, "docs/a", "new a\nline 2\n").unwrap(), got);
        // A file without the markers, or with them out of order, is refused.
        assert!(replace_marked("# Title\n", "docs/a", "x\n").is_err());
        let swapped = "<!-- which-step k end -->\n<!-- which-step k begin -->\n";
        assert!(replace_marked(swapped, "k", "x\n").unwrap_err().contains("in that order"));
        // The end marker may close the file without a newline.
        let last = "<!-- which-step k begin -->\nold\n<!-- which-step k end -->";
        assert_eq!(
            replace_marked(last, "k", "new\n").unwrap(),
            "<!-- which-step k begin -->\nnew\n<!-- which-step k end -->"
        );
    }
}
