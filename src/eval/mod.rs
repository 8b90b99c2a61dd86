//! Evaluating a model on an animated scene (EVALUATION.md "Accuracy"): a rollout of the runtime
//! through the scene's frames, scored per frame with the physics objective's evaluation form,
//! and optionally compared with the converged implicit step (the relative objective gap).
//!
//! * [`Animation`]: what a rollout plays (garment, body frames, pinned targets, initial state);
//!   implemented by [`Scene`] and by the owned, editable [`Playback`].
//! * [`rollout`] / [`rollout_observed`]: step a [`Sim`] through the frames; every frame gives a
//!   [`FrameRecord`] (objective terms, % penetrating vertices, largest edge strain and speed,
//!   step time, optionally the [`Gap`] and the % of vertices inside the body); the [`Rollout`]
//!   keeps chosen frames' positions and a [`Summary`].
//! * [`strip_images`]: preview images of kept frames (write them with `io::png::write_strip`).
//!
//! Scoring (one place for each piece of math): the terms are those of
//! [`ImplicitStep::evaluate`], the same function the optimum is measured with, so that model,
//! coasting guess and optimum are compared under identical rules; penetration uses
//! [`plane_distances`] and [`PENETRATION_DEPTH`]; strain [`max_edge_strain`]; "inside the body"
//! the body's winding number ([`Winding`]).
//!
//! Frames: frame 0 is the initial state; record `t ≥ 1` is the step from frame `t - 1` to `t`,
//! with the body at `t - 1` (current) and `t` (next). Units: metres, seconds; speeds in m/s.

use crate::body::{BodyMesh, PointGrid, Winding};
use crate::error::{Error, Result};
use crate::features::DT;
use crate::math::{finite_bounds, norm3, sub3};
use crate::mesh::Garment;
use crate::model::file::Model;
use crate::physics::{face_frames, max_edge_strain, plane_distances, CentroidQuery, Cloth, FaceFrame, Objective};
use crate::physics::{Terms, PENETRATION_DEPTH};
use crate::render::{Camera, Image, Style};
use crate::scene::Scene;
use crate::sim::{BodyDesc, Sim, SimConfig, SimState};
use crate::solve::{ImplicitStep, LbfgsParams, LbfgsReport, Query, StepBody, StepState};
use alloc::vec;
use alloc::vec::Vec;

mod common;
mod off_body;
pub use common::{common_state_gaps, Method, Reference};
pub use off_body::{
    kept_rule, Loss, LossWatch, OffBody, OffBodyFrame, LOST_PERCENT, OFF_DISTANCE, RIDE_UP_FRAMES, RIDE_UP_SHIFT,
    RIDE_UP_WINDOW, WORN_DISTANCE,
};

/// What a rollout plays: a garment, the body's frames (30 Hz), the pinned vertices' targets per
/// frame and the garment's initial positions.
pub trait Animation {
    /// The garment (rest shape, materials, pinned flags).
    fn garment(&self) -> &Garment;
    /// The body's topology, if there is a body.
    fn body_mesh(&self) -> Option<&BodyMesh>;
    /// Number of frames (frame 0 is the initial one).
    fn n_frames(&self) -> usize;
    /// Body positions at frame `f` (m; clamped to the last frame; empty without a body).
    fn body_frame(&self, f: usize) -> &[[f32; 3]];
    /// Targets of the pinned vertices at frame `f` into `out` (one entry per garment vertex, m).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is not one entry per garment vertex.
    fn pin_targets(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()>;
    /// Garment positions at frame 0, m.
    ///
    /// # Errors
    /// Implementation-specific (body queries, ...).
    fn initial_garment(&self) -> Result<Vec<[f32; 3]>>;
    /// Whether [`Animation::pin_targets`] gives every vertex where the body carries it (the
    /// garment skinned with the body), not only fixed targets for the pinned ones: then the
    /// off-body metric measures the garment's shift ([`OffBodyFrame::shift`]). Default: no.
    fn skins_garment(&self) -> bool {
        false
    }
    /// Garment velocities at frame 0, m per frame (the displacement since the frame before):
    /// the motion the body carries the garment with when the animation starts in mid-motion.
    /// Default: at rest.
    ///
    /// # Errors
    /// Implementation-specific (skinning, ...).
    fn initial_velocity(&self) -> Result<Vec<[f32; 3]>> {
        Ok(vec![[0.0; 3]; self.garment().n_vertices()])
    }
}

impl Animation for Scene {
    fn garment(&self) -> &Garment {
        &self.garment
    }
    fn body_mesh(&self) -> Option<&BodyMesh> {
        Some(&self.body)
    }
    fn n_frames(&self) -> usize {
        Scene::n_frames(self)
    }
    fn body_frame(&self, f: usize) -> &[[f32; 3]] {
        Scene::body_frame(self, f)
    }
    fn pin_targets(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()> {
        self.skinned_garment(f, out)
    }
    fn initial_garment(&self) -> Result<Vec<[f32; 3]>> {
        Scene::initial_garment(self, 0)
    }
    fn skins_garment(&self) -> bool {
        true
    }
    fn initial_velocity(&self) -> Result<Vec<[f32; 3]>> {
        Scene::initial_velocity(self, 0)
    }
}

/// An animation held in memory, every part editable (for hard cases: a body that jumps, a bad
/// start state) and buildable from files.
#[derive(Clone, Debug)]
pub struct Playback {
    /// The garment.
    pub garment: Garment,
    /// Body topology (`None`: no body).
    pub body: Option<BodyMesh>,
    /// Body positions per frame, m (ignored without a body; clamped to the last frame).
    pub body_frames: Vec<Vec<[f32; 3]>>,
    /// Targets per frame, one per garment vertex, m (clamped to the last): where the body
    /// carries each vertex, which the pinned ones follow and the off-body metric measures drift
    /// and shift from ([`Animation::skins_garment`]). Empty: the initial positions, held (no
    /// shift is measured).
    pub pin_targets: Vec<Vec<[f32; 3]>>,
    /// Garment positions at frame 0, m.
    pub initial: Vec<[f32; 3]>,
    /// Garment velocities at frame 0, m per frame (empty: at rest).
    pub initial_velocity: Vec<[f32; 3]>,
    /// Number of frames.
    pub frames: usize,
}

impl Playback {
    /// The first `frames` frames of `anim` (clamped to its length), copied.
    ///
    /// # Errors
    /// Errors of `anim`.
    pub fn record(anim: &dyn Animation, frames: usize) -> Result<Playback> {
        let frames = frames.min(anim.n_frames()).max(1);
        let n = anim.garment().n_vertices();
        let mut pin_targets = Vec::with_capacity(frames);
        for f in 0..frames {
            let mut t = vec![[0.0; 3]; n];
            anim.pin_targets(f, &mut t)?;
            pin_targets.push(t);
        }
        let body_frames = match anim.body_mesh() {
            Some(_) => (0..frames).map(|f| anim.body_frame(f).to_vec()).collect(),
            None => Vec::new(),
        };
        Ok(Playback {
            garment: anim.garment().clone(),
            body: anim.body_mesh().cloned(),
            body_frames,
            pin_targets,
            initial: anim.initial_garment()?,
            initial_velocity: anim.initial_velocity()?,
            frames,
        })
    }

    /// A garment without a body starting at its rest shape, pinned vertices held in place,
    /// for `frames` frames.
    pub fn cloth_only(garment: Garment, frames: usize) -> Playback {
        let initial = garment.rest().to_vec();
        Playback {
            garment,
            body: None,
            body_frames: Vec::new(),
            pin_targets: Vec::new(),
            initial,
            initial_velocity: Vec::new(),
            frames,
        }
    }
}

impl Animation for Playback {
    fn garment(&self) -> &Garment {
        &self.garment
    }
    fn body_mesh(&self) -> Option<&BodyMesh> {
        self.body.as_ref()
    }
    fn n_frames(&self) -> usize {
        self.frames
    }
    fn body_frame(&self, f: usize) -> &[[f32; 3]] {
        match (&self.body, self.body_frames.len()) {
            (Some(_), k) if k > 0 => &self.body_frames[f.min(k - 1)],
            _ => &[],
        }
    }
    fn pin_targets(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()> {
        let src = match self.pin_targets.len() {
            0 => &self.initial,
            k => &self.pin_targets[f.min(k - 1)],
        };
        if out.len() != src.len() {
            return Err(Error::SizeMismatch { what: "pin targets", expected: src.len(), got: out.len() });
        }
        out.copy_from_slice(src);
        Ok(())
    }
    fn initial_garment(&self) -> Result<Vec<[f32; 3]>> {
        Ok(self.initial.clone())
    }
    fn skins_garment(&self) -> bool {
        !self.pin_targets.is_empty()
    }
    fn initial_velocity(&self) -> Result<Vec<[f32; 3]>> {
        match self.initial_velocity.len() {
            0 => Ok(vec![[0.0; 3]; self.garment.n_vertices()]),
            k if k == self.garment.n_vertices() => Ok(self.initial_velocity.clone()),
            k => Err(Error::SizeMismatch { what: "initial velocity", expected: self.garment.n_vertices(), got: k }),
        }
    }
}

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
    pub penetrating_percent: f64,
    /// Largest `|l / L - 1|` over the garment's edges.
    pub max_edge_strain: f64,
    /// Largest vertex speed over the frame, m/s.
    pub max_speed: f64,
    /// Wall time of `Sim::step`, ms (0 without the `std` feature).
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
}

/// Aggregates over a rollout's frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Summary {
    /// Frames recorded.
    pub frames: usize,
    /// Whether every step's output was finite (the runtime refuses non-finite output; the
    /// rollout stops at the first refusal).
    pub finite: bool,
    /// Mean of every term over the frames that have them.
    pub mean_terms: Terms<f64>,
    /// Mean of the total objective over the same frames.
    pub mean_total: f64,
    /// Mean % penetrating vertices.
    pub mean_penetrating_percent: f64,
    /// Largest % penetrating vertices.
    pub max_penetrating_percent: f64,
    /// Largest edge strain of any frame.
    pub max_edge_strain: f64,
    /// Largest vertex speed of any frame but teleports (which are no motion), m/s.
    pub max_speed: f64,
    /// Mean relative gap over the frames where it was computed and defined.
    pub gap_mean: Option<f64>,
    /// 95th percentile (nearest rank) of the same.
    pub gap_p95: Option<f64>,
    /// Mean absolute gap `model - optimum` (J) over the same frames: unlike the relative gap it
    /// does not depend on the descent available at the rollout's own states (a calmer rollout
    /// has less, which raises its relative gap at an equal absolute one).
    pub gap_abs_mean: Option<f64>,
    /// The mean relative gap split by term ([`Gap::by_term`] averaged over the same frames; the
    /// parts sum to `gap_mean`).
    pub gap_by_term: Option<Terms<f64>>,
    /// How many frames the gap figures average.
    pub gap_frames: usize,
    /// Mean % of vertices inside the body over the frames where it was counted.
    pub inside_mean: Option<f64>,
    /// Largest of the same.
    pub inside_max: Option<f64>,
    /// How many frames the inside figures cover.
    pub inside_frames: usize,
    /// Mean step time, ms.
    pub mean_step_ms: f64,
    /// Median step time, ms.
    pub median_step_ms: f64,
    /// Largest % of worn vertices off the body over the frames ([`OffBody`]; `None` without a
    /// body).
    pub off_body_max: Option<f64>,
    /// Mean of the same.
    pub off_body_mean: Option<f64>,
    /// The first frame at which the garment was lost, and how ([`LossWatch`]: off the body, or
    /// ridden up): a failure whatever the other figures.
    pub lost: Option<(usize, Loss)>,
    /// Largest drift of a vertex from its skinned position over the frames, m (garments with
    /// pins).
    pub max_drift: Option<f64>,
    /// Largest shift of the worn vertices' centroid from its skinned position over the frames,
    /// m ([`OffBodyFrame::shift`]): a top riding up while it stays within 10 cm of the body.
    pub max_shift: Option<f64>,
}

impl Summary {
    /// Whether the garment stayed on the body (and the rollout finite): not lost at any frame
    /// ([`LossWatch`]).
    pub fn garment_kept(&self) -> bool {
        self.finite && self.lost.is_none()
    }

    /// The off-body verdict in words: `garment on the body (worn vertices off: max 0.4 %, mean
    /// 0.1 %; drift max 4.2 cm)` or `garment LOST from frame 140, off the body (...)`; `None` without a body.
    pub fn off_body_text(&self) -> Option<alloc::string::String> {
        let (max, mean) = (self.off_body_max?, self.off_body_mean?);
        let verdict = match self.lost {
            Some((f, why)) => alloc::format!("garment LOST from frame {f}, {}", why.describe()),
            None => "garment on the body".into(),
        };
        let mut drift =
            self.max_drift.map_or(alloc::string::String::new(), |d| alloc::format!("; drift max {:.1} cm", 100.0 * d));
        if let Some(d) = self.max_shift {
            drift.push_str(&alloc::format!("; shift max {:.1} cm", 100.0 * d));
        }
        Some(alloc::format!("{verdict} (worn vertices over 10 cm off: max {max:.1} %, mean {mean:.1} %{drift})"))
    }
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

/// One body frame's faces: f64 centroids and normals for the terms, a grid over the (f32)
/// centroids for the nearest-face queries.
struct BodySlot {
    frame: usize,
    centroids: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    centroids32: Vec<[f32; 3]>,
    grid: PointGrid,
}

/// The body at the frames a step reads (previous, current, next), each computed once.
struct BodyRing {
    faces: Vec<[u32; 3]>,
    slots: [BodySlot; 3],
}

impl BodyRing {
    fn new(mesh: &BodyMesh) -> Result<BodyRing> {
        let nf = mesh.n_faces();
        let slot = || -> Result<BodySlot> {
            Ok(BodySlot {
                frame: usize::MAX,
                centroids: vec![[0.0; 3]; nf],
                normals: vec![[0.0; 3]; nf],
                centroids32: vec![[0.0; 3]; nf],
                grid: PointGrid::new(nf.max(1), (8 * nf).max(64))?,
            })
        };
        Ok(BodyRing { faces: mesh.faces().to_vec(), slots: [slot()?, slot()?, slot()?] })
    }

    /// The slot holding frame `f` of `anim`, computing it over a slot not in `keep`.
    fn ensure(&mut self, anim: &dyn Animation, f: usize, keep: &[usize]) -> Result<usize> {
        if let Some(i) = self.slots.iter().position(|s| s.frame == f) {
            return Ok(i);
        }
        let i = self.slots.iter().position(|s| !keep.contains(&s.frame)).unwrap_or(0);
        let s = &mut self.slots[i];
        s.frame = usize::MAX;
        face_frames(anim.body_frame(f), &self.faces, &mut s.centroids, &mut s.normals)?;
        for (c32, c) in s.centroids32.iter_mut().zip(&s.centroids) {
            *c32 = c.map(|v| v as f32);
        }
        s.grid.rebuild(&s.centroids32)?;
        s.frame = f;
        Ok(i)
    }

    fn face_frame(&self, i: usize) -> FaceFrame<'_, f64> {
        FaceFrame { centroids: &self.slots[i].centroids, normals: &self.slots[i].normals }
    }
}

/// Scores steps of one garment: the f64 cloth constants, the implicit step's workspace and the
/// step's state in f64.
struct Scorer {
    cloth: Cloth<f64>,
    objective: Objective,
    solver: ImplicitStep<f64>,
    ring: Option<BodyRing>,
    pinned: Vec<bool>,
    pos: Vec<[f64; 3]>,
    vel: Vec<[f64; 3]>,
    targets: Vec<[f64; 3]>,
    x: Vec<[f64; 3]>,
    x_star: Vec<[f64; 3]>,
    pos32: Vec<[f32; 3]>,
    near: Vec<u32>,
    dist: Vec<f64>,
}

impl Scorer {
    fn new(anim: &dyn Animation, objective: &Objective) -> Result<Scorer> {
        let g = anim.garment();
        let n = g.n_vertices();
        let mut objective = *objective;
        let ring = match anim.body_mesh() {
            Some(m) => Some(BodyRing::new(m)?),
            None => {
                objective.collision = None;
                objective.friction = None;
                None
            }
        };
        let z = vec![[0.0f64; 3]; n];
        Ok(Scorer {
            cloth: Cloth::new(g),
            objective,
            solver: ImplicitStep::new(n, 10),
            ring,
            pinned: g.pinned().to_vec(),
            pos: z.clone(),
            vel: z.clone(),
            targets: z.clone(),
            x: z.clone(),
            x_star: z,
            pos32: vec![[0.0; 3]; n],
            near: vec![0; n],
            dist: vec![0.0; n],
        })
    }

    /// Loads the step's start state: `before` as the runtime saw it (pinned vertices at their
    /// targets with zero velocity), or, after the start-up step, the state it left.
    fn load(&mut self, kind: StepKind, before: &SimState, targets: &[[f32; 3]], x: &[[f32; 3]], v: &[[f32; 3]]) {
        self.load_parts(kind, &before.pos, &before.velocity, targets, x, v);
    }

    /// [`Scorer::load`] from the state's positions and velocities.
    fn load_parts(
        &mut self,
        kind: StepKind,
        before_pos: &[[f32; 3]],
        before_vel: &[[f32; 3]],
        targets: &[[f32; 3]],
        x: &[[f32; 3]],
        v: &[[f32; 3]],
    ) {
        let to64 = |p: [f32; 3]| p.map(|c| c as f64);
        for i in 0..self.pos.len() {
            self.targets[i] = to64(targets[i]);
            self.x[i] = to64(x[i]);
            if self.pinned[i] {
                self.pos[i] = self.targets[i];
                self.vel[i] = [0.0; 3];
            } else if kind == StepKind::StartUp {
                // x = p + v_s + a and v = v_s + a, so the start-up left p = x - v, v_s = p - p0.
                self.pos[i] = sub3(self.x[i], to64(v[i]));
                self.vel[i] = sub3(self.pos[i], to64(before_pos[i]));
            } else {
                self.pos[i] = to64(before_pos[i]);
                self.vel[i] = to64(before_vel[i]);
            }
        }
    }

    /// The record of the loaded and scored step (strain and speed of the prediction).
    fn record(
        &self,
        frame: usize,
        kind: StepKind,
        terms: Option<Terms<f64>>,
        penetrating_percent: f64,
        step_ms: f64,
        gap: Option<Gap>,
    ) -> FrameRecord {
        let max_speed =
            self.x.iter().zip(&self.pos).map(|(a, b)| norm3(sub3(*a, *b))).fold(0.0f64, f64::max) / DT as f64;
        FrameRecord {
            frame,
            kind,
            terms,
            penetrating_percent,
            max_edge_strain: max_edge_strain(&self.cloth, &self.x),
            max_speed,
            step_ms,
            gap,
            inside_percent: None,
            off_body: None,
        }
    }

    /// The ring slots of body frames `[previous, current, next]` (`None` without a body).
    fn body_slots(&mut self, anim: &dyn Animation, frames: [usize; 3]) -> Result<Option<[usize; 3]>> {
        let [fp, fc, fnx] = frames;
        let Some(ring) = &mut self.ring else { return Ok(None) };
        let c = ring.ensure(anim, fc, &[fc])?;
        let nx = ring.ensure(anim, fnx, &[fc, fnx])?;
        let p = ring.ensure(anim, fp, &[fc, fnx, fp])?;
        Ok(Some([p, c, nx]))
    }

    /// The implicit step (L-BFGS under `params`, from the coasting guess) of the loaded state
    /// into `x`: the implicit solver as a simulator.
    fn implicit(&mut self, anim: &dyn Animation, frames: [usize; 3], params: &LbfgsParams) -> Result<LbfgsReport> {
        let idx = self.body_slots(anim, frames)?;
        let body = step_body(self.ring.as_ref(), idx);
        let state = StepState {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            pinned: &self.pinned,
            targets: &self.targets,
        };
        self.solver.step(&self.cloth, &self.objective, &state, body.as_ref(), params, &mut self.x)
    }

    /// Scores the loaded step: terms, penetration, strain, speed and (if asked) the gap.
    fn score(
        &mut self,
        anim: &dyn Animation,
        frames: [usize; 3],
        with_terms: bool,
        gap: Option<&LbfgsParams>,
    ) -> Result<(Option<Terms<f64>>, f64, Option<Gap>)> {
        let idx = self.body_slots(anim, frames)?;
        let mut penetrating = 0.0;
        if let (Some(ring), Some([_, c, nx])) = (&self.ring, idx) {
            for (o, p) in self.pos32.iter_mut().zip(&self.pos) {
                *o = p.map(|c| c as f32);
            }
            ring.slots[c].grid.nearest_into(&self.pos32, &mut self.near);
            plane_distances(&self.x, &self.near, ring.face_frame(nx), &mut self.dist);
            let count = self.dist.iter().filter(|&&d| d < PENETRATION_DEPTH).count();
            penetrating = 100.0 * count as f64 / self.dist.len().max(1) as f64;
        }
        if !with_terms {
            return Ok((None, penetrating, None));
        }
        let body = step_body(self.ring.as_ref(), idx);
        let state = StepState {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            pinned: &self.pinned,
            targets: &self.targets,
        };
        let terms = self.solver.evaluate(&self.cloth, &self.objective, &state, body.as_ref(), &self.x)?;
        let gap = match gap {
            Some(params) => Some(self.optimum(anim, frames, params)?.gap(terms.total())),
            None => None,
        };
        Ok((Some(terms), penetrating, gap))
    }

    /// The converged implicit step of the loaded state (L-BFGS under `params` on the scoring
    /// objective, from the coasting guess) into `x_star`, with its terms.
    fn optimum(&mut self, anim: &dyn Animation, frames: [usize; 3], params: &LbfgsParams) -> Result<Optimum> {
        let idx = self.body_slots(anim, frames)?;
        let body = step_body(self.ring.as_ref(), idx);
        let state = StepState {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            pinned: &self.pinned,
            targets: &self.targets,
        };
        let r = self.solver.step(&self.cloth, &self.objective, &state, body.as_ref(), params, &mut self.x_star)?;
        let terms = self.solver.evaluate(&self.cloth, &self.objective, &state, body.as_ref(), &self.x_star)?;
        Ok(Optimum { report: r, terms })
    }
}

/// The converged implicit step of one state: what a step's objective is compared with.
struct Optimum {
    report: LbfgsReport,
    /// Terms at the optimum (their total is `report.f`).
    terms: Terms<f64>,
}

impl Optimum {
    /// The gap of a step whose objective is `model` (J), from the same state.
    fn gap(&self, model: f64) -> Gap {
        let r = &self.report;
        let descent = r.f_start - r.f;
        let relative = (descent > 1e-12 * r.f_start.abs().max(1e-3)).then(|| (model - r.f) / descent);
        Gap {
            model,
            optimum: r.f,
            optimum_terms: self.terms,
            coasting: r.f_start,
            relative,
            iterations: r.iterations,
            converged: r.converged(),
        }
    }
}

/// Counts the garment vertices inside the body on the frames [`RolloutOptions::inside_every`]
/// picks.
struct InsideCounter {
    winding: Winding,
    every: usize,
}

impl InsideCounter {
    /// `None` when the option is off or there is no body.
    fn new(anim: &dyn Animation, every: usize) -> Result<Option<InsideCounter>> {
        match anim.body_mesh() {
            Some(mesh) if every > 0 => {
                Ok(Some(InsideCounter { winding: Winding::new(mesh, anim.body_frame(0))?, every }))
            }
            _ => Ok(None),
        }
    }

    /// % of `garment` (m) inside the body at frame `t`, if `t` is one of the picked frames.
    fn count(this: &mut Option<Self>, anim: &dyn Animation, t: usize, garment: &[[f32; 3]]) -> Result<Option<f64>> {
        let (Some(c), Some(mesh)) = (this, anim.body_mesh()) else { return Ok(None) };
        if !t.is_multiple_of(c.every) {
            return Ok(None);
        }
        c.winding.refit(mesh, anim.body_frame(t))?;
        Ok(Some(100.0 * c.winding.count_inside(garment) as f64 / garment.len().max(1) as f64))
    }
}

/// Sees every frame's record and the garment's new positions (m) during a rollout.
pub type FrameObserver<'a> = dyn FnMut(&FrameRecord, &[[f32; 3]]) -> Result<()> + 'a;

/// The body of a step from the ring slots `[previous, current, next]`.
fn step_body(ring: Option<&BodyRing>, idx: Option<[usize; 3]>) -> Option<StepBody<'_, f64>> {
    let (ring, [p, c, nx]) = (ring?, idx?);
    Some(StepBody {
        prev: ring.face_frame(p),
        current: ring.face_frame(c),
        next: ring.face_frame(nx),
        query_prev: &ring.slots[p].grid as &Query,
        query_current: &ring.slots[c].grid,
        query_next: &ring.slots[nx].grid,
    })
}

/// What the runtime did in a step from `before` to `after` toward the body frame `body_next`
/// (`sim_body`: whether the Sim has a body).
fn step_kind(sim_body: bool, before: &SimState, after: &SimState, body_next: &[[f32; 3]]) -> StepKind {
    if sim_body && after.body_pos != body_next {
        StepKind::Slept
    } else if sim_body && before.body_pos != body_next && after.body_prev == body_next {
        StepKind::Teleported
    } else if !sim_body && after.pos == before.pos && after.velocity == before.velocity {
        StepKind::Slept
    } else if !before.started && after.started {
        StepKind::StartUp
    } else {
        StepKind::Stepped
    }
}

/// An implicit step's output `x` (f64, m) into `out` (f32), refusing a non-finite position.
fn store(x: &[[f64; 3]], out: &mut [[f32; 3]]) -> Result<()> {
    for (i, (o, p)) in out.iter_mut().zip(x).enumerate() {
        *o = p.map(|c| c as f32);
        if !o.iter().all(|c| c.is_finite()) {
            return Err(Error::NonFinite { what: "implicit step output for garment vertex", index: i });
        }
    }
    Ok(())
}

/// Moves a solver-driven garment to its new positions `next` (m): velocities become the
/// displacement over the frame, zero for pinned vertices.
fn advance(pinned: &[bool], next: &[[f32; 3]], pos: &mut [[f32; 3]], vel: &mut [[f32; 3]]) {
    for (i, (p, v)) in pos.iter_mut().zip(vel.iter_mut()).enumerate() {
        *v = if pinned[i] { [0.0; 3] } else { sub3(next[i], *p) };
        *p = next[i];
    }
}

/// Refuses a rollout of no frames or past the animation's last frame.
fn check_frames(anim: &dyn Animation, frames: usize) -> Result<()> {
    if frames == 0 {
        return Err(Error::Empty { what: "rollout frames" });
    }
    if frames >= anim.n_frames() {
        return Err(Error::OutOfRange { what: "rollout frames (past the animation's last frame)", index: frames });
    }
    Ok(())
}

/// [`rollout_observed`] without an observer.
///
/// # Errors
/// As [`rollout_observed`].
pub fn rollout(
    model: &Model<'_>,
    anim: &dyn Animation,
    frames: usize,
    cfg: SimConfig,
    options: &RolloutOptions,
) -> Result<Rollout> {
    rollout_observed(model, anim, frames, cfg, options, &mut |_, _| Ok(()))
}

/// Steps a [`Sim`] of `model` through frames `1..=frames` of `anim` (starting from
/// [`Animation::initial_garment`] at rest, the start-up step being the Sim's job), setting the
/// pinned targets of every frame, and scores every frame. `observer` sees each record with the
/// garment's new positions (for writing files, progress); an error from it stops the rollout and
/// is returned. A refused non-finite network output ends the rollout early
/// ([`Rollout::failure`]); it is not an error.
///
/// # Errors
/// [`Error::Empty`] for `frames == 0`; [`Error::OutOfRange`] when `frames` is past the
/// animation's last frame; errors of [`Sim::new`] (an effect the model lacks, ...), of the
/// animation and of the scoring; runtime errors other than a non-finite output.
pub fn rollout_observed(
    model: &Model<'_>,
    anim: &dyn Animation,
    frames: usize,
    cfg: SimConfig,
    options: &RolloutOptions,
    observer: &mut FrameObserver<'_>,
) -> Result<Rollout> {
    check_frames(anim, frames)?;
    let garment = anim.garment();
    let n = garment.n_vertices();
    let b0 = anim.body_frame(0);
    let body = anim.body_mesh().map(|mesh| BodyDesc { mesh, positions: b0 });
    let mut sim = Sim::new(model, garment, body, cfg)?;
    let sim_body = !sim.state().body_pos.is_empty();
    let body_state = if sim_body { b0.to_vec() } else { Vec::new() };
    sim.set_state(&SimState {
        pos: anim.initial_garment()?,
        velocity: anim.initial_velocity()?,
        body_prev: body_state.clone(),
        body_pos: body_state,
        started: sim.state().started,
    })?;
    let mut scorer = Scorer::new(anim, &options.objective)?;
    let mut inside = InsideCounter::new(anim, options.inside_every)?;
    let mut off_body = OffBody::new(anim)?;
    let mut out =
        Rollout { frames: Vec::with_capacity(frames), kept: Vec::new(), failure: None, summary: Summary::default() };
    if options.keep.contains(&0) {
        out.kept.push((0, sim.positions().to_vec()));
    }
    let mut targets = vec![[0.0f32; 3]; n];
    for t in 1..=frames {
        let before = sim.state().clone();
        anim.pin_targets(t, &mut targets)?;
        sim.set_pin_targets(&targets)?;
        let body_next = anim.body_frame(t);
        #[cfg(feature = "std")]
        let clock = std::time::Instant::now();
        match sim.step(body_next) {
            Ok(_) => {}
            Err(e @ Error::NonFinite { what, .. }) if what.starts_with("network output") => {
                out.failure = Some((t, e));
                break;
            }
            Err(e) => return Err(e),
        }
        #[cfg(feature = "std")]
        let step_ms = clock.elapsed().as_secs_f64() * 1e3;
        #[cfg(not(feature = "std"))]
        let step_ms = 0.0;
        let after = sim.state();
        let kind = step_kind(sim_body, &before, after, body_next);
        scorer.load(kind, &before, &targets, &after.pos, &after.velocity);
        let stepped = matches!(kind, StepKind::Stepped | StepKind::StartUp);
        let body_frames = if kind == StepKind::StartUp { [t - 1, t - 1, t] } else { [t.saturating_sub(2), t - 1, t] };
        let want_gap = stepped && options.gap_every > 0 && t % options.gap_every == 0;
        let (terms, penetrating_percent, gap) =
            scorer.score(anim, body_frames, stepped, want_gap.then_some(&options.gap_solver))?;
        let mut rec = scorer.record(t, kind, terms, penetrating_percent, step_ms, gap);
        rec.inside_percent = InsideCounter::count(&mut inside, anim, t, &after.pos)?;
        rec.off_body = off_body.as_mut().map(|o| o.measure(anim, t, &after.pos)).transpose()?;
        if options.keep.contains(&t) {
            out.kept.push((t, after.pos.clone()));
        }
        observer(&rec, &after.pos)?;
        out.frames.push(rec);
    }
    out.summary = summarise(&out.frames, out.failure.is_none());
    Ok(out)
}

/// The implicit solver as the simulator, for comparison with models (EVALUATION.md "Accuracy
/// against time"): from [`Animation::initial_garment`] moving at [`Animation::initial_velocity`], every frame is one
/// [`ImplicitStep`] (f64 L-BFGS under `solver`, e.g. a few iterations) on `options.objective`,
/// pinned vertices at their targets; no start-up step. Records, gap and summary as in
/// [`rollout_observed`] (`step_ms` is the solve's wall time); a non-finite solve ends the rollout
/// ([`Rollout::failure`]).
///
/// # Errors
/// As [`rollout_observed`] (without the runtime's).
pub fn implicit_rollout(
    anim: &dyn Animation,
    frames: usize,
    solver: &LbfgsParams,
    options: &RolloutOptions,
    observer: &mut FrameObserver<'_>,
) -> Result<Rollout> {
    check_frames(anim, frames)?;
    let n = anim.garment().n_vertices();
    let pinned = anim.garment().pinned().to_vec();
    let mut scorer = Scorer::new(anim, &options.objective)?;
    let mut inside = InsideCounter::new(anim, options.inside_every)?;
    let mut off_body = OffBody::new(anim)?;
    let mut pos = anim.initial_garment()?;
    let mut vel = anim.initial_velocity()?;
    let mut targets = vec![[0.0f32; 3]; n];
    let mut next = vec![[0.0f32; 3]; n];
    let mut out =
        Rollout { frames: Vec::with_capacity(frames), kept: Vec::new(), failure: None, summary: Summary::default() };
    if options.keep.contains(&0) {
        out.kept.push((0, pos.clone()));
    }
    for t in 1..=frames {
        anim.pin_targets(t, &mut targets)?;
        scorer.load_parts(StepKind::Stepped, &pos, &vel, &targets, &pos, &vel);
        let body_frames = [t.saturating_sub(2), t - 1, t];
        #[cfg(feature = "std")]
        let clock = std::time::Instant::now();
        scorer.implicit(anim, body_frames, solver)?;
        #[cfg(feature = "std")]
        let step_ms = clock.elapsed().as_secs_f64() * 1e3;
        #[cfg(not(feature = "std"))]
        let step_ms = 0.0;
        if let Err(e) = store(&scorer.x, &mut next) {
            out.failure = Some((t, e));
            break;
        }
        let want_gap = options.gap_every > 0 && t % options.gap_every == 0;
        let (terms, penetrating_percent, gap) =
            scorer.score(anim, body_frames, true, want_gap.then_some(&options.gap_solver))?;
        let mut rec = scorer.record(t, StepKind::Stepped, terms, penetrating_percent, step_ms, gap);
        advance(&pinned, &next, &mut pos, &mut vel);
        rec.inside_percent = InsideCounter::count(&mut inside, anim, t, &pos)?;
        rec.off_body = off_body.as_mut().map(|o| o.measure(anim, t, &pos)).transpose()?;
        if options.keep.contains(&t) {
            out.kept.push((t, pos.clone()));
        }
        observer(&rec, &pos)?;
        out.frames.push(rec);
    }
    out.summary = summarise(&out.frames, out.failure.is_none());
    Ok(out)
}

fn summarise(frames: &[FrameRecord], finite: bool) -> Summary {
    let mut s = Summary { frames: frames.len(), finite, ..Summary::default() };
    let scored: Vec<Terms<f64>> = frames.iter().filter_map(|f| f.terms).collect();
    s.mean_terms = mean_terms(&scored);
    s.mean_total = scored.iter().map(|t| t.total() / scored.len() as f64).sum();
    let nf = frames.len().max(1) as f64;
    for f in frames {
        s.mean_penetrating_percent += f.penetrating_percent / nf;
        s.max_penetrating_percent = s.max_penetrating_percent.max(f.penetrating_percent);
        s.max_edge_strain = s.max_edge_strain.max(f.max_edge_strain);
        if f.kind != StepKind::Teleported {
            s.max_speed = s.max_speed.max(f.max_speed);
        }
        s.mean_step_ms += f.step_ms / nf;
    }
    let mut gaps: Vec<f64> = frames.iter().filter_map(|f| f.gap.and_then(|g| g.relative)).collect();
    s.gap_frames = gaps.len();
    if !gaps.is_empty() {
        s.gap_mean = Some(gaps.iter().sum::<f64>() / gaps.len() as f64);
        let absolute = frames.iter().filter_map(|f| f.gap.and_then(|g| g.relative.map(|_| g.model - g.optimum)));
        s.gap_abs_mean = Some(absolute.sum::<f64>() / gaps.len() as f64);
        s.gap_p95 = Some(percentile(&mut gaps, 0.95));
        let parts: Vec<Terms<f64>> = frames
            .iter()
            .filter_map(|f| f.gap.as_ref().zip(f.terms.as_ref()))
            .filter_map(|(g, t)| g.by_term(t))
            .collect();
        s.gap_by_term = Some(mean_terms(&parts));
    }
    let inside: Vec<f64> = frames.iter().filter_map(|f| f.inside_percent).collect();
    s.inside_frames = inside.len();
    if !inside.is_empty() {
        s.inside_mean = Some(inside.iter().sum::<f64>() / inside.len() as f64);
        s.inside_max = Some(inside.iter().copied().fold(0.0, f64::max));
    }
    let mut ms: Vec<f64> = frames.iter().map(|f| f.step_ms).collect();
    if !ms.is_empty() {
        s.median_step_ms = percentile(&mut ms, 0.5);
    }
    let off: Vec<(usize, OffBodyFrame)> = frames.iter().filter_map(|f| Some((f.frame, f.off_body?))).collect();
    if !off.is_empty() {
        s.off_body_max = Some(off.iter().map(|o| o.1.off_percent).fold(0.0, f64::max));
        s.off_body_mean = Some(off.iter().map(|o| o.1.off_percent).sum::<f64>() / off.len() as f64);
        s.lost = LossWatch::first(off.iter().map(|o| &o.1)).map(|(i, why)| (off[i].0, why));
        s.max_drift = off.iter().filter_map(|o| o.1.max_drift).reduce(f64::max);
        s.max_shift = off.iter().filter_map(|o| o.1.shift).reduce(f64::max);
    }
    s
}

/// The mean of every term (zero for none).
fn mean_terms(terms: &[Terms<f64>]) -> Terms<f64> {
    let k = terms.len().max(1) as f64;
    let mut mean = Terms::<f64>::default();
    for t in terms {
        mean.stretching += t.stretching / k;
        mean.bending += t.bending / k;
        mean.inertia += t.inertia / k;
        mean.gravity += t.gravity / k;
        mean.collision += t.collision / k;
        mean.friction += t.friction / k;
    }
    mean
}

/// Nearest-rank percentile `q` (0-1) of `v` (sorted in place; not empty).
pub fn percentile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let rank = libm::ceil(q * v.len() as f64) as usize;
    v[rank.clamp(1, v.len()) - 1]
}

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
