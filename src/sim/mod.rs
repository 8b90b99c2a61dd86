//! The simulation: one HOOD step per call, in buffers sized at creation.
//!
//! [`Sim::new`] derives the graph, sizes every buffer and picks the kernel path; [`Sim::step`]
//! takes the body's vertices at the next frame and returns the garment's, running the data path
//! of ARCHITECTURE.md (pinned targets, body edges, features, normalise, encode, blocks, decode,
//! integrate) without allocating. Non-finite input is refused and leaves the state unchanged.
//!
//! Units: metres; one step is one frame at the model's 30 Hz (velocities are m/frame).

mod body_query;
mod clock;
pub mod driver;
mod effects;
pub mod graph;
pub mod network;
mod outfit;
mod projection;
mod refine;
mod saved;

use crate::body::rigid::{best_rigid_motion, RigidMotion};
use crate::body::{BodyMesh, BodySurvey, Nearest};
use crate::error::{Error, Result};
#[cfg(feature = "std")]
pub use crate::exec::ThreadPool;
pub use crate::exec::{Executor, Serial};
use crate::features::{self, BodyNodes, Embeddings, GarmentNodes, DT, DT_STARTUP, EDGE_WIDTH, NODE_WIDTH};
use crate::hierarchy::{Hierarchy, HierarchyConfig};
use crate::kernels::{Kernels, Tier};
use crate::math::{finite3, norm3};
use crate::mesh::{vertex_normals, Garment};
use crate::model::file::Model;
use crate::model::spec::EdgeKey;
use alloc::boxed::Box;
use alloc::vec;
use alloc::vec::Vec;
use body_query::{BodyNeeds, BodyQuery};
pub use clock::Clock;
#[cfg(feature = "std")]
pub use clock::StdClock;
pub use driver::{FixedStep, Interpolator};
pub use effects::StepEffects;
pub use graph::Graph;
use network::{BodyEdges, Net, Workspace};
pub use network::{Probe, Stage};
pub use outfit::Outfit;
use projection::Projection;
pub use projection::{DEFAULT_PROJECTION_MARGIN, PROJECTION_REACH};
use refine::{RefineBody, RefineInput, Refiner};
pub use refine::{DEFAULT_REFINE_ITERATIONS, MAX_REFINE_ITERATIONS, REFINE_COLLISION_WEIGHT};
pub use saved::{STATE_MAGIC, STATE_VERSION};

/// Default teleport threshold, metres per frame: a fast run moves a hand about 0.35 m per
/// frame; a jump of the whole body by a metre, or a 180° turn in one frame, moves far more.
pub const DEFAULT_TELEPORT: f32 = 0.45;

/// Default speed limit, metres per frame (3.6 m/s): 20 % above the fastest motion of the
/// training data (the procedural run, 3 m/s), so that none of it is affected; low enough that
/// the shipped models keep a garment on a body moved at 10 m/s (`tests/stability.rs`).
pub const DEFAULT_SPEED_LIMIT: f32 = 0.12;

/// Body-edge radius (MODEL.md section 1), metres.
pub const BODY_EDGE_RADIUS: f32 = 0.03;

/// Most threads [`SimConfig::threads`] may ask for: far beyond what a step's tasks can use, low
/// enough that a garbage count is refused instead of exhausting the system's threads.
pub const MAX_THREADS: usize = 256;

/// L-BFGS iterations per step of the default step mode ([`StepMode::default`]).
pub const DEFAULT_SOLVER_ITERATIONS: u32 = 30;

/// How a step advances the garment.
///
/// The default is [`StepMode::Solver`] with [`DEFAULT_SOLVER_ITERATIONS`]: on the accuracy/time
/// map (`docs/performance.md`, 1,000 to 12,000 vertices), 30 iterations of the solver are at least
/// as accurate as either shipped network, alone or refined, in less time, on the walk, the run and
/// every material (on the jump 30 lose the skirt where 100 keep it), and the step is
/// deterministic. For a fixed time per frame, [`StepMode::SolverBudget`] is the map's pick;
/// [`StepMode::Network`] is HOOD itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepMode {
    /// The network predicts the step (HOOD), optionally refined ([`SimConfig::refine`]).
    Network,
    /// No network: the implicit step itself, `iterations` L-BFGS iterations (1 ..=
    /// [`MAX_REFINE_ITERATIONS`]) of the refinement's objective started from the coasting guess
    /// (every free vertex moving on at its velocity). No start-up step; the network's buffers
    /// are not touched. The model still sets the garment's checks (materials, pins).
    Solver {
        /// L-BFGS iterations per step.
        iterations: u32,
    },
    /// As [`StepMode::Solver`], within `micros` microseconds of wall time per step (from the
    /// body's update on): after each iteration, the solve ends if the longest iteration so far
    /// would not end within the budget, or after `max_iterations` (1 ..= [`MAX_REFINE_ITERATIONS`]);
    /// at least one iteration runs. The step that fits a frame's time budget. The result then depends on the machine and its load (not bitwise
    /// reproducible). Reads the sim's clock ([`Sim::set_clock`]; with `std` one is there).
    SolverBudget {
        /// Wall time of one step's solve, µs (at least 1).
        micros: u32,
        /// L-BFGS iterations per step at most.
        max_iterations: u32,
    },
}

/// Arithmetic of the network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Precision {
    /// f32 weights and activations.
    #[default]
    F32,
    /// bf16 weights and activations, f32 accumulation (needs a model file with bf16 weights).
    Bf16,
}

/// When to skip steps because nothing moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sleeping {
    /// Largest body vertex displacement per frame (m) and largest garment speed (m/frame)
    /// that count as "at rest".
    pub threshold: f32,
    /// Consecutive frames at rest before the garment sleeps.
    pub frames: u32,
}

impl Default for Sleeping {
    fn default() -> Self {
        Sleeping { threshold: 1e-5, frames: 3 }
    }
}

/// The effects a scene uses; what is off costs nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    /// Body nodes and body edges (collision with the body). Off: no grid, no body work.
    pub body_collision: bool,
    /// Drive pinned vertices to their targets (see [`Sim::set_pin_targets`]).
    pub pinning: bool,
    /// Compute output vertex normals after every step ([`Sim::normals`]).
    pub normals: bool,
    /// Skip steps while body and garment are at rest.
    pub sleeping: Option<Sleeping>,
    /// Network arithmetic.
    pub precision: Precision,
    /// Run the start-up (relaxation) step with a static body and dt = 1/3 s before the first
    /// regular step (MODEL.md section 5).
    pub startup: bool,
    /// Kernel path cap (`None`: the best this CPU has; for bf16, the faster of its native and
    /// widened paths, [`crate::kernels::bf16_choice`]).
    pub tier: Option<Tier>,
    /// Teleport threshold, metres: when the body's centroid, or some body vertex beyond what
    /// the speed limit carries, moves farther than this in one frame, the garment is carried
    /// along by the body's best-fit rigid motion instead of being stepped through the jump
    /// (`None`: never).
    pub teleport: Option<f32>,
    /// Speed limit, metres per frame: when the body's centroid moves farther than this in one
    /// frame, the step runs in a frame of reference that follows the excess (the garment is
    /// carried by it, and the network sees the body move at the limit), like the inertia scales
    /// of game-engine cloth. The garment then feels the body's acceleration only up to the
    /// limit: a character moved at 10 m/s keeps its clothes (`None`: never; the network then
    /// sees speeds it was not trained on). A deviation from HOOD that only acts above the limit.
    pub speed_limit: Option<f32>,
    /// Collision projection margin, metres: after every step, each free garment vertex closer
    /// than this to the plane of its nearest body face (by centroid, within
    /// [`PROJECTION_REACH`]), or behind it, is moved along the face's normal to the margin, and
    /// its velocity takes the move (`None`: off). A post-process outside HOOD, for scenes that
    /// must not show the body through the cloth; needs body collision. See
    /// [`DEFAULT_PROJECTION_MARGIN`].
    pub projection: Option<f32>,
    /// Solver refinement: this many L-BFGS iterations (1 ..= [`MAX_REFINE_ITERATIONS`]) of the
    /// physics objective (training form, collision weight [`REFINE_COLLISION_WEIGHT`]), started
    /// from the network's prediction, before the projection, on every step but the start-up
    /// (`None`: off). Not part of HOOD: it
    /// trades time for accuracy, bringing each step toward the implicit step's optimum; its
    /// cost grows with the garment's vertices. [`Sim::last_refinement`] reports each one.
    pub refine: Option<u32>,
    /// What computes the step: the solver alone (the default, see [`StepMode`]) or the network.
    pub step: StepMode,
    /// Threads for the step's parallel parts when no executor is plugged in with
    /// [`Sim::set_executor`]: 1 runs serially; more (up to [`MAX_THREADS`]) starts a
    /// [`ThreadPool`] (feature `std`) of at most the machine's hardware threads, with fewer
    /// workers if the system refuses some. The
    /// network and the solver (step mode and refinement) both use them, and give the same bits
    /// for any number of threads.
    pub threads: usize,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            body_collision: true,
            pinning: true,
            normals: false,
            sleeping: None,
            precision: Precision::F32,
            startup: true,
            tier: None,
            teleport: Some(DEFAULT_TELEPORT),
            speed_limit: Some(DEFAULT_SPEED_LIMIT),
            projection: None,
            refine: None,
            step: StepMode::default(),
            threads: 1,
        }
    }
}

impl SimConfig {
    /// The defaults with the network's step ([`StepMode::Network`], HOOD): the start-up step,
    /// teleport and speed limit on; refinement, projection and sleeping off.
    pub fn network() -> Self {
        SimConfig { step: StepMode::Network, ..SimConfig::default() }
    }
}

impl Default for StepMode {
    fn default() -> Self {
        StepMode::Solver { iterations: DEFAULT_SOLVER_ITERATIONS }
    }
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
    nearest: Vec<Option<Nearest>>,
    /// Last step's nearest body vertex of every garment vertex (`u32::MAX`: none yet): the
    /// search starts from it, which only changes its speed.
    hints: Vec<u32>,
    active_of: Vec<u32>,
    active: Vec<u32>,
    edge_garment: Vec<u32>,
    edge_body: Vec<u32>,
    edge_pairs: Vec<[u32; 2]>,
    /// The body's previous and next frames as the network sees them under the speed limit, in
    /// the frame of reference that follows the carried motion.
    carried_prev: Vec<[f32; 3]>,
    carried_next: Vec<[f32; 3]>,
    /// Collision projection's buffers (only with [`SimConfig::projection`]).
    projection: Option<Projection>,
    /// Orientation and resolution of the body at the first frame.
    survey: BodySurvey,
}

/// One garment on one body, stepped by one model.
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
    exec: Box<dyn Executor + 'm>,
    /// The clock of [`StepMode::SolverBudget`].
    clock: Option<Box<dyn Clock + 'm>>,
    last_body: (usize, usize),
    /// The speed limit's carry of the last step, m (zero: none).
    last_carry: [f32; 3],
    /// What the last successful step did ([`Sim::last_effects`]).
    last_effects: StepEffects,
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
    /// garment's hierarchy built by the default [`HierarchyConfig`].
    ///
    /// # Errors
    /// [`Error::UnsupportedEffect`] for an effect the model was not trained with or a bf16 run
    /// of an f32-only file; [`Error::IncompatibleModel`]; errors of the hierarchy.
    pub fn new(model: &'m Model<'m>, garment: &Garment, body: Option<BodyDesc<'_>>, cfg: SimConfig) -> Result<Sim<'m>> {
        let levels = model.spec().levels;
        let hierarchy = Hierarchy::build(garment, &HierarchyConfig { levels, ..HierarchyConfig::default() })?;
        let graph = Graph::new(garment, &hierarchy)?;
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
        if cfg.projection.is_some() && !use_body {
            return Err(Error::UnsupportedEffect { effect: "collision projection (needs a body and body collision)" });
        }
        let m0 = garment.materials()[0];
        if !spec.effects.local_materials && garment.materials().iter().any(|m| *m != m0) {
            return Err(Error::UnsupportedEffect { effect: "per-vertex materials" });
        }
        let kernels = match cfg.tier {
            // bf16 weights on whichever of vdpbf16ps and widened f32 FMAs is faster here.
            None if cfg.precision == Precision::Bf16 => Kernels::best_bf16(),
            None => Kernels::best(),
            Some(t) => Kernels::with_tier(t.min(Kernels::best().tier())).unwrap_or(Kernels::scalar()),
        };
        let n = garment.n_vertices();
        let body_state = match body {
            Some(b) if use_body => {
                let survey = b.mesh.survey(b.positions)?;
                if survey.inside_out() {
                    return Err(Error::InsideOut { what: "body" });
                }
                let nb = b.mesh.n_vertices();
                Some(BodyState {
                    mesh: b.mesh.clone(),
                    nearest: vec![None; n],
                    hints: vec![u32::MAX; n],
                    active_of: vec![u32::MAX; nb],
                    active: vec![0; nb.min(n)],
                    edge_garment: vec![0; n],
                    edge_body: vec![0; n],
                    edge_pairs: vec![[0; 2]; n],
                    carried_prev: if cfg.speed_limit.is_some() { vec![[0.0; 3]; nb] } else { Vec::new() },
                    carried_next: if cfg.speed_limit.is_some() { vec![[0.0; 3]; nb] } else { Vec::new() },
                    projection: match cfg.projection {
                        Some(margin) => Some(Projection::new(n, margin)?),
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
        let max_active = body_state.as_ref().map_or(0, |b| b.active.len());
        let net = Net { model, kernels, bf16: cfg.precision == Precision::Bf16 };
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
    /// `std` a sim starts with [`StdClock`]).
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

    /// Garment vertices the collision projection moved in the last step (0 when it is off).
    pub fn last_projected(&self) -> usize {
        self.body.as_ref().and_then(|b| b.projection.as_ref()).map_or(0, |p| p.moved())
    }

    /// The last step's solver refinement (iterations, objective before and after in J), when
    /// [`SimConfig::refine`] is on and a network step ran.
    pub fn last_refinement(&self) -> Option<&crate::solve::LbfgsReport> {
        self.refiner.as_ref().and_then(|r| r.last())
    }

    /// The kernel path in use.
    pub fn tier(&self) -> Tier {
        self.net.kernels.tier()
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
    /// when the network's output is not finite: in every error case the state is unchanged.
    pub fn step(&mut self, body_next: &[[f32; 3]]) -> Result<&[[f32; 3]]> {
        self.step_observed(body_next, &mut |_| {})
    }

    /// [`Sim::step`] with an observer called with the node latents after the encoders and
    /// after every block (for parity tests and debugging).
    ///
    /// # Errors
    /// See [`Sim::step`].
    pub fn step_observed(
        &mut self,
        body_next: &[[f32; 3]],
        observer: &mut dyn FnMut(Probe<'_>),
    ) -> Result<&[[f32; 3]]> {
        // The sim's own query stays in place (not taken out for the step): a panic unwinding
        // through the step (an engine's executor, caught at the C ABI) leaves the sim usable.
        self.step_with(None, body_next, observer).map(|()| &self.state.pos[..])
    }

    /// [`Sim::step_observed`] reading the body's grids and normals from `query`, one that an
    /// [`Outfit`] shares between the sims on its body, or (`None`) the sim's own.
    fn step_with(
        &mut self,
        mut query: Option<&mut BodyQuery>,
        body_next: &[[f32; 3]],
        observer: &mut dyn FnMut(Probe<'_>),
    ) -> Result<()> {
        if let Some(b) = &self.body {
            let nb = b.mesh.n_vertices();
            if body_next.len() != nb {
                return Err(Error::SizeMismatch { what: "body vertices", expected: nb, got: body_next.len() });
            }
            check_finite("body vertex", body_next)?;
        }
        // The body's mean motion over this frame (and its largest vertex motion, squared), and
        // the part of the mean the speed limit carries.
        let ((mean, largest2), carry) = match &self.body {
            Some(_) if self.cfg.teleport.is_some() || self.cfg.speed_limit.is_some() => {
                let m = body_motion(&self.state.body_pos, body_next);
                (m, self.cfg.speed_limit.map_or([0.0; 3], |l| excess_motion(m.0, l)))
            }
            _ => (([0.0; 3], 0.0), [0.0; 3]),
        };
        if let (Some(limit), Some(_)) = (self.cfg.teleport, &self.body) {
            // A jump: the body as a whole, or some vertex beyond what the speed limit carries,
            // moves farther than the threshold (fast motion carried by the limit is no jump).
            // Only a carried step needs a second pass over the body.
            let l2 = limit * limit;
            let jump = norm3(mean) > limit
                || if carry == [0.0; 3] {
                    largest2 > l2
                } else {
                    self.state.body_pos.iter().zip(body_next).any(|(a, b)| {
                        let d = [b[0] - a[0] - carry[0], b[1] - a[1] - carry[1], b[2] - a[2] - carry[2]];
                        d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > l2
                    })
                };
            if jump {
                let motion = best_rigid_motion(&self.state.body_pos, body_next);
                // Reports itself in `last_effects`.
                self.teleport(&motion, body_next)?;
                return Ok(());
            }
        }
        // Frames at rest so far, counted in only when this step succeeds.
        let mut rest_frames = self.rest_frames;
        if let Some(sl) = self.cfg.sleeping {
            if self.at_rest(body_next, sl.threshold) {
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
        let next = if self.body.is_some() { Some(body_next) } else { None };
        let startup = !self.state.started && self.cfg.step == StepMode::Network;
        // Whether the start-up pass's projection moved a vertex (the regular pass's is read last).
        let mut startup_projected = false;
        if self.state.started || self.cfg.step != StepMode::Network {
            self.advance(query, next, carry, DT, observer)?;
        } else {
            // Start-up: static body (next = current), dt = 1/3 s, no velocity; then the regular
            // step. Both or neither: a refusal of either restores the state from before.
            copy_state(&mut self.before_startup, &self.state);
            let last_carry = self.last_carry;
            self.state.velocity.iter_mut().for_each(|v| *v = [0.0; 3]);
            let both = self.advance(query.as_deref_mut(), None, [0.0; 3], DT_STARTUP, observer).and_then(|()| {
                startup_projected = self.last_projected() > 0;
                self.state.started = true;
                self.advance(query, next, carry, DT, observer)
            });
            if let Err(e) = both {
                core::mem::swap(&mut self.state, &mut self.before_startup);
                self.last_carry = last_carry;
                self.update_output_normals();
                return Err(e);
            }
        }
        self.rest_frames = rest_frames;
        self.last_effects = StepEffects {
            startup,
            carried: carry != [0.0; 3],
            refined: self.refiner.is_some(),
            projected: startup_projected || self.last_projected() > 0,
            ..StepEffects::default()
        };
        Ok(())
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
        if let Some(p) = self.body.as_mut().and_then(|b| b.projection.as_mut()) {
            p.forget_last();
        }
    }

    /// Moves the garment (positions, velocities, pin targets) by `motion` without simulating,
    /// and puts the body at `body_now` at rest (previous = current). For a body that jumps
    /// (a cut, a respawn): [`SimConfig::teleport`] does this by itself for large jumps. Either
    /// way [`Sim::last_effects`] then reads [`StepEffects::teleported`] alone.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`], [`Error::NonFinite`] for bad body input (state unchanged).
    pub fn teleport(&mut self, motion: &RigidMotion, body_now: &[[f32; 3]]) -> Result<()> {
        if let Some(b) = &self.body {
            if body_now.len() != b.mesh.n_vertices() {
                return Err(Error::SizeMismatch {
                    what: "body vertices",
                    expected: b.mesh.n_vertices(),
                    got: body_now.len(),
                });
            }
            check_finite("body vertex", body_now)?;
        }
        if !motion.rotation.is_finite() || !motion.translation.is_finite() {
            return Err(Error::NonFinite { what: "teleport motion", index: 0 });
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

    fn at_rest(&self, body_next: &[[f32; 3]], threshold: f32) -> bool {
        let t2 = threshold * threshold;
        let d2 = |a: [f32; 3], b: [f32; 3]| (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum::<f32>();
        let body_still = self.body.is_none()
            || self.state.body_pos.iter().zip(body_next).all(|(a, b)| d2(*a, *b) <= t2)
                && self.state.body_prev.iter().zip(&self.state.body_pos).all(|(a, b)| d2(*a, *b) <= t2);
        body_still && self.state.velocity.iter().all(|v| d2(*v, [0.0; 3]) <= t2)
    }

    /// One network step from the current state to `body_next` (`None`: static body), in the
    /// speed limit's frame of reference: it moved by `self.last_carry` over the last step and
    /// moves by `carry` over this one (m; both zero but under the limit). In that frame,
    /// translated to coincide with the world at the current frame, the body's previous frame
    /// lies at `body_prev + last_carry` and its next at `body_next - carry`; the garment's
    /// velocity is already relative to it, and its new positions are moved by `+carry`.
    fn advance(
        &mut self,
        mut query: Option<&mut BodyQuery>,
        body_next: Option<&[[f32; 3]]>,
        carry: [f32; 3],
        dt: f32,
        observer: &mut dyn FnMut(Probe<'_>),
    ) -> Result<()> {
        let n = self.garment.n_vertices();
        let carried = carry != [0.0; 3];
        let last = if dt == DT_STARTUP { [0.0; 3] } else { self.last_carry };
        // Pinned vertices sit at their targets before the graph is built; keep the old
        // positions so that a refused step leaves the state unchanged.
        self.new_pos.copy_from_slice(&self.state.pos);
        let first_step = dt == DT_STARTUP;
        for i in 0..n {
            if self.pinned[i] {
                let t = self.pin_targets[i];
                self.new_pos[i] = if carried { [t[0] - carry[0], t[1] - carry[1], t[2] - carry[2]] } else { t };
            }
        }
        match self.cfg.step {
            StepMode::Network => self.predict(query.as_deref_mut(), body_next, carry, last, dt, observer)?,
            StepMode::Solver { .. } | StepMode::SolverBudget { .. } => {
                // The coasting guess, which the solver below refines into the implicit step.
                for i in 0..n {
                    let v = if self.pinned[i] { [0.0; 3] } else { self.state.velocity[i] };
                    self.new_vel[i] = v;
                    if !self.pinned[i] {
                        let p = self.state.pos[i];
                        self.new_pos[i] = [p[0] + v[0], p[1] + v[1], p[2] + v[2]];
                    }
                }
            }
        }
        if carried {
            for p in self.new_pos.iter_mut() {
                *p = [p[0] + carry[0], p[1] + carry[1], p[2] + carry[2]];
            }
        }
        // Not the start-up step: its optimum at dt = 1/3 s is a relaxation (for cloth without a
        // body, a free fall of a metre), and the velocity it leaves would carry that into the
        // first frame. The network's own start-up prediction is HOOD's.
        let refined = self.refiner.is_some() && !first_step;
        if let (Some(r), true) = (&mut self.refiner, refined) {
            let now = &self.state.body_pos[..];
            let body = match &self.body {
                Some(b) => {
                    let [now, next] = body_query(query.as_deref_mut(), &mut self.query)?.faces(
                        &b.mesh,
                        now,
                        body_next.unwrap_or(now),
                    )?;
                    Some(RefineBody { now, next })
                }
                None => None,
            };
            let input = RefineInput {
                pos: &self.state.pos,
                velocity: &self.state.velocity,
                carry,
                dt,
                pinned: &self.pinned,
                body,
            };
            r.apply(&*self.exec, &input, self.clock.as_deref(), &mut self.new_pos, &mut self.new_vel)?;
        }
        if let Some(b) = &mut self.body {
            if let Some(proj) = &mut b.projection {
                // A refined step has built the faces at the same frame.
                let at = body_next.unwrap_or(&self.state.body_pos);
                let faces = body_query(query, &mut self.query)?.faces_at(&b.mesh, at)?;
                proj.apply(&*self.exec, faces, &self.pinned, &mut self.new_pos, &mut self.new_vel)?;
            }
        }
        // Commit.
        if let (Some(r), true) = (&mut self.refiner, refined) {
            r.commit();
        }
        core::mem::swap(&mut self.state.pos, &mut self.new_pos);
        core::mem::swap(&mut self.state.velocity, &mut self.new_vel);
        if let Some(next) = body_next {
            core::mem::swap(&mut self.state.body_prev, &mut self.state.body_pos);
            self.state.body_pos.copy_from_slice(next);
        } else if !self.state.body_pos.is_empty() {
            let (prev, cur) = (&mut self.state.body_prev, &self.state.body_pos);
            prev.copy_from_slice(cur);
        }
        self.update_output_normals();
        self.last_carry = carry;
        Ok(())
    }
    /// The network's prediction of the step (features, forward pass, integration) into
    /// `new_pos` / `new_vel`, in the speed limit's frame (see [`advance`](Self::advance)); pinned
    /// vertices are already at their targets in `new_pos`.
    fn predict(
        &mut self,
        query: Option<&mut BodyQuery>,
        body_next: Option<&[[f32; 3]]>,
        carry: [f32; 3],
        last: [f32; 3],
        dt: f32,
        observer: &mut dyn FnMut(Probe<'_>),
    ) -> Result<()> {
        let n = self.garment.n_vertices();
        let carried = carry != [0.0; 3];
        let shifted = carried || last != [0.0; 3];
        let first_step = dt == DT_STARTUP;
        if let (true, Some(b), Some(next)) = (shifted, &mut self.body, body_next) {
            let shift = |out: &mut [[f32; 3]], src: &[[f32; 3]], by: [f32; 3]| {
                for (o, p) in out.iter_mut().zip(src) {
                    *o = [p[0] + by[0], p[1] + by[1], p[2] + by[2]];
                }
            };
            shift(&mut b.carried_prev, &self.state.body_prev, last);
            shift(&mut b.carried_next, next, carry.map(|c| -c));
        }
        let pos = &self.new_pos;
        // Body edges at the current frame.
        let mut prefix = [0usize; 4];
        let mut n_active = 0;
        let mut body_normals: &[[f32; 3]] = &[];
        if let Some(b) = &mut self.body {
            let bpos = &self.state.body_pos;
            let (grid, normals) = body_query(query, &mut self.query)?.vertices(&b.mesh, bpos)?;
            body_normals = normals;
            grid.nearest_within_on(&*self.exec, pos, BODY_EDGE_RADIUS, &b.hints, &mut b.nearest)?;
            for (h, near) in b.hints.iter_mut().zip(&b.nearest) {
                if let Some(near) = near {
                    *h = near.index;
                }
            }
            b.mesh.keep_not_omitted(&mut b.nearest);
            let mut nb = 0;
            for &g in &self.graph.body_order {
                if let Some(near) = b.nearest[g as usize] {
                    b.edge_garment[nb] = g;
                    b.edge_body[nb] = near.index;
                    nb += 1;
                    let lvl = self.graph.vertex_level[g as usize] as usize;
                    for p in prefix.iter_mut().take(lvl + 1) {
                        *p += 1;
                    }
                }
            }
            // Active body nodes, ascending; edge_body becomes the active row.
            for &o in &b.edge_body[..nb] {
                b.active_of[o as usize] = 0;
            }
            for (o, a) in b.active_of.iter_mut().enumerate() {
                if *a == 0 {
                    *a = n_active as u32;
                    b.active[n_active] = o as u32;
                    n_active += 1;
                }
            }
            for k in 0..nb {
                let o = b.edge_body[k];
                b.edge_pairs[k] = [b.edge_garment[k], o];
                b.edge_body[k] = b.active_of[o as usize];
            }
            for &o in &b.active[..n_active] {
                b.active_of[o as usize] = u32::MAX;
            }
        }
        // Node features.
        vertex_normals(self.garment.faces(), pos, &mut self.garment_normals);
        let model = self.net.model;
        let emb = Embeddings { node_type: model.node_type_embedding, level: model.level_embedding };
        let vel = &self.state.velocity;
        let gn = GarmentNodes {
            velocity: vel,
            normals: &self.garment_normals,
            mass: self.garment.vertex_mass(),
            pinned: &self.pinned,
            level: &self.graph.vertex_level,
            material: &self.material_in,
            dt,
        };
        let (gpart, bpart) = self.ws.node_features.split_at_mut(n * NODE_WIDTH);
        features::garment_node_features(&gn, &emb, gpart)?;
        let nb = prefix[0];
        if let Some(b) = &self.body {
            let bpos = &self.state.body_pos;
            let bprev = match (first_step, shifted) {
                (true, _) => bpos,
                (false, true) => &b.carried_prev,
                (false, false) => &self.state.body_prev,
            };
            let bn = BodyNodes { pos: bpos, prev: bprev, normals: body_normals, omitted: b.mesh.omitted(), dt };
            features::body_node_features(&bn, &b.active[..n_active], &emb, &mut bpart[..n_active * NODE_WIDTH])?;
            let bnext = match (shifted, body_next) {
                (true, Some(_)) => &b.carried_next,
                _ => body_next.unwrap_or(bpos),
            };
            features::body_edge_features(
                &b.edge_pairs[..nb],
                pos,
                bpos,
                bnext,
                dt,
                &mut self.ws.g2b_features[..nb * 9],
                &mut self.ws.b2g_features[..nb * 9],
            )?;
        }
        self.ws.flops = 0;
        // Mesh and coarse edges: features, then encode.
        let rest = self.garment.rest();
        if self.ws.uses(EdgeKey::Mesh) {
            let e = &self.graph.mesh.global;
            features::edge_features(e, pos, rest, &self.material_in, dt, self.ws.edge_feature_rows(e.len()))?;
            self.ws.encode_edges(&self.net, &*self.exec, EdgeKey::Mesh, e.len())?;
        }
        for l in 0..self.graph.coarse.len().min(3) {
            let key = EdgeKey::coarse(l).unwrap_or(EdgeKey::Mesh);
            if !self.ws.uses(key) {
                continue;
            }
            let e = &self.graph.coarse[l].edges.global;
            let rows = self.ws.edge_feature_rows(e.len());
            debug_assert_eq!(rows.len(), e.len() * EDGE_WIDTH);
            features::edge_features(e, pos, rest, &self.material_in, dt, rows)?;
            self.ws.encode_edges(&self.net, &*self.exec, key, e.len())?;
        }
        let body_edges = match &self.body {
            Some(b) => BodyEdges { garment: &b.edge_garment[..nb], body: &b.edge_body[..nb], n_active, prefix },
            None => BodyEdges { garment: &[], body: &[], n_active: 0, prefix: [0; 4] },
        };
        self.ws.forward(&self.net, &*self.exec, &self.graph, &body_edges, observer)?;
        self.last_body = (nb, n_active);
        // Integrate: acc = decoded * std + mean; v' = v + acc; x' = x + v + acc.
        let (mean, std) = model.output_stats();
        for i in 0..n {
            if self.pinned[i] {
                self.new_vel[i] = [0.0; 3];
                continue;
            }
            let d = &self.ws.decoded[3 * i..3 * i + 3];
            let v = self.state.velocity[i];
            let mut nv = [0.0; 3];
            let mut np = [0.0; 3];
            for k in 0..3 {
                let acc = d[k] * std[k] + mean[k];
                nv[k] = v[k] + acc;
                np[k] = self.new_pos[i][k] + v[k] + acc;
            }
            if !finite3(np) || !finite3(nv) {
                return Err(Error::NonFinite { what: "network output for garment vertex", index: i });
            }
            self.new_vel[i] = nv;
            self.new_pos[i] = np;
        }
        Ok(())
    }
}

/// The body query a step with a body reads: `shared` (an [`Outfit`]'s), else the sim's `own`
/// (present whenever the sim's configuration reads the body: [`Sim::with_graph`] sizes it).
fn body_query<'q>(shared: Option<&'q mut BodyQuery>, own: &'q mut Option<BodyQuery>) -> Result<&'q mut BodyQuery> {
    shared.or(own.as_mut()).ok_or(Error::UnsupportedEffect { effect: "a step without its body query" })
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

/// The mean displacement of the body's vertices from `now` to `next` (m) and the largest squared
/// displacement of one vertex (m²), in one pass.
fn body_motion(now: &[[f32; 3]], next: &[[f32; 3]]) -> ([f32; 3], f32) {
    let mut sum = [0.0f64; 3];
    let mut largest2 = 0.0f32;
    for (a, b) in now.iter().zip(next) {
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        for k in 0..3 {
            sum[k] += d[k] as f64;
        }
        largest2 = largest2.max(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    }
    let n = now.len().max(1) as f64;
    (sum.map(|v| (v / n) as f32), largest2)
}

/// The part of the displacement `d` beyond `limit` metres (zero when it is shorter), m.
fn excess_motion(d: [f32; 3], limit: f32) -> [f32; 3] {
    let len = norm3(d);
    if len.is_nan() || len <= limit {
        return [0.0; 3];
    }
    let s = 1.0 - limit / len;
    d.map(|v| v * s)
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
