//! What a scene asks of a step: [`SimConfig`] (the effects it uses, each off at no cost), the
//! [`StepMode`] that computes the step, the network's [`Precision`], [`Sleeping`], and their
//! defaults.

#[cfg(all(doc, feature = "std"))]
use super::ThreadPool;
#[cfg(doc)]
use super::{
    Sim, DEFAULT_PROJECTION_MARGIN, DEFAULT_TETHER_SLACK, MAX_REFINE_ITERATIONS, PROJECTION_REACH,
    REFINE_COLLISION_WEIGHT, TETHER_REACH,
};
use crate::kernels::Tier;

/// Default teleport threshold, metres per frame: a fast run moves a hand about 0.35 m per
/// frame; a jump of the whole body by a metre, or a 180° turn in one frame, moves far more.
pub const DEFAULT_TELEPORT: f32 = 0.45;

/// Default speed limit, metres per frame (3.6 m/s): 20 % above the fastest motion of the
/// training data (the procedural run, 3 m/s), so that none of it is affected; low enough that
/// the shipped models keep a garment on a body moved at 10 m/s (`tests/stability.rs`).
pub const DEFAULT_SPEED_LIMIT: f32 = 0.12;

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
    /// As [`StepMode::Solver`], within `micros` microseconds of wall time per step, counted
    /// from the start of [`Sim::step`] (the frame's checks and the body's grids are in it):
    /// after each iteration, the solve ends if the longest iteration so far would not end within
    /// the budget, or after `max_iterations` (1 ..= [`MAX_REFINE_ITERATIONS`]); at least one
    /// iteration runs, so a step whose set-up and one iteration take longer overruns, and says
    /// so ([`Sim::last_budget`], [`StepEffects::over_budget`](super::StepEffects::over_budget)).
    /// The step that fits a frame's time budget. The result then depends on the machine and its
    /// load (not bitwise reproducible). Reads the sim's clock ([`Sim::set_clock`]; with `std`
    /// one is there).
    SolverBudget {
        /// Wall time of one step, µs (at least 1).
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
    /// bf16 weights in the blocks and the decoder (needs a model file with bf16 weights); the
    /// encoders run in f32, as their outputs start the latents' residual streams (about a
    /// twentieth of the products). Where the kernel path has bf16 products (AVX-512-BF16, AMX)
    /// the activations are bf16 too, accumulated in f32; elsewhere the weights are widened to
    /// f32 once, when the simulation is made, and run at the f32 cost with f32 activations
    /// ([`Sim::widened_weight_bytes`](crate::sim::Sim::widened_weight_bytes)).
    Bf16,
}

impl Precision {
    /// `"f32"` or `"bf16"`, as the command line and the reports spell it.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::Bf16 => "bf16",
        }
    }
}

/// When to skip steps because nothing moves.
///
/// Built with [`Sleeping::new`], or from [`Sleeping::default`] and the `with_` methods (new
/// fields may come, so it has no struct literal outside this crate).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Sleeping {
    /// Largest body vertex displacement per frame (m) and largest garment speed (m/frame)
    /// that count as "at rest".
    pub threshold: f32,
    /// Consecutive frames at rest before the garment sleeps.
    pub frames: u32,
}

impl Default for Sleeping {
    /// A threshold of 1e-5 m, 3 frames.
    fn default() -> Self {
        Sleeping { threshold: 1e-5, frames: 3 }
    }
}

impl Sleeping {
    /// Sleeping after `frames` consecutive frames at rest, at most `threshold` m (body vertex
    /// displacement and garment speed per frame) counting as rest.
    pub fn new(threshold: f32, frames: u32) -> Self {
        Sleeping { threshold, frames }
    }

    with_fields! {
        /// Sets [`threshold`](Self::threshold): the largest motion at rest, m per frame.
        with_threshold => threshold: f32;
        /// Sets [`frames`](Self::frames): consecutive frames at rest before the garment sleeps.
        with_frames => frames: u32;
    }
}

/// The effects a scene uses; what is off costs nothing.
///
/// Start from [`SimConfig::default`] (the solver's step) or [`SimConfig::network`] (HOOD's) and
/// change what differs with the `with_` methods; new fields may come, so there is no struct
/// literal outside this crate. The fields stay public to read and to assign.
///
/// # Examples
///
/// ```
/// use hood::sim::{SimConfig, Sleeping};
///
/// let cfg = SimConfig::network()
///     .with_refine(Some(3))
///     .with_projection(Some(hood::sim::DEFAULT_PROJECTION_MARGIN))
///     .with_sleeping(Some(Sleeping::new(1e-5, 4)))
///     .with_threads(2);
/// assert_eq!(cfg.refine, Some(3));
/// assert_eq!(cfg.threads, 2);
///
/// // A field can also be assigned.
/// let mut cfg = cfg;
/// cfg.normals = true;
/// assert!(cfg.normals && cfg.startup);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
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
    /// Kernel path cap (`None`: the faster of the precision's two paths on this CPU,
    /// [`crate::kernels::f32_choice`], [`crate::kernels::bf16_choice`]).
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
    /// Body tethers' slack, metres: at the first step (and the first after [`Sim::set_state`]),
    /// every free garment vertex within [`TETHER_REACH`] of a body vertex is tied to the nearest
    /// one, and after every step a vertex farther from it than its distance then plus this slack
    /// is moved straight back to that length; the cloth around it follows, so that no edge from
    /// a moved vertex stays stretched by more than
    /// [`TETHER_FOLLOW_STRETCH`](super::TETHER_FOLLOW_STRETCH), and velocities take the moves
    /// (`None`: off). The "max distance" constraint of game-engine cloth, outside HOOD and the
    /// physics, for garments that must stay on whatever the motion (a top upside down); needs
    /// body collision. Applied after [`projection`](Self::projection), so that the cloth's
    /// following is not undone, and the cloth follows the projection's moves as it follows the
    /// pulls. See [`DEFAULT_TETHER_SLACK`].
    pub tether: Option<f32>,
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
    /// `ThreadPool` (feature `std`) of at most the machine's hardware threads, with fewer
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
            tether: None,
            refine: None,
            step: StepMode::default(),
            threads: 1,
        }
    }
}

impl SimConfig {
    /// The defaults with the network's step ([`StepMode::Network`], HOOD): the start-up step,
    /// teleport and speed limit on; refinement, projection, tethers and sleeping off.
    pub fn network() -> Self {
        SimConfig { step: StepMode::Network, ..SimConfig::default() }
    }

    with_fields! {
        /// Sets [`body_collision`](Self::body_collision): collision with the body.
        with_body_collision => body_collision: bool;
        /// Sets [`pinning`](Self::pinning): pinned vertices driven to their targets.
        with_pinning => pinning: bool;
        /// Sets [`normals`](Self::normals): output vertex normals after every step.
        with_normals => normals: bool;
        /// Sets [`sleeping`](Self::sleeping): skipping steps at rest (`None`: never).
        with_sleeping => sleeping: Option<Sleeping>;
        /// Sets [`precision`](Self::precision): the network's arithmetic.
        with_precision => precision: Precision;
        /// Sets [`startup`](Self::startup): the start-up step before the first regular one.
        with_startup => startup: bool;
        /// Sets [`tier`](Self::tier): the kernel path cap (`None`: the best this CPU has).
        with_tier => tier: Option<Tier>;
        /// Sets [`teleport`](Self::teleport): the threshold, metres per frame (`None`: never).
        with_teleport => teleport: Option<f32>;
        /// Sets [`speed_limit`](Self::speed_limit): metres per frame (`None`: never).
        with_speed_limit => speed_limit: Option<f32>;
        /// Sets [`projection`](Self::projection): the margin, metres (`None`: off).
        with_projection => projection: Option<f32>;
        /// Sets [`tether`](Self::tether): the slack, metres (`None`: off).
        with_tether => tether: Option<f32>;
        /// Sets [`refine`](Self::refine): L-BFGS refinement iterations per step (`None`: off).
        with_refine => refine: Option<u32>;
        /// Sets [`step`](Self::step): what computes the step.
        with_step => step: StepMode;
        /// Sets [`threads`](Self::threads): threads for the step's parallel parts (1: serial).
        with_threads => threads: usize;
    }
}

impl Default for StepMode {
    fn default() -> Self {
        StepMode::Solver { iterations: DEFAULT_SOLVER_ITERATIONS }
    }
}
