//! `hood simulate`: run a model on a scene, write an OBJ sequence (or point caches, a USD stage)
//! and a PNG preview strip, print per-step timing and the objective.

use crate::objective::ObjectiveArg;
use clap::Args;
use hood::eval::{common_state_gaps, rollout_observed, strip_images, Animation, FrameRecord, Method, Playback};
use hood::eval::{Reference, RolloutOptions, Summary};
use hood::io::export::{mdd, pc2, usda, write_file, ExportMesh, ObjTemplate};
use hood::io::obj::Obj;
use hood::mesh::Material;
use hood::model::ModelBytes;
use hood::rig::procedural::Mannequin;
use hood::scene::own::{garment_from_mesh, FaceAttachment, GarmentOptions, OwnGarment, Pins, UpAxis};
use hood::scene::{makehuman_wearing, MakeHumanGarment, MakeHumanMotion, Wearing};
use hood::scene::{procedural, GarmentKind, MotionKind, Scene};
use hood::sim::{Precision, SimConfig, StepMode};
use hood::{Error, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The shipped default model (`models/compact.hood`), embedded in the binary.
const EMBEDDED_MODEL: &[u8] = include_bytes!("../../../models/compact.hood");

#[derive(Args)]
pub struct SimulateArgs {
    /// Model file (default: the shipped compact model).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Use an untrained random model of this latent width instead (tries the pipeline; the
    /// motion it produces is garbage).
    #[arg(long, conflicts_with = "model")]
    random_model: Option<usize>,
    /// Garment: skirt, dress or cape (procedural mannequin), or a MakeHuman outfit piece (tee,
    /// jeans, crop-top, leggings, male-tee, male-jeans: the men's outfit is held out from
    /// training), on the CMU walk unless --motion says otherwise (assets from --assets).
    #[arg(long, default_value = "dress")]
    garment: String,
    /// Vertices of a procedural garment (approximate). The default stays within the resolutions the
    /// shipped compact model is validated at (its card: it trains on 400–1,300 vertices and holds
    /// a 4,000-vertex dress and skirt on the walk; it is untested beyond).
    #[arg(long, default_value_t = 2000)]
    vertices: usize,
    /// Procedural motion: walk, run, jump, turn, arm-swings, random-<seed>, or a clip of the motion
    /// corpus as <family>-<seed> (families: jumps, hop, skip, crouch, spin, dance, kick,
    /// cartwheel, handstand, backflip, fall, mix). For the MakeHuman garments, walk is the CMU
    /// walk, and amp-walk, amp-run, amp-backflip are the AMP motion-capture clips.
    #[arg(long, default_value = "walk")]
    motion: String,
    /// Frames to simulate (30 per second).
    #[arg(long, default_value_t = 90)]
    frames: usize,
    /// Output folder (`preview.png`, the strip; `animation.png`, an animated PNG of every
    /// other frame at 15 frames per second; and what --export names).
    #[arg(long, short, default_value = "hood-out")]
    out: PathBuf,
    /// Threads of the step.
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Network arithmetic: f32 or bf16.
    #[arg(long, default_value = "f32")]
    precision: String,
    /// A garment OBJ of your own instead of the built-in garments, modelled around the body's
    /// reference shape: the MakeHuman body's rest pose (then --motion or --bvh moves it), or the
    /// first frame of --body-obj. See --scale, --up, --pins, --material.
    #[arg(long)]
    garment_obj: Option<PathBuf>,
    /// The body as an OBJ sequence: a folder whose `.obj` files (same topology, sorted by name)
    /// are the frames at 30 Hz, in metres, y up.
    #[arg(long, requires = "garment_obj")]
    body_obj: Option<PathBuf>,
    /// A skinned body in glTF 2.0 (`.glb` or `.gltf`: mesh, skin, animations; metres, y up) for
    /// --garment-obj, modelled around the body's bind pose; --animation picks the clip.
    #[arg(long, requires = "garment_obj", conflicts_with_all = ["body_obj", "bvh"])]
    body: Option<PathBuf>,
    /// The --body file's animation to play (default: its first), sampled at 30 Hz.
    #[arg(long, requires = "body")]
    animation: Option<String>,
    /// Units of the body's file per unit of the --garment-obj file: 1 when the garment was
    /// modelled around that file (`assets/body/base.obj` for the MakeHuman body, the first
    /// --body-obj frame, the --body glTF), 0.01 for centimetres around a body in metres.
    #[arg(long, default_value_t = 1.0, requires = "garment_obj")]
    scale: f32,
    /// The --garment-obj file's up axis: y, or z (turned to y up).
    #[arg(long, default_value = "y", requires = "garment_obj")]
    up: String,
    /// Which --garment-obj vertices follow the body: auto (the waistband of a garment that does
    /// not reach the shoulders; none for tops and dresses), none, group:NAME[,NAME] (the vertices
    /// of the faces of those OBJ groups) or a file of 0-based vertex indices (separated by
    /// spaces, commas or lines; `#` starts a comment).
    #[arg(long, default_value = "auto", requires = "garment_obj")]
    pins: String,
    /// The garment's material: default, soft-stretch, stiff-stretch, soft-bend, stiff-bend, or
    /// density,mu,lambda,bending in SI units (kg/m^2, Pa, Pa, J). A --garment-obj is made of the
    /// default unless this says otherwise; a built-in garment keeps its own (the default) unless
    /// this remakes it, same shape and pins.
    #[arg(long)]
    material: Option<String>,
    /// The assets folder: MakeHuman body, garments, motion clips (default: $HOOD_ASSETS, else
    /// `shared/assets` in the working directory or a parent).
    #[arg(long)]
    assets: Option<PathBuf>,
    /// A BVH clip of your own for a MakeHuman garment (`--garment tee`, ...), instead of
    /// --motion: bones matched by the CMU / MotionBuilder names (Hips, Spine, LeftUpLeg, LeftArm,
    /// ...), resampled to 30 Hz, the root scaled by the leg-length ratio, lifted onto the floor.
    #[arg(long)]
    bvh: Option<PathBuf>,
    /// The --bvh clip's rest: first-frame-t-pose (a T-pose calibration frame 0, as the CMU
    /// takes), zero-t-pose (all rotations zero is a T-pose, as Mixamo), zero-arms-down (all
    /// rotations zero has the arms hanging down, as the AMP clips).
    #[arg(long, default_value = "zero-t-pose", requires = "bvh")]
    bvh_rest: String,
    /// Seconds on the MakeHuman body that lead from the rest pose, in which the garments are
    /// modelled, into the motion's first frame, so that the garment starts as modelled and
    /// follows the body into the motion (counted in --frames). Default: 1 with --bvh, else 0.
    #[arg(long)]
    lead_in: Option<f32>,
    /// Also compute the relative objective gap to the converged implicit step every this many
    /// frames (slow; 0: never).
    #[arg(long, default_value_t = 0)]
    gap_every: usize,
    /// With --gap-every: also score the model one step at a time from common states, those of a
    /// converged implicit rollout of the training objective (the same states for any model),
    /// on the same frames.
    #[arg(long, requires = "gap_every")]
    common_states: bool,
    /// Also count the garment vertices inside the body (winding number) every this many frames
    /// (0: never). "penetrating" counts vertices within 1 mm of, or behind, the plane of their
    /// nearest body face; "inside" counts what a viewer would call interpenetration.
    #[arg(long, default_value_t = 0)]
    inside_every: usize,
    /// Collision projection: after every step, push garment vertices that end up within this
    /// margin (m) of the body out to it (a post-process outside HOOD; without a value: 0.002).
    #[arg(long, num_args = 0..=1, default_missing_value = "0.002")]
    projection: Option<f32>,
    /// Body tethers: every worn garment vertex (within 0.1 m of the body at the first frame) may
    /// move at most this much (m) farther from the body vertex it started on, and is pulled back
    /// when it does (game cloth's "max distance", outside HOOD; without a value: 0.05).
    #[arg(long, num_args = 0..=1, default_missing_value = "0.05")]
    tether: Option<f32>,
    /// Solver refinement (the runtime effect `SimConfig::refine`): every network step is
    /// refined by this many L-BFGS iterations of the training-form objective, in f32, started
    /// from the prediction (0: the model alone). Trades time for accuracy.
    #[arg(long, default_value_t = 0)]
    refine: u32,
    /// The solver step mode (`SimConfig::step`, the default): no network, every step the
    /// implicit step by this many L-BFGS iterations from the coasting guess; 0: the network
    /// steps (HOOD). Default: 30 (`DEFAULT_SOLVER_ITERATIONS`), or 0 (the network) when a model
    /// is named (`--model`, `--random-model`) or with `--refine`, which refines the network's
    /// step.
    #[arg(long)]
    solver: Option<u32>,
    /// With `--solver K`: end each step's solve after this many microseconds of wall time too
    /// (`StepMode::SolverBudget`, at most K iterations; 0: no budget).
    #[arg(long, default_value_t = 0)]
    solver_budget_us: u32,
    /// Objective of the printed figures and of the gap.
    #[arg(long, value_enum, default_value_t = ObjectiveArg::Evaluation)]
    objective: ObjectiveArg,
    /// Frames in the preview strip.
    #[arg(long, default_value_t = 6)]
    strip: usize,
    /// What to write, repeatable or comma-separated: obj (the OBJ sequence `garment_NNNN.obj`,
    /// `body_NNNN.obj`), pc2 and mdd (point caches `garment.pc2` / `garment.mdd` with
    /// `garment.obj`, the frame-0 mesh they apply to, and the same for the body), usda
    /// (`scene.usda`: the garment and body meshes with time-sampled points). All in metres, y up,
    /// 30 frames per second; a --garment-obj keeps its texture coordinates, groups and materials.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "obj")]
    export: Vec<Export>,
    /// Do not write the OBJ sequence (as leaving obj out of --export).
    #[arg(long)]
    no_obj: bool,
    /// Write no body files (and no body in `scene.usda`).
    #[arg(long)]
    no_body: bool,
}

/// A point-cache writer: frames into bytes.
type CacheWriter = fn(&mut Vec<u8>, &[Vec<[f32; 3]>]) -> Result<()>;

/// An export of `hood simulate`.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Export {
    Obj,
    Pc2,
    Mdd,
    Usda,
}

fn random_model(h: usize) -> Result<ModelBytes> {
    use hood::model::{write_model, ModelSpec, Normalisers, Params};
    let mut p = Params::init(&ModelSpec::hood(h), 0)?;
    p.normalisers = Normalisers::unit_scale(1);
    Ok(ModelBytes::new(&write_model(&p, true, &[("kind", "random, untrained")])?))
}

pub fn parse_precision(p: &str) -> Result<Precision> {
    match p {
        "f32" => Ok(Precision::F32),
        "bf16" => Ok(Precision::Bf16),
        _ => Err(Error::parse("precision", 0, format!("'{p}' (use f32 or bf16)"))),
    }
}

/// The OBJ files of a folder, sorted by name.
fn obj_sequence(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| hood::Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("obj")))
        .collect();
    files.sort();
    if files.len() < 2 {
        return Err(Error::Empty { what: "body OBJ sequence (needs at least two frames)" });
    }
    Ok(files)
}

/// How --scale, --up, --pins and --material make a garment of `obj`.
fn garment_options(a: &SimulateArgs, obj: &Obj) -> Result<GarmentOptions> {
    let up = UpAxis::parse(&a.up).ok_or_else(|| Error::parse("up", 0, format!("'{}' (use y or z)", a.up)))?;
    let pins = match a.pins.as_str() {
        "auto" => Pins::Auto,
        "none" => Pins::None,
        spec => match spec.strip_prefix("group:") {
            Some(names) => {
                let names: Vec<&str> = names.split(',').collect();
                let mut v: Vec<u32> =
                    obj.triangles_in_groups(&names)?.into_iter().flat_map(|t| obj.triangles[t]).collect();
                v.sort_unstable();
                v.dedup();
                Pins::Vertices(v)
            }
            None => Pins::Vertices(read_vertex_list(Path::new(spec))?),
        },
    };
    Ok(GarmentOptions::default()
        .with_scale(a.scale)
        .with_up(up)
        .with_pins(pins)
        .with_material(Some(Material::parse(a.material.as_deref().unwrap_or("default"))?)))
}

/// 0-based vertex indices from a text file: separated by whitespace or commas, `#` comments.
fn read_vertex_list(path: &Path) -> Result<Vec<u32>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut v = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for token in line.split(|c: char| c.is_whitespace() || c == ',').filter(|t| !t.is_empty()) {
            let k =
                token.parse().map_err(|_| Error::parse("pins", i + 1, format!("'{token}' is not a vertex index")))?;
            v.push(k);
        }
    }
    Ok(v)
}

/// A garment OBJ on a body OBJ sequence: the garment starts at its rest shape pushed out of the
/// body at the first frame; its pins ride on the body face nearest each in that frame.
fn files_scene(g: &Obj, body_dir: &Path, options: &GarmentOptions) -> Result<Playback> {
    let files = obj_sequence(body_dir)?;
    let first = Obj::read(&files[0])?;
    let body = hood::body::BodyMesh::new(first.positions.len(), &first.triangles)?;
    let mut body_frames = vec![first.positions];
    for f in &files[1..] {
        let o = Obj::read(f)?;
        if o.positions.len() != body.n_vertices() {
            return Err(Error::SizeMismatch {
                what: "body OBJ frame vertices",
                expected: body.n_vertices(),
                got: o.positions.len(),
            });
        }
        body_frames.push(o.positions);
    }
    let garment = garment_from_mesh(&g.positions, &g.triangles, options, &body, &body_frames[0])?;
    let mut initial = garment.rest().to_vec();
    hood::solve::push_out_of(&body, &body_frames[0], &mut initial, garment.pinned())?;
    // Every vertex rides on its nearest body face: the pins' targets, and for the off-body
    // metric the garment "skinned" with the body (its drift and shift).
    let every: Vec<u32> = (0..garment.n_vertices() as u32).collect();
    let attached = FaceAttachment::new(&body, &body_frames[0], garment.rest(), &every)?;
    let mut pin_targets = Vec::with_capacity(body_frames.len());
    for frame in &body_frames {
        let mut t = garment.rest().to_vec();
        attached.place(&body, frame, &mut t)?;
        pin_targets.push(t);
    }
    let frames = body_frames.len();
    Ok(Playback { garment, body: Some(body), body_frames, pin_targets, initial, initial_velocity: Vec::new(), frames })
}

/// The scene the arguments name, as a boxed animation, and its description.
fn scene(a: &SimulateArgs) -> Result<(Box<dyn Animation>, String)> {
    if let Some(path) = &a.garment_obj {
        let obj = Obj::read(path)?;
        let options = garment_options(a, &obj)?;
        if let Some(b) = &a.body_obj {
            let p = files_scene(&obj, b, &options)?;
            return Ok((Box::new(p), format!("{} on {}", path.display(), b.display())));
        }
        let name = path.file_stem().map_or_else(|| "garment".into(), |s| s.to_string_lossy().into_owned());
        let own = OwnGarment { name: &name, positions: &obj.positions, triangles: &obj.triangles, options: &options };
        if let Some(file) = &a.body {
            let body = hood::io::gltf::GltfBody::read(file)?;
            let s = hood::scene::gltf_wearing(&body, a.animation.as_deref(), own, a.frames + 1)?;
            let name = s.name.clone();
            return Ok((Box::new(s), name));
        }
        let assets = hood::assets::locate(a.assets.as_deref())?;
        let s = makehuman_wearing(&assets, Wearing::Own(own), makehuman_motion(a, &assets)?, a.frames + 1)?;
        let name = s.name.clone();
        return Ok((Box::new(s), name));
    }
    if a.bvh.is_some() || a.lead_in.is_some_and(|s| s > 0.0) {
        let which = MakeHumanGarment::parse(&a.garment).ok_or_else(|| {
            Error::parse("garment", 0, format!("--bvh and --lead-in need a MakeHuman garment, not '{}'", a.garment))
        })?;
        let assets = hood::assets::locate(a.assets.as_deref())?;
        let s = makehuman_wearing(&assets, Wearing::Piece(which), makehuman_motion(a, &assets)?, a.frames + 1)?;
        let s = made_of(s, material(a.material.as_deref())?)?;
        let name = s.name.clone();
        return Ok((Box::new(s), name));
    }
    named_scene(&a.garment, a.vertices, &a.motion, a.frames, a.assets.as_deref(), material(a.material.as_deref())?)
}

/// A `--material` argument, parsed (None: not given).
pub fn material(arg: Option<&str>) -> Result<Option<Material>> {
    arg.map(Material::parse).transpose()
}

/// The scene with its garment remade of `material` (same rest shape and pins), or as built.
fn made_of(mut s: Scene, material: Option<Material>) -> Result<Scene> {
    if let Some(m) = material {
        s.garment = s.garment_with_material(m)?;
    }
    Ok(s)
}

/// The motion on the MakeHuman body: `--bvh`, else `--motion`, after `--lead-in` (default: a
/// second for a BVH clip, none otherwise).
fn makehuman_motion(a: &SimulateArgs, assets: &Path) -> Result<MakeHumanMotion> {
    let motion = match &a.bvh {
        Some(bvh) => MakeHumanMotion::Bvh(bvh.clone(), bvh_rest(&a.bvh_rest)?),
        None => MakeHumanMotion::named(assets, Some(motion_kind(&a.motion)?).filter(|_| a.motion != "walk")),
    };
    let seconds = a.lead_in.unwrap_or(if a.bvh.is_some() { 1.0 } else { 0.0 });
    if !(0.0..=60.0).contains(&seconds) {
        return Err(Error::parse("lead-in", 0, format!("--lead-in {seconds}: seconds from 0 to 60")));
    }
    let frames = (seconds * hood::rig::motion::MODEL_FPS).round() as usize;
    Ok(if frames == 0 { motion } else { MakeHumanMotion::FromRest(Box::new(motion), frames) })
}

fn bvh_rest(name: &str) -> Result<hood::scene::BvhRest> {
    use hood::scene::BvhRest;
    BvhRest::parse(name).ok_or_else(|| {
        Error::parse("bvh rest", 0, format!("unknown rest '{name}' (one of {})", BvhRest::NAMES.join(", ")))
    })
}

fn motion_kind(name: &str) -> Result<MotionKind> {
    MotionKind::parse(name).ok_or_else(|| Error::parse("motion", 0, format!("unknown motion '{name}'")))
}

/// A built-in scene long enough for `frames` steps, as a boxed animation, and its description:
/// a procedural garment (skirt, dress, cape; about `vertices` vertices) on the procedural
/// mannequin doing `motion`, or the MakeHuman t-shirt or jeans (`tee`, `jeans`) on the CMU walk
/// (`walk`) or `motion`, from `assets` (default: `../shared/assets` beside the source).
pub fn named_scene(
    garment: &str,
    vertices: usize,
    motion: &str,
    frames: usize,
    assets: Option<&Path>,
    material: Option<Material>,
) -> Result<(Box<dyn Animation>, String)> {
    let seconds = (frames + 1) as f32 / 30.0 + 0.1;
    let motion_name = motion;
    let motion = motion_kind(motion)?;
    if let Some(kind) = GarmentKind::parse(garment) {
        let s = made_of(procedural(&Mannequin::new(), kind, vertices, motion, seconds)?, material)?;
        let name = s.name.clone();
        return Ok((Box::new(s), name));
    }
    use hood::scene::{makehuman_on, MakeHumanGarment};
    let Some(which) = MakeHumanGarment::parse(garment) else {
        let names: Vec<&str> = MakeHumanGarment::ALL.iter().map(|g| g.name()).collect();
        return Err(Error::parse(
            "garment",
            0,
            format!("unknown garment '{garment}' (skirt, dress, cape, {})", names.join(", ")),
        ));
    };
    let assets = hood::assets::locate(assets)?;
    let on = (motion_name != "walk").then_some(motion);
    let s = made_of(makehuman_on(&assets, which, on, frames + 1)?, material)?;
    let name = s.name.clone();
    Ok((Box::new(s), name))
}

/// `--solver`'s iterations: as given, else the network's (0) when the command names a model to
/// run (`model_named`) or refines one (`refine` > 0), else the default step's.
pub fn solver_iterations(given: Option<u32>, model_named: bool, refine: u32) -> u32 {
    given.unwrap_or(if model_named || refine > 0 { 0 } else { hood::sim::DEFAULT_SOLVER_ITERATIONS })
}

/// What steps the garment, for the scene line: the network (with its refinement) or the solver.
fn step_description(step: StepMode, refine: u32, model: &str) -> String {
    match step {
        StepMode::Network if refine > 0 => format!("the network ({model}), refined by {refine} iterations"),
        StepMode::Network => format!("the network ({model})"),
        StepMode::Solver { iterations } => {
            format!("the solver, {iterations} iterations (no network; --solver 0 runs {model})")
        }
        StepMode::SolverBudget { micros, max_iterations } => {
            format!("the solver, at most {max_iterations} iterations within {micros} us (no network)")
        }
    }
}

/// The step mode of `--solver K` (and `--solver-budget-us B`): the network for K = 0, else the
/// solver with K iterations (within B µs when B > 0).
pub fn step_mode(solver: u32, budget_us: u32) -> StepMode {
    match (solver, budget_us) {
        (0, _) => StepMode::Network,
        (iterations, 0) => StepMode::Solver { iterations },
        (max_iterations, micros) => StepMode::SolverBudget { micros, max_iterations },
    }
}

fn print_frame(r: &FrameRecord, frames: usize) {
    let t = r.terms.unwrap_or_default();
    // The relative gap, then the absolute gap and the descent available (coasting - optimum).
    let mut optional = r.gap.and_then(|g| Some((g.relative?, g))).map_or(String::new(), |(rel, g)| {
        format!("  gap {rel:.3} ({:.2e} of {:.2e} J)", g.model - g.optimum, g.coasting - g.optimum)
    });
    if let Some(p) = r.inside_percent {
        optional.push_str(&format!("  inside {p:.2}%"));
    }
    if let Some(o) = r.off_body {
        optional.push_str(&format!("  off body {:.1}%", o.off_percent));
        if let Some(d) = o.max_drift {
            optional.push_str(&format!("  drift {:.1} cm", 100.0 * d));
        }
        if let Some(d) = o.shift {
            optional.push_str(&format!("  shift {:.1} cm", 100.0 * d));
        }
    }
    say!(
        "frame {:>4}/{frames}  {:>7.2} ms  objective {:>10.4} J (stretch {:.4}, bend {:.2e}, inertia {:.4}, gravity {:.4}, collision {:.2e}, friction {:.2e})  penetrating {:>5.2}%  strain {:.3}  speed {:.2} m/s{optional}{}",
        r.frame,
        r.step_ms,
        t.total(),
        t.stretching,
        t.bending,
        t.inertia,
        t.gravity,
        t.collision,
        t.friction,
        r.penetrating_percent,
        r.max_edge_strain,
        r.max_speed,
        match r.kind {
            hood::eval::StepKind::Stepped => "",
            hood::eval::StepKind::StartUp => "  (with start-up step)",
            hood::eval::StepKind::Teleported => "  (teleported)",
            hood::eval::StepKind::Slept => "  (asleep)",
        }
    );
}

/// The mean relative gap split by term, if there is one.
fn print_gap_by_term(label: &str, s: &Summary) {
    if let Some(t) = s.gap_by_term {
        say!(
            "{label}: stretching {:+.3}, bending {:+.3}, inertia {:+.3}, gravity {:+.3}, collision {:+.3}, friction {:+.3}",
            t.stretching,
            t.bending,
            t.inertia,
            t.gravity,
            t.collision,
            t.friction
        );
    }
}

/// Frames per picture of `animation.png` (the model's 30 Hz shown at 15 frames a second).
const ANIMATION_EVERY: usize = 2;

/// Runs `hood simulate`.
pub fn simulate(a: SimulateArgs) -> Result<()> {
    let bytes = match (&a.model, a.random_model) {
        (Some(p), _) => ModelBytes::read(p)?,
        (None, Some(h)) => random_model(h)?,
        (None, None) => ModelBytes::new(EMBEDDED_MODEL),
    };
    let model = bytes.model()?;
    let precision = parse_precision(&a.precision)?;
    let clock = Instant::now();
    let (anim, name) = scene(&a)?;
    let frames = a.frames.min(anim.n_frames().saturating_sub(1));
    let step = step_mode(
        solver_iterations(a.solver, a.model.is_some() || a.random_model.is_some(), a.refine),
        a.solver_budget_us,
    );
    let model_name = match (&a.model, a.random_model) {
        (Some(p), _) => p.display().to_string(),
        (None, Some(h)) => format!("a random model, h = {h}"),
        (None, None) => "the shipped compact model".to_string(),
    };
    eprintln!(
        "scene: {name}, garment {} vertices, body {} vertices, {frames} frames (built in {:.1} s); steps: {}",
        anim.garment().n_vertices(),
        anim.body_mesh().map_or(0, |b| b.n_vertices()),
        clock.elapsed().as_secs_f64(),
        step_description(step, a.refine, &model_name)
    );
    std::fs::create_dir_all(&a.out).map_err(|e| hood::Error::io(&a.out, e))?;
    let k = a.strip.max(1);
    let keep: Vec<usize> = if k == 1 { vec![frames] } else { (0..k).map(|i| i * frames / (k - 1)).collect() };
    let opts = RolloutOptions::default()
        .with_gap_every(a.gap_every)
        .with_inside_every(a.inside_every)
        .with_keep(keep)
        .with_objective(a.objective.objective());
    let cfg = SimConfig::default()
        .with_threads(a.threads.max(1))
        .with_precision(precision)
        .with_projection(a.projection)
        .with_tether(a.tether)
        .with_refine((a.refine > 0).then_some(a.refine))
        .with_step(step);
    let faces = anim.garment().faces().to_vec();
    let body_faces = if a.no_body { None } else { anim.body_mesh().map(|b| b.faces().to_vec()) };
    // A garment from a file is written as that file with new positions.
    let template = a.garment_obj.as_ref().map(ObjTemplate::read).transpose()?;
    let write_garment = |path: &Path, pos: &[[f32; 3]]| -> Result<()> {
        match &template {
            Some(t) => write_file(path, |w| t.write(w, pos)),
            None => hood::io::obj::write(path, pos, &faces, None),
        }
    };
    let sequence = a.export.contains(&Export::Obj) && !a.no_obj;
    let caches = a.export.iter().any(|e| *e != Export::Obj);
    let write_sequence = |f: usize, pos: &[[f32; 3]]| -> Result<()> {
        write_garment(&a.out.join(format!("garment_{f:04}.obj")), pos)?;
        if let Some(bf) = &body_faces {
            hood::io::obj::write(a.out.join(format!("body_{f:04}.obj")), anim.body_frame(f), bf, None)?;
        }
        Ok(())
    };
    let initial = anim.initial_garment()?;
    if sequence {
        write_sequence(0, &initial)?;
    }
    // Every other frame of the animated preview (15 frames per second).
    let mut animated = vec![(0, initial.clone())];
    let mut garment_frames = if caches { vec![initial] } else { Vec::new() };
    let bar = crate::progress::Progress::new("simulate", "frames", frames as u64, std::time::Duration::from_secs(10));
    let r = rollout_observed(&model, &*anim, frames, cfg, &opts, &mut |rec, pos| {
        bar.suspend(|| print_frame(rec, frames));
        bar.set_position(rec.frame as u64);
        if sequence {
            write_sequence(rec.frame, pos)?;
        }
        if caches {
            garment_frames.push(pos.to_vec());
        }
        if rec.frame % ANIMATION_EVERY == 0 {
            animated.push((rec.frame, pos.to_vec()));
        }
        Ok(())
    });
    bar.finish();
    let r = r?;
    if caches {
        let body = body_faces.as_ref().map(|bf| {
            let frames: Vec<Vec<[f32; 3]>> = (0..garment_frames.len()).map(|f| anim.body_frame(f).to_vec()).collect();
            (bf, frames)
        });
        write_garment(&a.out.join("garment.obj"), &garment_frames[0])?;
        if let Some((bf, frames)) = &body {
            hood::io::obj::write(a.out.join("body.obj"), &frames[0], bf, None)?;
        }
        for e in &a.export {
            let (ext, write): (&str, CacheWriter) = match e {
                Export::Pc2 => ("pc2", |w, f| pc2::write(w, f)),
                Export::Mdd => ("mdd", |w, f| mdd::write(w, f)),
                _ => continue,
            };
            write_file(&a.out.join(format!("garment.{ext}")), |w| write(w, &garment_frames))?;
            if let Some((_, frames)) = &body {
                write_file(&a.out.join(format!("body.{ext}")), |w| write(w, frames))?;
            }
        }
        if a.export.contains(&Export::Usda) {
            let garment_mesh =
                template.as_ref().map_or_else(|| ExportMesh::from_triangles(&faces), |t| ExportMesh::from_obj(t.obj()));
            let body_mesh = body.as_ref().map(|(bf, frames)| (ExportMesh::from_triangles(bf), frames));
            let mut meshes = vec![usda::UsdMesh { name: "garment", mesh: &garment_mesh, frames: &garment_frames }];
            if let Some((mesh, frames)) = &body_mesh {
                meshes.push(usda::UsdMesh { name: "body", mesh, frames });
            }
            write_file(&a.out.join("scene.usda"), |w| usda::write(w, &meshes))?;
        }
    }
    let strip = a.out.join("preview.png");
    hood::io::png::write_strip(&strip, &strip_images(&*anim, &r.kept, 240, 420))?;
    let animation = a.out.join("animation.png");
    let fps = (30 / ANIMATION_EVERY) as u16;
    hood::io::png::write_animation(&animation, &strip_images(&*anim, &animated, 180, 315), fps)?;
    let s = &r.summary;
    if let Some((f, e)) = &r.failure {
        eprintln!("stopped at frame {f}: {e}");
    }
    say!(
        "{} frames, {}: step median {:.2} ms (mean {:.2}); objective mean {:.4} J; penetrating mean {:.2}% (max {:.2}%); largest strain {:.3} ({:.3} over edges at least a quarter of the median long), speed {:.2} m/s{}",
        s.frames,
        if s.finite { "finite throughout" } else { "NOT finite" },
        s.median_step_ms,
        s.mean_step_ms,
        s.mean_total,
        s.mean_penetrating_percent,
        s.max_penetrating_percent,
        s.max_edge_strain,
        s.max_long_edge_strain,
        s.max_speed,
        match (s.gap_mean, s.gap_p95) {
            (Some(m), Some(p)) => format!(
                "; relative gap mean {m:.3}, p95 {p:.3} ({} frames; absolute {:.2e} J)",
                s.gap_frames,
                s.gap_abs_mean.unwrap_or(f64::NAN)
            ),
            _ => String::new(),
        } + &match (s.inside_mean, s.inside_max) {
            (Some(m), Some(x)) => format!("; inside the body mean {m:.2}% (max {x:.2}%, {} frames)", s.inside_frames),
            _ => String::new(),
        }
    );
    if let Some(text) = s.off_body_text() {
        say!("{text}");
    }
    if let StepMode::SolverBudget { micros, .. } = cfg.step {
        say!(
            "time budget {:.1} ms: kept on {} of {} steps, exceeded on {}",
            micros as f64 / 1e3,
            s.frames - s.over_budget_frames,
            s.frames,
            s.over_budget_frames
        );
    }
    print_gap_by_term("relative gap by term", s);
    if a.common_states && a.gap_every > 0 {
        let reference = Reference::Converged(ObjectiveArg::Training.objective());
        let out = common_state_gaps(&*anim, frames, &[Method::Network { model: &model, cfg }], reference, &opts)?;
        let c = &out[0].summary;
        if let (Some(m), Some(p)) = (c.gap_mean, c.gap_p95) {
            say!(
                "from common states (a converged implicit rollout, training objective): relative gap mean {m:.3}, p95 {p:.3} ({} frames; absolute {:.2e} J); step median {:.2} ms",
                c.gap_frames,
                c.gap_abs_mean.unwrap_or(f64::NAN),
                c.median_step_ms
            );
        }
        if let Some((f, e)) = &out[0].failure {
            eprintln!("from common states: refused at frame {f}: {e}");
        }
        print_gap_by_term("from common states, by term", c);
    }
    let mut wrote: Vec<String> = a
        .export
        .iter()
        .filter(|e| **e != Export::Obj || sequence)
        .map(|e| match e {
            Export::Obj => "the OBJ sequence".to_string(),
            Export::Pc2 => "garment.pc2".to_string(),
            Export::Mdd => "garment.mdd".to_string(),
            Export::Usda => "scene.usda".to_string(),
        })
        .collect();
    wrote.dedup();
    let also =
        if wrote.is_empty() { String::new() } else { format!(" and {} in {}", wrote.join(", "), a.out.display()) };
    say!("wrote {}, {}{also}", strip.display(), animation.display());
    Ok(())
}
