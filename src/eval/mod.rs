//! Evaluating a model on an animated scene (feature `tools`; EVALUATION.md "Accuracy"): a rollout
//! of the runtime through the scene's frames, scored per frame with the physics objective's
//! evaluation form, and optionally compared with the converged implicit step (the relative
//! objective gap).
//!
//! * [`Animation`]: what a rollout plays (garment, body frames, pinned targets, initial state);
//!   implemented by [`Scene`] and by the owned, editable [`Playback`].
//! * [`rollout`](fn@rollout) / [`rollout_observed`]: step a [`Sim`] through the frames; every frame gives a
//!   [`FrameRecord`] (objective terms, % penetrating vertices, largest edge strain and speed,
//!   step time, optionally the [`Gap`] and the % of vertices inside the body); the [`Rollout`]
//!   keeps chosen frames' positions and a [`Summary`].
//! * [`strip_images`]: preview images of kept frames (write them with `io::png::write_strip`).
//! * [`SplitSummary`]: many rollouts' figures reduced to a model card's lines, over every rollout
//!   and over those that kept the garment on.
//!
//! Scoring (one place for each piece of math): the terms are those of
//! [`ImplicitStep::evaluate`], the same function the optimum is measured with, so that model,
//! coasting guess and optimum are compared under identical rules; penetration uses
//! [`plane_distances`] and [`PENETRATION_DEPTH`]; strain [`max_edge_strain`]; "inside the body"
//! the body's winding number ([`Winding`]).
//!
//! Frames: frame 0 is the initial state; record `t ≥ 1` is the step from frame `t - 1` to `t`,
//! with the body at `t - 1` (current) and `t` (next). Units: metres, seconds; speeds in m/s.
//!
//! [`Scene`]: crate::scene::Scene
//! [`Sim`]: crate::sim::Sim
//! [`ImplicitStep::evaluate`]: crate::solve::ImplicitStep::evaluate
//! [`plane_distances`]: crate::physics::plane_distances
//! [`PENETRATION_DEPTH`]: crate::physics::PENETRATION_DEPTH
//! [`max_edge_strain`]: crate::physics::max_edge_strain
//! [`Winding`]: crate::body::Winding

use crate::error::{Error, Result};
use crate::math::finite_bounds;
use crate::physics::{Objective, Terms};
use crate::render::{Camera, Image, Style};
use crate::solve::LbfgsParams;
use alloc::vec::Vec;

mod animation;
mod common;
mod off_body;
mod rollout;
mod scoring;
mod split;
mod summary;
pub use animation::{Animation, Playback};
pub use common::{common_state_gaps, Method, Reference};
pub use off_body::{
    kept_rule, Loss, LossWatch, OffBody, OffBodyFrame, LOST_PERCENT, OFF_DISTANCE, RIDE_UP_FRAMES, RIDE_UP_SHIFT,
    RIDE_UP_WINDOW, WORN_DISTANCE,
};
pub use rollout::{implicit_rollout, rollout, rollout_observed};
pub use split::{AllAndKept, SplitSummary, PENETRATING_GOAL_PERCENT, STRAIN_GOAL};
pub use summary::{percentile, Summary};

/// What a rollout measures besides the per-frame figures.
///
/// Built from [`Default`] and the `with_` methods (new fields may come, so it has no struct
/// literal outside this crate).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct RolloutOptions {
    /// The objective the frames are scored with (default: [`Objective::evaluation`]); contact
    /// terms are dropped when the animation has no body.
    pub objective: Objective,
    /// Compute the relative objective gap every this many frames (frames `k, 2k, ...`; 0:
    /// never). Each costs one converged implicit step (f64 L-BFGS).
    pub gap_every: usize,
    /// Stopping rules of that implicit step.
    pub gap_solver: LbfgsParams,
    /// Count the garment vertices inside the body (winding number, [`Winding`]) every this many
    /// frames (0: never; no effect without a body).
    ///
    /// [`Winding`]: crate::body::Winding
    pub inside_every: usize,
    /// Frames whose garment positions [`Rollout::kept`] keeps (0: the initial state).
    pub keep: Vec<usize>,
}

impl Default for RolloutOptions {
    fn default() -> Self {
        RolloutOptions {
            objective: Objective::evaluation(),
            gap_every: 0,
            gap_solver: converged_solver(),
            inside_every: 0,
            keep: Vec::new(),
        }
    }
}

impl RolloutOptions {
    with_fields! {
        /// Sets [`objective`](Self::objective): the objective the frames are scored with.
        with_objective => objective: Objective;
        /// Sets [`gap_every`](Self::gap_every): frames between objective gaps (0: never).
        with_gap_every => gap_every: usize;
        /// Sets [`gap_solver`](Self::gap_solver): stopping rules of the gap's implicit step.
        with_gap_solver => gap_solver: LbfgsParams;
        /// Sets [`inside_every`](Self::inside_every): frames between inside counts (0: never).
        with_inside_every => inside_every: usize;
        /// Sets [`keep`](Self::keep): the frames whose garment positions are kept.
        with_keep => keep: Vec<usize>;
    }
}

/// L-BFGS rules for the "converged" implicit step of the gap: tight tolerances, a generous cap.
pub fn converged_solver() -> LbfgsParams {
    LbfgsParams { max_iterations: 1000, grad_tol: 1e-8, rel_decrease_tol: 1e-12, ..LbfgsParams::default() }
}

/// What the runtime did in one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepKind {
    /// A regular network step.
    Stepped,
    /// The start-up step (static body, dt = 1/3 s) followed by the first regular step; the
    /// figures score the regular step, from the state the start-up step left (reconstructed
    /// exactly: the start-up position is `x - v` and its velocity the start-up displacement).
    StartUp,
    /// The body jumped farther than the teleport threshold: the garment was carried rigidly.
    Teleported,
    /// Body and garment at rest: the step was skipped (sleeping).
    Slept,
}

/// The objective gap of one frame (EVALUATION.md "Distance to the optimum"), J.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gap {
    /// Objective at the model's prediction.
    pub model: f64,
    /// Objective at the converged implicit step's optimum.
    pub optimum: f64,
    /// Its terms (their total is `optimum`): with the model's terms (the frame's
    /// [`FrameRecord::terms`]) they split the gap by term, see [`Gap::by_term`].
    pub optimum_terms: Terms<f64>,
    /// Objective at the coasting guess `pos + velocity` (pinned vertices at their targets).
    pub coasting: f64,
    /// `(model - optimum) / (coasting - optimum)`: 0 at the optimum, 1 no better than coasting
    /// (`None` when coasting is already optimal to rounding).
    pub relative: Option<f64>,
    /// L-BFGS iterations of the implicit step.
    pub iterations: usize,
    /// Whether the implicit step met a convergence criterion (else it hit a cap).
    pub converged: bool,
}

impl Gap {
    /// The relative gap split by term: `(model_t - optimum_t) / (coasting - optimum)` for every
    /// term `t`, given the model's terms; they sum to [`Gap::relative`]. A negative part is a
    /// term the model left lower than the optimum does (paid for by the others). `None` where
    /// the relative gap is.
    pub fn by_term(&self, model: &Terms<f64>) -> Option<Terms<f64>> {
        self.relative?;
        let descent = self.coasting - self.optimum;
        let o = &self.optimum_terms;
        Some(Terms {
            stretching: (model.stretching - o.stretching) / descent,
            bending: (model.bending - o.bending) / descent,
            inertia: (model.inertia - o.inertia) / descent,
            gravity: (model.gravity - o.gravity) / descent,
            collision: (model.collision - o.collision) / descent,
            friction: (model.friction - o.friction) / descent,
        })
    }
}

/// The figures of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRecord {
    /// The frame reached (1-based: the step from `frame - 1`).
    pub frame: usize,
    /// What the runtime did.
    pub kind: StepKind,
    /// The objective's terms at the new positions (`None` for teleported or skipped frames,
    /// which are no step).
    pub terms: Option<Terms<f64>>,
    /// Percentage (0-100) of garment vertices closer than [`PENETRATION_DEPTH`] to (or behind)
    /// the plane of their nearest body face (the face nearest at the current frame, its plane at
    /// the next); 0 without a body.
    ///
    /// [`PENETRATION_DEPTH`]: crate::physics::PENETRATION_DEPTH
    pub penetrating_percent: f64,
    /// Largest `|l / L - 1|` over the garment's edges.
    pub max_edge_strain: f64,
    /// The same over the edges at least a quarter of the median edge long at rest
    /// ([`quarter_median_edge_length`]): the fabric's strain, without the sliver edges of a
    /// modelled mesh.
    ///
    /// [`quarter_median_edge_length`]: crate::physics::quarter_median_edge_length
    pub max_long_edge_strain: f64,
    /// Largest vertex speed over the frame, m/s.
    pub max_speed: f64,
    /// Wall time of `Sim::step`, ms.
    pub step_ms: f64,
    /// The objective gap, on the frames [`RolloutOptions::gap_every`] picks.
    pub gap: Option<Gap>,
    /// Percentage (0-100) of garment vertices inside the body at the new frame (winding number
    /// above 1/2), on the frames [`RolloutOptions::inside_every`] picks. Unlike
    /// `penetrating_percent` it counts neither vertices just outside nor vertices behind the
    /// plane of a face they are not under (armpits, crotch).
    pub inside_percent: Option<f64>,
    /// How much of the garment has left the body ([`OffBody`]; `None` without a body).
    pub off_body: Option<OffBodyFrame>,
    /// The step took longer than the time budget of its step mode
    /// ([`StepEffects::over_budget`](crate::sim::StepEffects::over_budget)).
    pub over_budget: bool,
}

/// A scored rollout.
#[derive(Clone, Debug, PartialEq)]
pub struct Rollout {
    /// One record per frame reached.
    pub frames: Vec<FrameRecord>,
    /// `(frame, garment positions)` of the frames [`RolloutOptions::keep`] asked for (and
    /// reached), in frame order.
    pub kept: Vec<(usize, Vec<[f32; 3]>)>,
    /// The frame at which the runtime refused a non-finite output, with its error.
    pub failure: Option<(usize, Error)>,
    /// Aggregates.
    pub summary: Summary,
}

/// Sees every frame's record and the garment's new positions (m) during a rollout.
pub type FrameObserver<'a> = dyn FnMut(&FrameRecord, &[[f32; 3]]) -> Result<()> + 'a;

const BODY_COLOUR: [u8; 3] = [200, 160, 130];
const CLOTH_COLOUR: [u8; 3] = [60, 110, 190];

/// Preview images (`width x height` pixels each) of kept frames: the body (if any) and the
/// garment at each `(frame, positions)`, seen from the front-left, orthographic, framed on the
/// body's (else the garment's) bounding box at that frame, with the floor at its lowest point.
pub fn strip_images(anim: &dyn Animation, kept: &[(usize, Vec<[f32; 3]>)], width: usize, height: usize) -> Vec<Image> {
    let garment = anim.garment();
    kept.iter()
        .map(|(f, pos)| {
            let body = anim.body_mesh().map(|m| (anim.body_frame(*f), m.faces()));
            // Framed on the body: a garment that flew off must not shrink the picture.
            let framed: &[[f32; 3]] = match body {
                Some((b, _)) if !b.is_empty() => b,
                _ => pos,
            };
            let (lo, hi) = finite_bounds(framed);
            let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])];
            let extent = (hi[1] - lo[1]).max(0.6 * (hi[0] - lo[0]).max(hi[2] - lo[2])).max(0.1);
            let cam = Camera::orthographic(centre, [1.0, 0.15, 0.35], 1.15 * extent);
            let mut im = Image::new(width, height, [245, 245, 240]);
            im.draw_floor(&cam, [centre[0], lo[1], centre[2]], 3.0 * extent, lo[1]);
            if let Some((b, faces)) = body {
                im.draw_mesh(&cam, b, faces, Style { colour: BODY_COLOUR });
            }
            im.draw_mesh(&cam, pos, garment.faces(), Style { colour: CLOTH_COLOUR });
            im
        })
        .collect()
}
