//! The implicit step: minimise the objective over the next garment positions.

use super::{Lbfgs, LbfgsParams, LbfgsReport};
use crate::error::{Error, Result};
use crate::exec::par::{split, Disjoint};
use crate::exec::{Executor, Serial};
use crate::math::{add3, Real};
use crate::physics::{check_len, CentroidQuery, Cloth, CollisionInput, FaceFrame, FrictionFrames, FrictionInput};
use crate::physics::{within_friction_radius, Objective, ObjectiveTasks, StepInputs, Terms};
use alloc::vec;
use alloc::vec::Vec;

/// The garment state a step starts from.
#[derive(Clone, Copy, Debug)]
pub struct StepState<'a, T> {
    /// Positions at the current frame, m.
    pub pos: &'a [[T; 3]],
    /// Velocity, m/frame.
    pub velocity: &'a [[T; 3]],
    /// Time step, s.
    pub dt: T,
    /// Pinned flag per vertex (empty: none pinned).
    pub pinned: &'a [bool],
    /// Positions of the pinned vertices at the next frame (one per vertex, only the pinned ones
    /// are read; empty when none is pinned), m.
    pub targets: &'a [[T; 3]],
}

/// The body around one step: its faces at the previous, current and next frame, and a
/// nearest-centroid query over each frame's centroids. The previous frame is only read by the
/// reference form of friction ([`FrictionFrames::PrevCurrent`]).
#[derive(Clone, Copy)]
pub struct StepBody<'a, T> {
    /// Faces at the previous frame.
    pub prev: FaceFrame<'a, T>,
    /// Faces at the current frame.
    pub current: FaceFrame<'a, T>,
    /// Faces at the next frame.
    pub next: FaceFrame<'a, T>,
    /// Nearest centroid at the previous frame.
    pub query_prev: &'a Query,
    /// Nearest centroid at the current frame.
    pub query_current: &'a Query,
    /// Nearest centroid at the next frame.
    pub query_next: &'a Query,
}

/// A nearest-centroid query that tasks may share.
pub type Query = dyn CentroidQuery + Sync;

/// Reusable workspace of the implicit step (L-BFGS buffers, nearest-face indices, the
/// preconditioner).
#[derive(Clone, Debug)]
pub struct ImplicitStep<T: Real> {
    lbfgs: Lbfgs<T>,
    near_cur: Vec<u32>,
    near_a: Vec<u32>,
    near_b: Vec<u32>,
    x32: Vec<[f32; 3]>,
    diag: Vec<T>,
    precondition: bool,
    /// The objective's task buffers, when the workspace was made for one garment
    /// ([`ImplicitStep::with_tasks`]).
    tasks: Option<ObjectiveTasks<T>>,
}

fn to_f32<T: Real>(x: &[[T; 3]], out: &mut [[f32; 3]]) {
    for (o, p) in out.iter_mut().zip(x) {
        *o = p.map(|c| c.to_f64() as f32);
    }
}

impl<T: Real> ImplicitStep<T> {
    /// A workspace for `n` vertices with `memory` L-BFGS correction pairs (10 is a good default).
    pub fn new(n: usize, memory: usize) -> ImplicitStep<T> {
        ImplicitStep {
            lbfgs: Lbfgs::new(n, memory),
            near_cur: vec![0; n],
            near_a: vec![0; n],
            near_b: vec![0; n],
            x32: vec![[0.0; 3]; n],
            diag: vec![T::ZERO; n],
            precondition: true,
            tasks: None,
        }
    }

    /// A workspace for `cloth`'s garment that evaluates the objective as tasks of the executor
    /// [`ImplicitStep::refine_until`] is given ([`ObjectiveTasks`]): the same bits for any number
    /// of threads, within rounding of a workspace from [`ImplicitStep::new`].
    pub fn with_tasks(cloth: &Cloth<T>, memory: usize) -> ImplicitStep<T> {
        ImplicitStep { tasks: Some(ObjectiveTasks::new(cloth)), ..ImplicitStep::new(cloth.n_vertices(), memory) }
    }

    /// Whether L-BFGS is preconditioned with the inverse of `m / dt² + k_stretch` per vertex
    /// (default on; off gives plain L-BFGS, for comparison).
    pub fn set_preconditioning(&mut self, on: bool) {
        self.precondition = on;
    }

    /// Minimises `objective` over the next positions `x` (written, m) starting from the coasting
    /// guess `pos + velocity`, with pinned vertices held at their targets. Collision uses the
    /// face nearest to `pos` at the current frame; friction's nearest face of `x` is refreshed at
    /// every evaluation. Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for buffers of the wrong length; [`Error::Empty`] when a contact
    /// term is enabled without a body; errors of the objective.
    pub fn step(
        &mut self,
        cloth: &Cloth<T>,
        objective: &Objective,
        state: &StepState<'_, T>,
        body: Option<&StepBody<'_, T>>,
        params: &LbfgsParams,
        x: &mut [[T; 3]],
    ) -> Result<LbfgsReport> {
        // Lengths are checked by `refine`.
        for ((xi, p), v) in x.iter_mut().zip(state.pos).zip(state.velocity) {
            *xi = add3(*p, *v);
        }
        self.refine(cloth, objective, state, body, params, x)
    }

    /// As [`ImplicitStep::step`], starting from the positions in `x` (e.g. a model's prediction:
    /// a few iterations from there trade time for accuracy) instead of the coasting guess;
    /// pinned vertices are put at their targets first. Allocates nothing.
    ///
    /// # Errors
    /// As [`ImplicitStep::step`].
    pub fn refine(
        &mut self,
        cloth: &Cloth<T>,
        objective: &Objective,
        state: &StepState<'_, T>,
        body: Option<&StepBody<'_, T>>,
        params: &LbfgsParams,
        x: &mut [[T; 3]],
    ) -> Result<LbfgsReport> {
        self.refine_until(&Serial, cloth, objective, state, body, params, x, &mut || false)
    }

    /// As [`ImplicitStep::refine`], also stopping when `stop()` says so (asked before every
    /// iteration after the first, [`Lbfgs::minimize_until`](crate::solve::Lbfgs::minimize_until)):
    /// the solve of a time budget. The nearest-face searches, and with
    /// [`ImplicitStep::with_tasks`] the objective, run as tasks of `exec`. Allocates nothing.
    ///
    /// # Errors
    /// As [`ImplicitStep::step`].
    #[allow(clippy::too_many_arguments)] // the solve's inputs and its stop rule
    pub fn refine_until(
        &mut self,
        exec: &dyn Executor,
        cloth: &Cloth<T>,
        objective: &Objective,
        state: &StepState<'_, T>,
        body: Option<&StepBody<'_, T>>,
        params: &LbfgsParams,
        x: &mut [[T; 3]],
        stop: &mut dyn FnMut() -> bool,
    ) -> Result<LbfgsReport> {
        let n = cloth.n_vertices();
        check_len("implicit step workspace", self.lbfgs.n_vertices(), n)?;
        check_len("positions", x.len(), n)?;
        check_len("current positions", state.pos.len(), n)?;
        check_len("velocities", state.velocity.len(), n)?;
        let pinned = state.pinned;
        if !pinned.is_empty() {
            check_len("pinned flags", pinned.len(), n)?;
            if pinned.iter().any(|&p| p) {
                check_len("pinned targets", state.targets.len(), n)?;
            }
        }
        if body.is_none() && (objective.collision.is_some() || objective.friction.is_some()) {
            return Err(Error::Empty { what: "body (collision or friction enabled)" });
        }
        for (i, &p) in pinned.iter().enumerate() {
            if p {
                x[i] = state.targets[i];
            }
        }
        let Self { lbfgs, near_cur, near_a, near_b, x32, diag, precondition, tasks } = self;
        if *precondition {
            diag.iter_mut().for_each(|d| *d = T::ZERO);
            cloth.stretch_stiffness_into(diag)?;
            let inv_dt2 = if objective.inertia { T::ONE / (state.dt * state.dt) } else { T::ZERO };
            for (d, &m) in diag.iter_mut().zip(cloth.mass()) {
                *d = T::ONE / (*d + m * inv_dt2);
            }
            lbfgs.set_preconditioner(Some(diag))?;
        } else {
            lbfgs.set_preconditioner(None)?;
        }
        let mut scratch = Contacts { near_cur, near_a, near_b, x32 };
        let friction_b = prepare_contacts(exec, objective, state, body, &mut scratch);
        let next = body.map(|b| b.next);
        let mut eval = Eval { exec, tasks: tasks.as_mut() };
        let f = |y: &[[T; 3]], grad: &mut [[T; 3]]| {
            let t =
                eval_terms(&mut eval, cloth, objective, state, next, friction_b, &mut scratch, y, Some(&mut *grad))?;
            for (g, &p) in grad.iter_mut().zip(pinned) {
                if p {
                    *g = [T::ZERO; 3];
                }
            }
            Ok(t.total())
        };
        lbfgs.minimize_until(x, params, f, stop)
    }

    /// The objective's terms at `x` under the same rules as [`ImplicitStep::step`] (collision
    /// faces nearest to `pos`, friction faces nearest to `x`): the figure to compare a model's
    /// prediction, the coasting guess `pos + velocity` and the step's optimum with (EVALUATION.md
    /// "objective gap"). Allocates nothing.
    ///
    /// # Errors
    /// As [`ImplicitStep::step`].
    pub fn evaluate(
        &mut self,
        cloth: &Cloth<T>,
        objective: &Objective,
        state: &StepState<'_, T>,
        body: Option<&StepBody<'_, T>>,
        x: &[[T; 3]],
    ) -> Result<Terms<T>> {
        let n = cloth.n_vertices();
        check_len("implicit step workspace", self.near_cur.len(), n)?;
        check_len("positions", x.len(), n)?;
        check_len("current positions", state.pos.len(), n)?;
        if body.is_none() && (objective.collision.is_some() || objective.friction.is_some()) {
            return Err(Error::Empty { what: "body (collision or friction enabled)" });
        }
        let Self { near_cur, near_a, near_b, x32, tasks, .. } = self;
        let mut scratch = Contacts { near_cur, near_a, near_b, x32 };
        let friction_b = prepare_contacts(&Serial, objective, state, body, &mut scratch);
        let mut eval = Eval { exec: &Serial, tasks: tasks.as_mut() };
        eval_terms(&mut eval, cloth, objective, state, body.map(|b| b.next), friction_b, &mut scratch, x, None)
    }
}

/// The nearest-face buffers the contact terms read.
struct Contacts<'a> {
    near_cur: &'a mut [u32],
    near_a: &'a mut [u32],
    /// Friction's nearest faces of the last evaluated `x` (at `B_b`); they start as those of
    /// `pos` at `B_a`, the hints of the first search.
    near_b: &'a mut [u32],
    x32: &'a mut [[f32; 3]],
}

/// What friction needs per evaluation: the query at `B_b` and the two frames.
type FrictionFramesOf<'a, T> = (&'a Query, FaceFrame<'a, T>, FaceFrame<'a, T>);

/// How the objective is evaluated: on `exec`, as tasks when the workspace has task buffers.
struct Eval<'a, T: Real> {
    exec: &'a dyn Executor,
    tasks: Option<&'a mut ObjectiveTasks<T>>,
}

/// Nearest centroids of `query` for the points `points[i]` with `search(i)` true, searched from
/// `out[i]` (the last answer) and written there; the others keep theirs. Split into tasks of
/// `exec` by vertex.
fn refresh_nearest(
    exec: &dyn Executor,
    query: &Query,
    points: impl Fn(usize) -> [f32; 3] + Sync,
    search: impl Fn(usize) -> bool + Sync,
    out: &mut [u32],
) {
    let n = out.len();
    let tasks = exec.parallelism().clamp(1, n.max(1));
    let out = Disjoint::new(out);
    exec.run(tasks, &|t| {
        let r = split(n, tasks, t);
        let first = r.start;
        // SAFETY: the tasks' vertex ranges are disjoint.
        let out = unsafe { out.range(r.clone()) };
        for i in r {
            if search(i) {
                out[i - first] = query.nearest_hinted(points(i), out[i - first]);
            }
        }
    });
}

/// Nearest faces of `pos` (collision at the current frame, friction at `B_a`), each search
/// starting from the last call's answers (a step's garment moves little; the answers do not
/// depend on the hints); friction's faces of `x` start as those of `pos`.
fn prepare_contacts<'a, T: Real>(
    exec: &dyn Executor,
    objective: &Objective,
    state: &StepState<'_, T>,
    body: Option<&StepBody<'a, T>>,
    c: &mut Contacts<'_>,
) -> Option<FrictionFramesOf<'a, T>> {
    let b = body?;
    to_f32(state.pos, c.x32);
    let x32 = &*c.x32;
    refresh_nearest(exec, b.query_current, |i| x32[i], |_| true, c.near_cur);
    let fp = objective.friction.as_ref()?;
    let (qa, fa, qb, fb) = match fp.frames {
        FrictionFrames::CurrentNext => (b.query_current, b.current, b.query_next, b.next),
        FrictionFrames::PrevCurrent => (b.query_prev, b.prev, b.query_current, b.current),
    };
    c.near_a.copy_from_slice(c.near_cur);
    if !core::ptr::addr_eq(qa, b.query_current) {
        refresh_nearest(exec, qa, |i| x32[i], |_| true, c.near_a);
    }
    c.near_b.copy_from_slice(c.near_a);
    Some((qb, fa, fb))
}

/// The objective at `y`, refreshing friction's nearest faces of `y` first.
#[allow(clippy::too_many_arguments)]
fn eval_terms<T: Real>(
    eval: &mut Eval<'_, T>,
    cloth: &Cloth<T>,
    objective: &Objective,
    state: &StepState<'_, T>,
    next: Option<FaceFrame<'_, T>>,
    friction_b: Option<FrictionFramesOf<'_, T>>,
    c: &mut Contacts<'_>,
    y: &[[T; 3]],
    grad: Option<&mut [[T; 3]]>,
) -> Result<Terms<T>> {
    let mut inputs =
        StepInputs { pos: state.pos, velocity: state.velocity, dt: state.dt, collision: None, friction: None };
    if let Some(next) = next {
        inputs.collision = Some(CollisionInput { nearest: c.near_cur, next });
    }
    if let (Some((qb, fa, fb)), Some(fp)) = (friction_b, &objective.friction) {
        // Only vertices within the radius at `B_a` can take part: the others' face at `B_b`
        // changes nothing, and keeps its last (valid) value.
        let nf = fa.centroids.len();
        let (pos, near_a) = (state.pos, &*c.near_a);
        let point = |i: usize| y[i].map(|v| v.to_f64() as f32);
        let search = |i: usize| {
            let u = near_a[i] as usize;
            u >= nf || within_friction_radius(pos[i], fa.centroids[u], fp)
        };
        refresh_nearest(eval.exec, qb, point, search, c.near_b);
        inputs.friction = Some(FrictionInput { frame_a: fa, frame_b: fb, nearest_a: c.near_a, nearest_b: c.near_b });
    }
    match eval.tasks.as_deref_mut() {
        Some(tasks) => tasks.eval(eval.exec, objective, cloth, &inputs, y, grad),
        None => objective.eval(cloth, &inputs, y, grad),
    }
}
