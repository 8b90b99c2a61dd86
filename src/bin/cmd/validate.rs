//! `hood validate`: the model cards' validation in one command. Every model runs the
//! four 300-frame scenes the cards report (the procedural skirt at 500 vertices and dress at
//! 2,000 on the procedural walk, the MakeHuman t-shirt and jeans on the CMU walk), each scored
//! on its own rollout and one step at a time from common states, with the training objective;
//! the figures come out as one Markdown table and every rollout as a PNG strip. `--held-out`
//! runs the held-out split of the motion corpus instead (motions no training run may use), and
//! any `GARMENT:MOTION` pair can be named. Every row says first whether the garment stayed on
//! the body (the off-body metric): a lost garment fails whatever its other figures.

use crate::objective::ObjectiveArg;
use crate::progress::Progress;
use crate::simulate::{material, named_scene, parse_precision, step_mode};
use clap::Args;
use hood::eval::{
    common_state_gaps, rollout, strip_images, Method, Reference, RolloutOptions, SplitSummary, Summary,
    PENETRATING_GOAL_PERCENT, STRAIN_GOAL,
};
use hood::model::{Model, ModelBytes};
use hood::sim::SimConfig;
use hood::{Error, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The validation scenes: name, garment, vertices (procedural garments), motion.
const SCENES: [(&str, &str, usize, &str); 4] = [
    ("skirt", "skirt", 500, "walk"),
    ("dress", "dress", 2000, "walk"),
    ("tee", "tee", 0, "walk"),
    ("jeans", "jeans", 0, "walk"),
];

/// The held-out split's validation scenes (`--held-out`): vigorous corpus motions with seeds no
/// training run may use, the whole back-flip family, on the MakeHuman t-shirt and jeans and the
/// procedural dress and skirt; and the held-out garments (the men's outfit) on the CMU walk and
/// on held-out clips.
const HELD_OUT: [&str; 19] = [
    "tee:jumps-1001",
    "tee:hop-1001",
    "tee:dance-1001",
    "tee:spin-1001",
    "tee:cartwheel-1001",
    "tee:handstand-1001",
    "tee:backflip-1001",
    "tee:mix-1001",
    "jeans:jumps-1002",
    "jeans:kick-1002",
    "jeans:cartwheel-1002",
    "jeans:dance-1002",
    "dress:jumps-1003",
    "dress:dance-1003",
    "dress:spin-1003",
    "skirt:hop-1004",
    "male-tee:walk",
    "male-tee:dance-1005",
    "male-jeans:jumps-1005",
];

/// One scene to validate on.
#[derive(Clone, Debug)]
struct SceneSpec {
    /// The name in the table and the strips' file names.
    label: String,
    garment: String,
    vertices: usize,
    motion: String,
}

impl SceneSpec {
    /// A name of [`SCENES`], or `GARMENT:MOTION` (the procedural garments at the sizes of
    /// [`SCENES`], the cape at 400 vertices).
    fn parse(name: &str) -> Result<SceneSpec> {
        if let Some(&(label, garment, vertices, motion)) = SCENES.iter().find(|c| c.0 == name) {
            return Ok(SceneSpec { label: label.into(), garment: garment.into(), vertices, motion: motion.into() });
        }
        let unknown = || {
            Error::parse("scenes", 0, format!("unknown scene '{name}' (skirt, dress, tee, jeans or GARMENT:MOTION)"))
        };
        let (garment, motion) = name.split_once(':').ok_or_else(unknown)?;
        let vertices = match garment {
            "cape" => 400,
            g if hood::scene::MakeHumanGarment::parse(g).is_some() => 0,
            g => SCENES.iter().find(|c| c.1 == g).ok_or_else(unknown)?.2,
        };
        let label = name.replace(':', "-");
        Ok(SceneSpec { label, garment: garment.into(), vertices, motion: motion.into() })
    }
}

#[derive(Args)]
pub struct ValidateArgs {
    /// The `.hood` files to validate (one table row per file and scene).
    #[arg(required = true)]
    models: Vec<PathBuf>,
    /// Scenes, comma-separated: skirt, dress, tee, jeans (the cards' training-walk scenes), or
    /// GARMENT:MOTION (e.g. tee:jumps-1001; motions as `hood simulate --motion` takes them).
    #[arg(long, default_value = "skirt,dress,tee,jeans", value_delimiter = ',')]
    scenes: Vec<String>,
    /// The held-out split instead of `--scenes`: 16 scenes of vigorous motion (jumps, hops,
    /// dances, spins, inversions, a mix) with seeds no training run may use, and 3 of the
    /// held-out garments (the men's tee and jeans).
    #[arg(long)]
    held_out: bool,
    /// Frames of every rollout (30 per second).
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// The gap (to the converged implicit step) and the inside count every this many frames.
    #[arg(long, default_value_t = 10)]
    gap_every: usize,
    /// Leave out the scoring from common states (saves a converged implicit rollout and one
    /// network step per scored frame).
    #[arg(long)]
    no_common_states: bool,
    /// Rollouts run at once, each on one thread (the figures do not depend on it).
    #[arg(long, default_value_t = 2)]
    jobs: usize,
    /// Network arithmetic: f32 or bf16.
    #[arg(long, default_value = "f32")]
    precision: String,
    /// Collision projection (the runtime effect `SimConfig::projection`, off by default): the
    /// model with the effect rather than the model alone (without a value: 0.002 m).
    #[arg(long, num_args = 0..=1, default_missing_value = "0.002")]
    projection: Option<f32>,
    /// Body tethers (the runtime effect `SimConfig::tether`, off by default): worn vertices
    /// held within this slack (m) of their distance from the body vertex they started on, so
    /// the rows score the model with the effect (without a value: 0.05 m).
    #[arg(long, num_args = 0..=1, default_missing_value = "0.05")]
    tether: Option<f32>,
    /// Solver refinement (the runtime effect `SimConfig::refine`, off by default): every
    /// network step but the start-up refined by this many L-BFGS iterations of the
    /// training-form objective, so the rows score the model with the effect.
    #[arg(long, default_value_t = 0)]
    refine: u32,
    /// The solver step mode instead of the network (`SimConfig::step`): every step the implicit
    /// step by this many L-BFGS iterations from the coasting guess (0: the network steps; the
    /// model file then only names the row).
    #[arg(long, default_value_t = 0)]
    solver: u32,
    /// Every garment remade of this material (same shape and pins): default, soft-stretch,
    /// stiff-stretch, soft-bend, stiff-bend, or density,mu,lambda,bending in SI units (kg/m^2,
    /// Pa, Pa, J). Without it each garment keeps its own.
    #[arg(long)]
    material: Option<String>,
    /// Output folder: `<model>-<scene>.png` strips and `validation.md` (the table).
    #[arg(long, short, default_value = "hood-validate")]
    out: PathBuf,
    /// The assets folder: MakeHuman body, garments, motion clips (default: $HOOD_ASSETS, else
    /// `shared/assets` in the working directory or a parent).
    #[arg(long)]
    assets: Option<PathBuf>,
}

/// The figures of one model on one scene.
struct Row {
    vertices: usize,
    own: Summary,
    /// The largest objective of one frame of the own rollout after the start-up step (J) and
    /// its frame. The gap, computed every few frames, misses a failure that lasts one frame
    /// (a fast limb that meets the cloth from beyond the network's body-edge radius, such as a
    /// foot kicking a long hem); this does not.
    peak: Option<(f64, usize)>,
    common: Option<Summary>,
    seconds: f64,
}

/// `mean (absolute)` of a summary's gap, or `-`.
fn gap_cell(s: &Summary) -> String {
    match (s.gap_mean, s.gap_abs_mean) {
        (Some(g), Some(a)) => format!("{g:.3} ({})", joules(a)),
        _ => "-".into(),
    }
}

/// The lines under the table: per model, the mean own-rollout relative gap (one figure to rank
/// snapshots; only for models scored on every scene), the garments kept on the body, and the
/// split's figures over every scene and over the kept ones against the motion corpus's goals.
fn closing_lines<'a>(summaries: &[Vec<Summary>], scenes: usize, stem: impl Fn(usize) -> &'a str) -> String {
    let splits: Vec<(usize, SplitSummary)> =
        summaries.iter().enumerate().filter(|(_, s)| !s.is_empty()).map(|(m, s)| (m, SplitSummary::of(s))).collect();
    let mut out = String::new();
    let means: Vec<String> = splits
        .iter()
        .filter(|(m, s)| s.rollouts == scenes && summaries[*m].iter().all(|r| r.gap_mean.is_some()))
        .filter_map(|(m, s)| s.gap.all.map(|g| format!("{} {g:.3}", stem(*m))))
        .collect();
    if !means.is_empty() {
        out += &format!("\nMean own-rollout relative gap over the {scenes} scene(s): {}.\n", means.join(", "));
    }
    if splits.is_empty() {
        return out;
    }
    let verdicts: Vec<String> =
        splits.iter().map(|(m, s)| format!("{} {} of {}", stem(*m), s.kept, s.rollouts)).collect();
    out += &format!("\nGarment on the body ({}): {}.\n", hood::eval::kept_rule(), verdicts.join(", "));
    let either = |x: Option<f64>, f: &dyn Fn(f64) -> String| x.map_or_else(|| "-".into(), f);
    let per_model: Vec<String> = splits
        .iter()
        .map(|(m, s)| {
            format!(
                "{}: absolute gap {} (kept {}), penetrating {} (kept {}), largest strain above {STRAIN_GOAL} on {} (kept {}, largest {}), goals {}",
                stem(*m),
                either(s.gap_abs.all, &joules),
                either(s.gap_abs.kept, &joules),
                either(s.penetrating_percent.all, &|p| format!("{p:.2} %")),
                either(s.penetrating_percent.kept, &|p| format!("{p:.2} %")),
                s.strained,
                s.strained_kept,
                either(s.max_kept_strain, &|x| format!("{x:.3}")),
                if s.meets_goals() { "met" } else { "not met" },
            )
        })
        .collect();
    out += &format!(
        "\nMeans over the scenes, and over those that kept the garment on (a lost garment flatters the penetration and the gap); \
         goals of a model alone: every scene kept, largest strain at most {STRAIN_GOAL}, under {PENETRATING_GOAL_PERCENT} % penetrating on average: {}.\n",
        per_model.join("; ")
    );
    out
}

/// An energy in the unit that keeps it readable.
fn joules(e: f64) -> String {
    if e.abs() >= 1.0 {
        format!("{e:.2} J")
    } else if e.abs() >= 0.1 {
        format!("{e:.3} J")
    } else {
        format!("{:.2} mJ", e * 1e3)
    }
}

/// Names for the table and the strips: the files' stems, or `folder-stem` when two stems are
/// equal (snapshots named by their iteration in several run folders).
fn labels(models: &[PathBuf]) -> Vec<String> {
    let name = |p: Option<&std::ffi::OsStr>| p.map(|s| s.to_string_lossy().into_owned());
    let stems: Vec<String> =
        models.iter().enumerate().map(|(m, p)| name(p.file_stem()).unwrap_or_else(|| format!("model{m}"))).collect();
    let unique = stems.iter().all(|s| stems.iter().filter(|t| *t == s).count() == 1);
    if unique {
        return stems;
    }
    models
        .iter()
        .zip(&stems)
        .enumerate()
        .map(|(m, (p, s))| {
            let folder = name(p.parent().and_then(Path::file_name)).unwrap_or_default();
            if folder.is_empty() {
                format!("{m}-{s}")
            } else {
                format!("{folder}-{s}")
            }
        })
        .collect()
}

/// Runs one model on one scene.
fn validate_one(model: &Model<'_>, scene: &SceneSpec, a: &ValidateArgs, strip: &Path) -> Result<Row> {
    let clock = Instant::now();
    let material = material(a.material.as_deref())?;
    let (anim, _) =
        named_scene(&scene.garment, scene.vertices, &scene.motion, a.frames, a.assets.as_deref(), material)?;
    let frames = a.frames.min(anim.n_frames().saturating_sub(1));
    let opts = RolloutOptions::default()
        .with_gap_every(a.gap_every)
        .with_inside_every(a.gap_every)
        .with_keep((0..8).map(|i| i * frames / 7).collect())
        .with_objective(ObjectiveArg::Training.objective());
    let cfg = SimConfig::default()
        .with_threads(1)
        .with_precision(parse_precision(&a.precision)?)
        .with_projection(a.projection)
        .with_tether(a.tether)
        .with_refine((a.refine > 0).then_some(a.refine))
        .with_step(step_mode(a.solver, 0));
    let own = rollout(model, &*anim, frames, cfg, &opts)?;
    hood::io::png::write_strip(strip, &strip_images(&*anim, &own.kept, 240, 420))?;
    let common = if a.no_common_states || a.gap_every == 0 {
        None
    } else {
        let reference = Reference::Converged(ObjectiveArg::Training.objective());
        let mut out = common_state_gaps(&*anim, frames, &[Method::Network { model, cfg }], reference, &opts)?;
        Some(out.swap_remove(0).summary)
    };
    let peak = own
        .frames
        .iter()
        .filter(|r| r.frame > 1)
        .filter_map(|r| Some((r.terms?.total(), r.frame)))
        .fold(None, |m: Option<(f64, usize)>, x| if m.is_some_and(|m| m.0 >= x.0) { m } else { Some(x) });
    Ok(Row {
        vertices: anim.garment().n_vertices(),
        own: own.summary,
        peak,
        common,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// Runs `hood validate`.
pub fn validate(a: ValidateArgs) -> Result<()> {
    let names: Vec<&str> = if a.held_out { HELD_OUT.to_vec() } else { a.scenes.iter().map(String::as_str).collect() };
    let scenes: Vec<SceneSpec> = names.iter().map(|s| SceneSpec::parse(s)).collect::<Result<_>>()?;
    // Refused before any rollout runs.
    let made_of = match (a.material.as_deref(), material(a.material.as_deref())?) {
        (Some(name), Some(m)) if hood::mesh::Material::preset(name).is_some() => {
            format!(", every garment made of {name} ({m})")
        }
        (_, Some(m)) => format!(", every garment made of {m}"),
        _ => String::new(),
    };
    let files: Vec<ModelBytes> = a.models.iter().map(ModelBytes::read).collect::<Result<_>>()?;
    // Validated once, before any rollout; the rollouts share them.
    let models: Vec<Model<'_>> = files.iter().map(ModelBytes::model).collect::<Result<_>>()?;
    std::fs::create_dir_all(&a.out).map_err(|e| hood::Error::io(&a.out, e))?;
    let labels = labels(&a.models);
    let stem = |m: usize| labels[m].as_str();
    let jobs: Vec<(usize, usize)> = (0..models.len()).flat_map(|m| (0..scenes.len()).map(move |s| (m, s))).collect();
    let results: Mutex<Vec<Option<Result<Row>>>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    let next = AtomicUsize::new(0);
    let clock = Instant::now();
    let bar = Progress::new("validate", "rollouts", jobs.len() as u64, Duration::from_secs(10));
    std::thread::scope(|scope| {
        for _ in 0..a.jobs.clamp(1, jobs.len().max(1)) {
            scope.spawn(|| loop {
                let j = next.fetch_add(1, Ordering::Relaxed);
                let Some(&(m, s)) = jobs.get(j) else { break };
                let strip = a.out.join(format!("{}-{}.png", stem(m), scenes[s].label));
                let r = validate_one(&models[m], &scenes[s], &a, &strip);
                let done = results.lock().map(|mut v| {
                    v[j] = Some(r);
                    v.iter().filter(|x| x.is_some()).count()
                });
                bar.println(format!(
                    "[{}/{}] {} on {} ({:.0} s elapsed)",
                    done.unwrap_or(0),
                    jobs.len(),
                    a.models[m].display(),
                    scenes[s].label,
                    clock.elapsed().as_secs_f64()
                ));
                bar.inc(1);
            });
        }
    });
    bar.finish();
    let results = results.into_inner().map_err(|_| Error::parse("validate", 0, "a rollout thread panicked"))?;
    let mut table = format!(
        "Validation: {} frames, gap and inside count every {} frames, training objective, {}{}{}{made_of}, one thread per rollout.\n\n\
         | model | scene | vertices | on the body | worn vertices off: max % (mean) | drift max (cm) | worn centroid shift max (cm) | finite | own rollout: relative gap (absolute) | of which stretching | p95 | from common states | objective mean (J) | largest after frame 1 (J, frame) | penetrating % | inside % | largest strain | of edges ≥ median / 4 | s |\n\
         |---|---|---:|---|---:|---:|---:|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|\n",
        a.frames,
        a.gap_every,
        a.precision,
        a.projection.map_or_else(String::new, |m| format!(", collision projection (margin {m} m)"))
            + &a.tether.map_or_else(String::new, |m| format!(", body tethers (slack {m} m)")),
        if a.refine > 0 { format!(", {} refinement iterations per step", a.refine) } else { String::new() }
            + &if a.solver > 0 { format!(", the solver step mode ({} iterations per step, no network)", a.solver) } else { String::new() }
    );
    let mut failed = None;
    // Each model's own-rollout summaries, for the closing lines.
    let mut summaries: Vec<Vec<Summary>> = vec![Vec::new(); a.models.len()];
    for (&(m, s), r) in jobs.iter().zip(results) {
        let row = match r {
            Some(Ok(row)) => row,
            Some(Err(e)) => {
                eprintln!("{} on {}: {e}", a.models[m].display(), scenes[s].label);
                failed.get_or_insert(e);
                continue;
            }
            None => continue,
        };
        let o = &row.own;
        summaries[m].push(*o);
        let f2 = |x: Option<f64>| x.map_or_else(|| "-".into(), |v| format!("{v:.2}"));
        let f3 = |x: Option<f64>| x.map_or_else(|| "-".into(), |v| format!("{v:.3}"));
        table += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.4} | {} | {:.2} | {} | {:.3} | {:.3} | {:.0} |\n",
            stem(m),
            scenes[s].label,
            row.vertices,
            crate::verdict::on_body_cell(o, "yes"),
            match (o.off_body_max, o.off_body_mean) {
                (Some(x), Some(mean)) => format!("{x:.1} ({mean:.1})"),
                _ => "-".into(),
            },
            o.max_drift.map_or_else(|| "-".into(), |d| format!("{:.1}", 100.0 * d)),
            o.max_shift.map_or_else(|| "-".into(), |d| format!("{:.1}", 100.0 * d)),
            if o.finite { "yes" } else { "**no**" },
            gap_cell(o),
            f3(o.gap_by_term.map(|t| t.stretching)),
            f3(o.gap_p95),
            row.common.as_ref().map_or_else(|| "-".into(), gap_cell),
            o.mean_total,
            row.peak.map_or_else(|| "-".into(), |(e, f)| format!("{e:.2} ({f})")),
            o.mean_penetrating_percent,
            f2(o.inside_mean),
            o.max_edge_strain,
            o.max_long_edge_strain,
            row.seconds
        );
    }
    table += &closing_lines(&summaries, scenes.len(), stem);
    let path = a.out.join("validation.md");
    std::fs::write(&path, &table).map_err(|e| hood::Error::io(&path, e))?;
    say!("{table}\nwrote {} and the strips beside it", path.display());
    failed.map_or(Ok(()), Err)
}
