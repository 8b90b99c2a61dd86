//! The simulation: one HOOD step per call, in buffers sized at creation.
//!
//! [`Sim::new`] derives the graph, sizes every buffer and picks the kernel path; [`Sim::step`]
//! takes the body's vertices at the next frame and returns the garment's, running the data path
//! of ARCHITECTURE.md (pinned targets, body edges, features, normalise, encode, blocks, decode,
//! integrate) without allocating. Non-finite input is refused and leaves the state unchanged.
//!
//! Where a step goes: `Sim::step_frame` (here) reads the body's motion (`motion.rs`: the speed
//! limit's carry, a teleport, sleep) and runs one or two passes (the start-up pass first);
//! `Sim::advance` (`stages.rs`) runs a pass as a pipeline of stages, the network's prediction
//! among them in `predict.rs`. The configuration is in `config.rs`.
//!
//! Units: metres; one step is one frame at the model's 30 Hz (velocities are m/frame).

mod body_query;
mod clock;
mod config;
pub mod driver;
mod effects;
pub mod graph;
pub(crate) mod inputs;
mod motion;
pub(crate) mod network;
mod outfit;
mod predict;
mod projection;
mod refine;
mod saved;
mod stages;
mod tether;

use crate::body::rigid::RigidMotion;
use crate::body::{BodyMesh, BodySurvey};
use crate::error::{Error, Result};
#[cfg(feature = "std")]
pub use crate::exec::ThreadPool;
pub use crate::exec::{Executor, Serial};
use crate::features::{DT, DT_STARTUP};
use crate::kernels::{Kernels, Tier};
use crate::math::finite3;
use crate::mesh::{vertex_normals, Garment};
use crate::model::file::Model;
use alloc::boxed::Box;
use alloc::vec;
use alloc::vec::Vec;
use body_query::{BodyNeeds, BodyQuery};
#[cfg(feature = "std")]
pub use clock::StdClock;
pub use clock::{BudgetUse, Clock};
pub use config::{
    Precision, SimConfig, Sleeping, StepMode, DEFAULT_SOLVER_ITERATIONS, DEFAULT_SPEED_LIMIT, DEFAULT_TELEPORT,
    MAX_THREADS,
};
pub use driver::{FixedStep, Interpolator, MAX_ENGINE_DT, MODEL_DT};
pub use effects::StepEffects;
pub use graph::Graph;
pub use inputs::BODY_EDGE_RADIUS;
use motion::FrameMotion;
use network::{Net, WidenedBf16, Workspace};
// Public for the parity tests (`tests/runtime_parity.rs`): a debugging hook, not stable API.
#[doc(hidden)]
pub use network::{Probe, Stage};
pub use outfit::Outfit;
use predict::NetBody;
use projection::Projection;
pub use projection::{DEFAULT_PROJECTION_MARGIN, PROJECTION_REACH};
use refine::Refiner;
pub use refine::{DEFAULT_REFINE_ITERATIONS, MAX_REFINE_ITERATIONS, REFINE_COLLISION_WEIGHT};
pub use saved::{STATE_MAGIC, STATE_VERSION};
use tether::Tethers;
pub use tether::{DEFAULT_TETHER_SLACK, MAX_TETHER_SLACK, TETHER_FOLLOW_STRETCH, TETHER_REACH};

/// For the sim's tests: a random HOOD model (latent `8`) whose decoder outputs nothing, so every
/// network step is the coasting guess (plus the unit-scale normalisers' mean output).
#[cfg(test)]
pub(crate) fn coasting_model_bytes(seed: u64) -> crate::model::ModelBytes {
    use crate::model::{write_model, ModelBytes, ModelSpec, Normalisers, Params};
    let mut p = Params::init(&ModelSpec::hood(8), seed).unwrap();
    p.normalisers = Normalisers::unit_scale(3);
    let last = p.mlps.decoder.layers.last_mut().unwrap();
    last.weight.iter_mut().chain(last.bias.iter_mut()).for_each(|w| *w = 0.0);
    ModelBytes::new(&write_model(&p, false, &[]).unwrap())
}

/// The garment and body state between steps.
#[derive(Clone, Debug, PartialEq)]
pub struct SimState {
    /// Garment positions at the current frame, m.
    pub pos: Vec<[f32; 3]>,
    /// Garment velocities, m/frame (while the speed limit carries the garment, relative to the
    /// frame of reference that follows the body's excess motion).
    pub velocity: Vec<[f32; 3]>,
    /// Body positions at the previous frame, m (empty without a body).
    pub body_prev: Vec<[f32; 3]>,
    /// Body positions at the current frame, m (empty without a body).
    pub body_pos: Vec<[f32; 3]>,
    /// Whether the start-up step has run.
    pub started: bool,
}

struct BodyState {
    mesh: BodyMesh,
    /// The network's body edges and the body's frames as it sees them (`predict.rs`).
    net: NetBody,
    /// Collision projection's buffers (only with [`SimConfig::projection`]).
    projection: Option<Projection>,
    /// Body tethers (only with [`SimConfig::tether`]).
    tethers: Option<Tethers>,
    /// Orientation and resolution of the body at the first frame.
    survey: BodySurvey,
}

/// One garment on one body, stepped by one model.
///
/// # Examples
///
/// A 5 x 5 patch of cloth with two corners pinned and no body, stepped by HOOD's network; the
/// README has one over a body.
///
/// ```
/// use hood::mesh::{Garment, GarmentDesc};
/// use hood::model::ModelBytes;
/// use hood::sim::{Sim, SimConfig};
///
/// let rest: Vec<[f32; 3]> = (0..25).map(|i| [(i % 5) as f32 * 0.1, 1.0, (i / 5) as f32 * 0.1]).collect();
/// let faces: Vec<[u32; 3]> =
///     (0..16u32).map(|q| q + q / 4).flat_map(|v| [[v, v + 5, v + 1], [v + 1, v + 5, v + 6]]).collect();
/// let pinned: Vec<bool> = (0..25).map(|i| i == 0 || i == 4).collect();
/// let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned))?;
///
/// let bytes = ModelBytes::read(concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood"))?;
/// let model = bytes.model()?;
/// let mut sim = Sim::new(&model, &garment, None, SimConfig::network())?;
/// for _ in 0..10 {
///     sim.step(&[])?; // without a body the frame is empty
/// }
/// let now = sim.positions();
/// assert_eq!(now[0], rest[0]); // pinned: held at its target
/// assert!(now[24][1] < rest[24][1]); // the free corner sags
/// # Ok::<(), hood::Error>(())
/// ```
pub struct Sim<'m> {
    net: Net<'m>,
    cfg: SimConfig,
    garment: Garment,
    graph: Graph,
    material_in: Vec<[f32; 3]>,
    pinned: Vec<bool>,
    pin_targets: Vec<[f32; 3]>,
    body: Option<BodyState>,
    /// The body's grids and normals of the frames a step reads (`None` without a body, or
    /// while an [`Outfit`] that shares its own holds the sim).
    query: Option<BodyQuery>,
    /// What a step reads of the body (for a query shared with other sims).
    needs: BodyNeeds,
    /// Solver refinement's buffers (only with [`SimConfig::refine`]).
    refiner: Option<Refiner>,
    state: SimState,
    garment_normals: Vec<[f32; 3]>,
    new_pos: Vec<[f32; 3]>,
    new_vel: Vec<[f32; 3]>,
    output_normals: Vec<[f32; 3]>,
    /// The state before the first step's start-up pass, restored when the regular pass of that
    /// step is refused (sized at creation).
    before_startup: SimState,
    rest_frames: u32,
    ws: Workspace,
    /// The bf16 weights widened to f32 (bf16 on a kernel path without bf16 products).
    widened: Option<WidenedBf16>,
    exec: Box<dyn Executor + 'm>,
    /// The clock of [`StepMode::SolverBudget`].
    clock: Option<Box<dyn Clock + 'm>>,
    last_body: (usize, usize),
    /// The speed limit's carry of the last step, m (zero: none).
    last_carry: [f32; 3],
    /// What the last successful step did ([`Sim::last_effects`]).
    last_effects: StepEffects,
}

/// What [`Sim`]'s accessors report about the last step that ran ([`Sim::last_step_flops`],
/// [`Sim::last_body_counts`], [`Sim::last_refinement`], [`Sim::last_budget`],
/// [`Sim::last_projected`], [`Sim::last_tethered`], [`Sim::tethered_vertices`],
/// [`Sim::last_effects`]): a refused step (of the sim or of an [`Outfit`] it is in) puts them
/// back, so that they keep describing the last step that ran, as the state does.
#[derive(Clone, Copy)]
struct LastStepFigures {
    flops: u64,
    body: (usize, usize),
    projected: usize,
    tethered: usize,
    /// Whether the tethers were tied (a refused first step ties them).
    tied: bool,
    refined: Option<refine::Solved>,
    /// [`Sim::last_effects`] (a sim's own refused step leaves it; an [`Outfit`] puts it back).
    effects: StepEffects,
}

/// The body of a scene: its mesh (optionally with omitted vertices) and its positions at the
/// first frame.
#[derive(Clone, Copy, Debug)]
pub struct BodyDesc<'a> {
    /// Topology (and omitted flags).
    pub mesh: &'a BodyMesh,
    /// Positions at the first frame, m.
    pub positions: &'a [[f32; 3]],
}

fn check_finite(what: &'static str, p: &[[f32; 3]]) -> Result<()> {
    match p.iter().position(|v| !finite3(*v)) {
        Some(i) => Err(Error::NonFinite { what, index: i }),
        None => Ok(()),
    }
}

impl<'m> Sim<'m> {
    /// A simulation of `garment` (starting at its rest positions) on `body` (or none), with the
    /// garment's graph built by [`Graph::build`] (the default hierarchy, the model's levels).
    ///
    /// # Errors
    /// [`Error::UnsupportedEffect`] for an effect the model was not trained with or a bf16 run
    /// of an f32-only file; [`Error::IncompatibleModel`]; [`Error::OutOfRange`] for a setting
    /// outside its range (a speed limit or teleport threshold that is not finite and positive,
    /// too many threads); errors of the hierarchy.
    pub fn new(model: &'m Model<'m>, garment: &Garment, body: Option<BodyDesc<'_>>, cfg: SimConfig) -> Result<Sim<'m>> {
        let graph = Graph::build(garment, model.spec().levels)?;
        Sim::with_graph(model, garment, graph, body, cfg)
    }

    /// As [`Sim::new`] with a prepared graph (e.g. coarse edges from elsewhere).
    ///
    /// # Errors
    /// See [`Sim::new`].
    pub fn with_graph(
        model: &'m Model<'m>,
        garment: &Garment,
        graph: Graph,
        body: Option<BodyDesc<'_>>,
        cfg: SimConfig,
    ) -> Result<Sim<'m>> {
        let spec = model.spec();
        if graph.n_vertices() != garment.n_vertices() {
            return Err(Error::SizeMismatch {
                what: "graph vertices",
                expected: garment.n_vertices(),
                got: graph.n_vertices(),
            });
        }
        if cfg.precision == Precision::Bf16 && !model.has_bf16() {
            return Err(Error::UnsupportedEffect { effect: "bf16 precision (the model file has no bf16 weights)" });
        }
        let use_body = cfg.body_collision && body.is_some();
        if use_body && !spec.effects.body {
            return Err(Error::UnsupportedEffect { effect: "body collision (the model was trained without a body)" });
        }
        let any_pinned = garment.pinned().iter().any(|&p| p);
        if cfg.pinning && any_pinned && !spec.effects.pinning {
            return Err(Error::UnsupportedEffect { effect: "pinning (the model was trained without pinned vertices)" });
        }
        if cfg.threads > MAX_THREADS {
            return Err(Error::OutOfRange { what: "threads (at most MAX_THREADS)", index: 0 });
        }
        for (what, distance) in [
            ("speed limit (finite, above 0 m/frame)", cfg.speed_limit),
            ("teleport threshold (finite, above 0 m)", cfg.teleport),
        ] {
            if distance.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
                return Err(Error::OutOfRange { what, index: 0 });
            }
        }
        if cfg.projection.is_some() && !use_body {
            return Err(Error::UnsupportedEffect { effect: "collision projection (needs a body and body collision)" });
        }
        if cfg.tether.is_some() && !use_body {
            return Err(Error::UnsupportedEffect { effect: "body tethers (need a body and body collision)" });
        }
        let m0 = garment.materials()[0];
        if !spec.effects.local_materials && garment.materials().iter().any(|m| *m != m0) {
            return Err(Error::UnsupportedEffect { effect: "per-vertex materials" });
        }
        let bf16 = cfg.precision == Precision::Bf16;
        let uses_network = cfg.step == StepMode::Network;
        let kernels = match cfg.tier {
            // The precision on the faster of its two paths here (measured once per process, and
            // only for a step that runs the network).
            None if !uses_network => Kernels::best(),
            None if bf16 => Kernels::best_bf16(),
            None => Kernels::best_f32(),
            Some(t) => Kernels::with_tier(t.min(Kernels::best().tier())).unwrap_or(Kernels::scalar()),
        };
        let n = garment.n_vertices();
        let body_state = match body {
            Some(b) if use_body => {
                let survey = b.mesh.survey(b.positions)?;
                if survey.inside_out() {
                    return Err(Error::InsideOut { what: "body" });
                }
                Some(BodyState {
                    mesh: b.mesh.clone(),
                    net: NetBody::new(n, b.mesh.n_vertices(), cfg.speed_limit.is_some()),
                    projection: match cfg.projection {
                        Some(margin) => Some(Projection::new(n, margin)?),
                        None => None,
                    },
                    tethers: match cfg.tether {
                        Some(slack) => Some(Tethers::new(garment, b.mesh.n_vertices(), slack)?),
                        None => None,
                    },
                    survey,
                })
            }
            _ => None,
        };
        let (iterations, budget_ns) = match (cfg.step, cfg.refine) {
            (StepMode::Solver { .. } | StepMode::SolverBudget { .. }, Some(_)) => {
                return Err(Error::UnsupportedEffect {
                    effect: "refine with the solver step mode (set the solver's iterations instead)",
                })
            }
            (StepMode::Solver { iterations }, None) => (Some(iterations), None),
            (StepMode::SolverBudget { micros: 0, .. }, None) => {
                return Err(Error::OutOfRange { what: "solver time budget (at least 1 us)", index: 0 })
            }
            (StepMode::SolverBudget { micros, max_iterations }, None) => {
                (Some(max_iterations), Some(u64::from(micros) * 1000))
            }
            (StepMode::Network, refine) => (refine, None),
        };
        let refiner = match iterations {
            Some(iterations) => {
                Some(Refiner::new(garment, body_state.as_ref().map(|b| &b.mesh), iterations, budget_ns)?)
            }
            None => None,
        };
        let needs = match &body_state {
            Some(b) => BodyNeeds {
                vertices: cfg.step == StepMode::Network,
                faces: refiner.is_some() || b.projection.is_some(),
            },
            None => BodyNeeds::default(),
        };
        let query = match &body_state {
            Some(b) if !needs.none() => Some(BodyQuery::new(&b.mesh, needs)?),
            _ => None,
        };
        let max_active = body_state.as_ref().map_or(0, |b| b.net.max_active());
        // Without bf16 products the kernels would widen bf16 weights on every call: widen them
        // once instead, and run them on the f32 path.
        let widened = if bf16 && uses_network && !kernels.tier().has_bf16_products() {
            Some(WidenedBf16::new(model)?)
        } else {
            None
        };
        let net = Net { model, kernels, bf16, widened: None };
        let ws = Workspace::new(model, &graph, max_active)?;
        let (body_prev, body_pos) = match (&body_state, body) {
            (Some(_), Some(b)) => (b.positions.to_vec(), b.positions.to_vec()),
            _ => (Vec::new(), Vec::new()),
        };
        let pinned = if cfg.pinning { garment.pinned().to_vec() } else { vec![false; n] };
        let state = SimState {
            pos: garment.rest().to_vec(),
            velocity: vec![[0.0; 3]; n],
            body_prev,
            body_pos,
            started: !cfg.startup,
        };
        let mut output_normals = Vec::new();
        if cfg.normals {
            output_normals = vec![[0.0; 3]; n];
            vertex_normals(garment.faces(), &state.pos, &mut output_normals);
        }
        Ok(Sim {
            net,
            cfg,
            material_in: garment.materials().iter().map(|m| m.network_inputs()).collect(),
            pinned,
            pin_targets: garment.rest().to_vec(),
            garment: garment.clone(),
            graph,
            body: body_state,
            query,
            needs,
            refiner,
            before_startup: state.clone(),
            state,
            garment_normals: vec![[0.0; 3]; n],
            new_pos: vec![[0.0; 3]; n],
            new_vel: vec![[0.0; 3]; n],
            output_normals,
            rest_frames: 0,
            ws,
            widened,
            exec: default_executor(cfg.threads),
            clock: clock::default_clock(),
            last_body: (0, 0),
            last_carry: [0.0; 3],
            last_effects: StepEffects::default(),
        })
        .map(|mut sim: Sim<'m>| {
            sim.ws.set_tasks(sim.exec.parallelism(), &sim.graph);
            sim
        })
    }

    /// Plugs in the executor that runs the step's parallel parts (an engine's job system).
    /// Sizes per-task scratch for its [`Executor::parallelism`] (this allocates; the steps
    /// that follow do not).
    pub fn set_executor(&mut self, exec: Box<dyn Executor + 'm>) {
        self.ws.set_tasks(exec.parallelism(), &self.graph);
        self.exec = exec;
    }

    /// Plugs in the clock that [`StepMode::SolverBudget`] reads (an engine's frame timer; with
    /// `std` a sim starts with `StdClock`).
    pub fn set_clock(&mut self, clock: Box<dyn Clock + 'm>) {
        self.clock = Some(clock);
    }

    /// Useful floating-point operations of the network's matrix products in the last network
    /// pass (counted from the shapes, with the split first layer; a multiply-add is 2).
    pub fn last_step_flops(&self) -> u64 {
        self.ws.flops
    }

    /// Body edges and active body nodes of the last network pass.
    pub fn last_body_counts(&self) -> (usize, usize) {
        self.last_body
    }

    /// Orientation and resolution of the body at the first frame (`None` without a body or
    /// body collision). [`BodySurvey::too_coarse_for`] with [`BODY_EDGE_RADIUS`] says whether
    /// unpinned cloth may fall between its vertices: [`Sim::new`] accepts such a body (a crude
    /// proxy may be what a scene wants) but a caller should warn.
    pub fn body_survey(&self) -> Option<BodySurvey> {
        self.body.as_ref().map(|b| b.survey)
    }

    /// Garment vertices the body tethers pulled back in the last step (0 when they are off).
    pub fn last_tethered(&self) -> usize {
        self.body.as_ref().and_then(|b| b.tethers.as_ref()).map_or(0, |t| t.moved())
    }

    /// Garment vertices with a body tether: the free vertices that were within [`TETHER_REACH`]
    /// of the body when the ties were made, at the first step after the sim was made or its state
    /// set (0 when tethers are off, and until then).
    pub fn tethered_vertices(&self) -> usize {
        self.body.as_ref().and_then(|b| b.tethers.as_ref()).map_or(0, |t| t.count())
    }

    /// Garment vertices the collision projection moved in the last step (0 when it is off).
    pub fn last_projected(&self) -> usize {
        self.body.as_ref().and_then(|b| b.projection.as_ref()).map_or(0, |p| p.moved())
    }

    /// The last step's solver refinement (iterations, objective before and after in J), when
    /// [`SimConfig::refine`] is on and a network step ran.
    pub fn last_refinement(&self) -> Option<&crate::solve::LbfgsReport> {
        self.refiner.as_ref().and_then(|r| r.last())
    }

    /// How the last step of [`StepMode::SolverBudget`] kept its time budget (`None` in other
    /// step modes, before the first solved step and after calls that place the garment without
    /// a solve, as [`Sim::last_refinement`]).
    pub fn last_budget(&self) -> Option<BudgetUse> {
        self.refiner.as_ref().and_then(|r| r.last_budget())
    }

    /// The kernel path in use.
    pub fn tier(&self) -> Tier {
        self.net.kernels.tier()
    }

    /// Bytes of bf16 weights this simulation holds widened to f32: zero unless it runs bf16 on
    /// a kernel path without bf16 products, where the weights are widened once, at creation,
    /// and run on the f32 kernels (bf16-exact weights, f32 activations).
    pub fn widened_weight_bytes(&self) -> usize {
        self.widened.as_ref().map_or(0, WidenedBf16::bytes)
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The garment.
    pub fn garment(&self) -> &Garment {
        &self.garment
    }

    /// The static graph (mesh edges, coarse levels).
    pub fn graph(&self) -> &Graph {
        &self.graph
    }

    /// Garment positions at the current frame, m.
    pub fn positions(&self) -> &[[f32; 3]] {
        &self.state.pos
    }

    /// Output vertex normals of the current positions (empty unless [`SimConfig::normals`]).
    pub fn normals(&self) -> &[[f32; 3]] {
        &self.output_normals
    }

    /// The full state (for saving, or inspection).
    pub fn state(&self) -> &SimState {
        &self.state
    }

    /// Replaces the state (e.g. a saved one, or a garment placed on a posed body). No step has
    /// run from it: [`Sim::last_effects`] reads all false until the next step.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for wrong lengths; [`Error::NonFinite`]. The state is unchanged
    /// on error.
    pub fn set_state(&mut self, s: &SimState) -> Result<()> {
        let n = self.garment.n_vertices();
        let nb = self.body.as_ref().map_or(0, |b| b.mesh.n_vertices());
        for (what, len, want) in [
            ("state positions", s.pos.len(), n),
            ("state velocities", s.velocity.len(), n),
            ("state body previous positions", s.body_prev.len(), nb),
            ("state body positions", s.body_pos.len(), nb),
        ] {
            if len != want {
                return Err(Error::SizeMismatch { what, expected: want, got: len });
            }
        }
        check_finite("state position", &s.pos)?;
        check_finite("state velocity", &s.velocity)?;
        check_finite("state body previous position", &s.body_prev)?;
        check_finite("state body position", &s.body_pos)?;
        copy_state(&mut self.state, s);
        self.rest_frames = 0;
        // The garment is placed anew: tethers tie again at the next step.
        if let Some(t) = self.body.as_mut().and_then(|b| b.tethers.as_mut()) {
            t.untie();
        }
        // The state is in world coordinates: the speed limit's frame of reference starts anew.
        self.last_carry = [0.0; 3];
        // No step has run from this state yet.
        self.report_no_step(StepEffects::default());
        self.update_output_normals();
        Ok(())
    }

    /// Targets of the pinned vertices at the next frame (one per garment vertex; only the
    /// pinned entries are read), m. Without a call, pinned vertices keep their last target
    /// (initially their rest position).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`], [`Error::NonFinite`]; the targets are unchanged on error.
    pub fn set_pin_targets(&mut self, targets: &[[f32; 3]]) -> Result<()> {
        if targets.len() != self.pin_targets.len() {
            return Err(Error::SizeMismatch {
                what: "pin targets",
                expected: self.pin_targets.len(),
                got: targets.len(),
            });
        }
        for (i, t) in targets.iter().enumerate() {
            if self.pinned[i] && !finite3(*t) {
                return Err(Error::NonFinite { what: "pin target", index: i });
            }
        }
        self.pin_targets.copy_from_slice(targets);
        Ok(())
    }

    /// Advances one frame: `body_next` holds the body's vertices at the next frame (ignored,
    /// and may be empty, without a body). Returns the garment's new positions.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] or [`Error::NonFinite`] for bad body input, [`Error::NonFinite`]
    /// when the network's output is not finite: in every error case the state is unchanged, and
    /// so is what the sim reports about the last step ([`Sim::last_step_flops`],
    /// [`Sim::last_projected`], [`Sim::last_tethered`], [`Sim::tethered_vertices`], ...).
    pub fn step(&mut self, body_next: &[[f32; 3]]) -> Result<&[[f32; 3]]> {
        self.step_with(body_next, None)
    }

    /// [`Sim::step`] with an observer called with the node latents after the encoders and
    /// after every block (for parity tests and debugging). The observed step computes the body's
    /// rows of the last block too, which [`Sim::step`] leaves out (nothing reads them); the
    /// garment's positions are bitwise the same.
    ///
    /// # Errors
    /// See [`Sim::step`].
    // Public for the parity tests (`tests/runtime_parity.rs`): a debugging hook, not stable API.
    #[doc(hidden)]
    pub fn step_observed(
        &mut self,
        body_next: &[[f32; 3]],
        observer: &mut dyn FnMut(Probe<'_>),
    ) -> Result<&[[f32; 3]]> {
        self.step_with(body_next, Some(observer))
    }

    /// [`Sim::step`] with an observer, if any.
    fn step_with(
        &mut self,
        body_next: &[[f32; 3]],
        observer: Option<&mut dyn FnMut(Probe<'_>)>,
    ) -> Result<&[[f32; 3]]> {
        // A refused step also leaves the last step's figures as they were.
        let figures = self.last_step_figures();
        // The sim's own query stays in place (not taken out for the step): a panic unwinding
        // through the step (an engine's executor, caught at the C ABI) leaves the sim usable.
        if let Err(e) = self.step_frame(None, body_next, observer) {
            self.restore_last_step_figures(figures);
            return Err(e);
        }
        Ok(&self.state.pos[..])
    }

    /// The figures [`LastStepFigures`] keeps.
    fn last_step_figures(&self) -> LastStepFigures {
        let tethers = self.body.as_ref().and_then(|b| b.tethers.as_ref());
        LastStepFigures {
            flops: self.ws.flops,
            body: self.last_body,
            projected: self.last_projected(),
            tethered: self.last_tethered(),
            tied: tethers.is_some_and(|t| t.tied()),
            refined: self.refiner.as_ref().and_then(|r| r.solved()),
            effects: self.last_effects,
        }
    }

    /// Puts back the figures of [`Sim::last_step_figures`] after a refused step.
    fn restore_last_step_figures(&mut self, f: LastStepFigures) {
        self.ws.flops = f.flops;
        self.last_body = f.body;
        self.last_effects = f.effects;
        if let Some(r) = self.refiner.as_mut() {
            r.restore_last(f.refined);
        }
        if let Some(b) = self.body.as_mut() {
            if let Some(p) = b.projection.as_mut() {
                p.restore_last(f.projected);
            }
            if let Some(t) = b.tethers.as_mut() {
                t.restore_last(f.tethered);
                if !f.tied {
                    // The refused step tied them; the next step ties them again.
                    t.untie();
                }
            }
        }
    }

    /// One step, reading the body's grids and normals from `query` (one that an [`Outfit`] shares
    /// between the sims on its body) or (`None`) the sim's own. On an error the state is
    /// unchanged but the last step's figures may not be: callers put them back
    /// ([`Sim::last_step_figures`], [`Sim::restore_last_step_figures`]).
    fn step_frame(
        &mut self,
        mut query: Option<&mut BodyQuery>,
        body_next: &[[f32; 3]],
        mut observer: Option<&mut dyn FnMut(Probe<'_>)>,
    ) -> Result<()> {
        if let Some(r) = &mut self.refiner {
            r.start_step(self.clock.as_deref());
        }
        self.check_body_frame(body_next)?;
        let next = if self.body.is_some() { Some(body_next) } else { None };
        // The speed limit's carry over this frame; a jump teleports instead (and reports itself).
        let (teleport, limit) = (self.cfg.teleport, self.cfg.speed_limit);
        let carry = match next.map(|n| motion::frame_motion(&self.state.body_pos, n, teleport, limit)) {
            Some(FrameMotion::Step { carry }) => carry,
            Some(FrameMotion::Jump(motion)) => return self.teleport(&motion, body_next),
            None => [0.0; 3],
        };
        // Frames at rest so far, counted in only when this step succeeds.
        let mut rest_frames = self.rest_frames;
        if let Some(sl) = self.cfg.sleeping {
            if motion::at_rest(&self.state, next, sl.threshold) {
                rest_frames = rest_frames.saturating_add(1);
                if rest_frames > sl.frames {
                    self.rest_frames = rest_frames;
                    self.report_no_step(StepEffects { slept: true, ..StepEffects::default() });
                    return Ok(());
                }
            } else {
                rest_frames = 0;
            }
        }
        let startup = !self.state.started && self.cfg.step == StepMode::Network;
        // Whether the start-up pass's projection moved a vertex (the regular pass's is read last).
        let mut startup_projected = false;
        let mut startup_tethered = false;
        if self.state.started || self.cfg.step != StepMode::Network {
            self.advance(query, next, carry, DT, observer)?;
        } else {
            // Start-up: static body (next = current), dt = 1/3 s, no velocity; then the regular
            // step. Both or neither: a refusal of either, or a panic unwinding out of either (an
            // engine's executor that broke its contract), restores the state from before.
            copy_state(&mut self.before_startup, &self.state);
            let mut rollback = StartupRollback { last_carry: self.last_carry, sim: self, done: false };
            let sim = &mut *rollback.sim;
            sim.state.velocity.iter_mut().for_each(|v| *v = [0.0; 3]);
            let startup_observer = observer.as_mut().map(|o| &mut **o as &mut dyn FnMut(Probe<'_>));
            sim.advance(query.as_deref_mut(), None, [0.0; 3], DT_STARTUP, startup_observer)?;
            startup_projected = sim.last_projected() > 0;
            startup_tethered = sim.last_tethered() > 0;
            sim.state.started = true;
            sim.advance(query, next, carry, DT, observer)?;
            rollback.done = true;
        }
        self.rest_frames = rest_frames;
        self.last_effects = StepEffects {
            startup,
            carried: carry != [0.0; 3],
            refined: self.refiner.is_some(),
            projected: startup_projected || self.last_projected() > 0,
            tethered: startup_tethered || self.last_tethered() > 0,
            over_budget: self.last_budget().is_some_and(|b| !b.met()),
            ..StepEffects::default()
        };
        Ok(())
    }

    /// Refuses a body frame of the wrong length or with a non-finite vertex (any frame passes
    /// without a body).
    fn check_body_frame(&self, body: &[[f32; 3]]) -> Result<()> {
        self.body.as_ref().map_or(Ok(()), |b| b.mesh.check_positions(body))
    }

    /// Recomputes the output normals at the current positions (with [`SimConfig::normals`]).
    fn update_output_normals(&mut self) {
        if self.cfg.normals {
            vertex_normals(self.garment.faces(), &self.state.pos, &mut self.output_normals);
        }
    }

    /// Reports a call that changed the state without stepping (a sleep, a teleport, a new
    /// state): its effects, and no refinement or projection ([`Sim::last_refinement`],
    /// [`Sim::last_projected`] describe the last step that ran those).
    pub(super) fn report_no_step(&mut self, effects: StepEffects) {
        self.last_effects = effects;
        if let Some(r) = self.refiner.as_mut() {
            r.forget_last();
        }
        if let Some(b) = self.body.as_mut() {
            if let Some(p) = b.projection.as_mut() {
                p.forget_last();
            }
            if let Some(t) = b.tethers.as_mut() {
                t.forget_last();
            }
        }
    }

    /// Moves the garment (positions, velocities, pin targets) by `motion` without simulating,
    /// and puts the body at `body_now` at rest (previous = current). For a body that jumps
    /// (a cut, a respawn): [`SimConfig::teleport`] does this by itself for large jumps. Either
    /// way [`Sim::last_effects`] then reads [`StepEffects::teleported`] alone.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`], [`Error::NonFinite`] for bad body input, and
    /// [`Error::NonFinite`] for a motion that would carry the garment out of `f32` (state
    /// unchanged).
    pub fn teleport(&mut self, motion: &RigidMotion, body_now: &[[f32; 3]]) -> Result<()> {
        self.check_body_frame(body_now)?;
        if !motion.rotation.is_finite() || !motion.translation.is_finite() {
            return Err(Error::NonFinite { what: "teleport motion", index: 0 });
        }
        // A finite motion can still overflow far from the origin: checked before anything moves.
        // (Only pinned vertices' targets: the others are never read, and may be anything.)
        let n = self.state.pos.len();
        let targets = self.pin_targets.iter().zip(&self.pinned).map(|(&t, &p)| if p { t } else { [0.0; 3] });
        let moved = self.state.pos.iter().copied().chain(targets).map(|p| motion.apply(p));
        let turned = self.state.velocity.iter().map(|&v| motion.rotate(v));
        if let Some(i) = moved.chain(turned).position(|p| !finite3(p)) {
            return Err(Error::NonFinite { what: "teleported garment vertex", index: i % n.max(1) });
        }
        for p in self.state.pos.iter_mut().chain(self.pin_targets.iter_mut()) {
            *p = motion.apply(*p);
        }
        for v in self.state.velocity.iter_mut() {
            *v = motion.rotate(*v);
        }
        if self.body.is_some() {
            self.state.body_pos.copy_from_slice(body_now);
            self.state.body_prev.copy_from_slice(body_now);
        }
        self.last_carry = [0.0; 3];
        // The body is at rest from here: frames at rest are counted anew.
        self.rest_frames = 0;
        self.report_no_step(StepEffects { teleported: true, ..StepEffects::default() });
        self.update_output_normals();
        Ok(())
    }
}

/// The body query a step with a body reads: `shared` (an [`Outfit`]'s), else the sim's `own`
/// (present whenever the sim's configuration reads the body: [`Sim::with_graph`] sizes it).
fn body_query<'q>(shared: Option<&'q mut BodyQuery>, own: &'q mut Option<BodyQuery>) -> Result<&'q mut BodyQuery> {
    shared.or(own.as_mut()).ok_or(Error::UnsupportedEffect { effect: "a step without its body query" })
}

/// Undoes a start-up step that did not finish: unless `done`, puts back the state saved in
/// `before_startup` when dropped, so on an error return and on a panic alike.
struct StartupRollback<'s, 'm> {
    sim: &'s mut Sim<'m>,
    last_carry: [f32; 3],
    done: bool,
}

impl Drop for StartupRollback<'_, '_> {
    fn drop(&mut self) {
        if !self.done {
            core::mem::swap(&mut self.sim.state, &mut self.sim.before_startup);
            self.sim.last_carry = self.last_carry;
            self.sim.update_output_normals();
        }
    }
}

/// Copies `src` into `dst`, of the same lengths, without allocating (unlike `clone_from`, which
/// a derived `Clone` implements as a fresh clone).
fn copy_state(dst: &mut SimState, src: &SimState) {
    dst.pos.copy_from_slice(&src.pos);
    dst.velocity.copy_from_slice(&src.velocity);
    dst.body_prev.copy_from_slice(&src.body_prev);
    dst.body_pos.copy_from_slice(&src.body_pos);
    dst.started = src.started;
}

/// The executor of [`SimConfig::threads`]: serial, or a pool of at most as many threads as the
/// machine runs at once (more would only make the step's workers wait for each other).
fn default_executor<'m>(threads: usize) -> Box<dyn Executor + 'm> {
    #[cfg(feature = "std")]
    if threads > 1 {
        let threads = crate::limits::cap_threads(threads);
        if threads > 1 {
            return Box::new(ThreadPool::new(threads));
        }
    }
    let _ = threads;
    Box::new(Serial)
}
