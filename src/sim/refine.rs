//! Solver refinement: a few iterations of the implicit step started from the network's
//! prediction, in the step itself. Not part of HOOD (its network alone predicts the step); it
//! trades time for accuracy: the relative objective gap (EVALUATION.md) of a prediction falls
//! with every iteration, at a cost that grows with the garment, not with the model.
//!
//! The objective is the training form of MODEL.md section 6 at the recipe's final collision
//! weight ([`REFINE_COLLISION_WEIGHT`]), in f32, minimised by the preconditioned L-BFGS of
//! [`crate::solve`] over the free vertices; pinned vertices stay at their targets. The refined
//! move is added to the velocity too, so the next step starts from the refined state.

use super::body_query::BodyFaces;
use super::clock::{BudgetUse, Clock, Deadline};
use crate::body::BodyMesh;
use crate::error::{Error, Result};
use crate::exec::Executor;
use crate::mesh::Garment;
use crate::physics::{Cloth, Objective};
use crate::solve::{ImplicitStep, LbfgsParams, LbfgsReport, Query, StepBody, StepState};
use alloc::vec;
use alloc::vec::Vec;

/// A useful default iteration count: it closes most of the gap a trained model leaves (the
/// report's "+ refine" rows), at a few milliseconds for a garment of a thousand vertices.
pub const DEFAULT_REFINE_ITERATIONS: u32 = 10;

/// Most refinement iterations a step may ask for.
pub const MAX_REFINE_ITERATIONS: u32 = 1000;

/// Collision weight of the refinement's objective: the end of the training recipe's ramp
/// (MODEL.md section 7), eps 2 mm.
pub const REFINE_COLLISION_WEIGHT: f64 = 5e5;

/// L-BFGS correction pairs kept (at most the iteration count).
const REFINE_MEMORY: usize = 10;

/// What a refined step starts from, in world coordinates.
pub(super) struct RefineInput<'a> {
    /// Garment positions at the current frame, m.
    pub pos: &'a [[f32; 3]],
    /// Garment velocities as the network saw them, m/frame (relative to the speed limit's
    /// frame of reference when it carries the garment).
    pub velocity: &'a [[f32; 3]],
    /// The speed limit's carry over this step, m (zero: none): the garment coasts by
    /// `velocity + carry` in the world.
    pub carry: [f32; 3],
    /// Time step, s.
    pub dt: f32,
    /// Pinned flag per vertex.
    pub pinned: &'a [bool],
    /// The body, if the scene has one.
    pub body: Option<RefineBody<'a>>,
}

/// The body around a refined step: its faces at the current and the next frame.
#[derive(Clone, Copy)]
pub(super) struct RefineBody<'a> {
    /// At the current frame.
    pub now: BodyFaces<'a>,
    /// At the next frame.
    pub next: BodyFaces<'a>,
}

/// What one refinement reports: the solver's report and, with a time budget, how the step kept it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Solved {
    report: LbfgsReport,
    budget: Option<BudgetUse>,
}

/// Buffers of the refinement, sized once for one garment (and body).
#[derive(Clone, Debug)]
pub(super) struct Refiner {
    cloth: Cloth<f32>,
    objective: Objective,
    solver: ImplicitStep<f32>,
    params: LbfgsParams,
    /// The garment's world-frame velocity (`velocity + carry`).
    coast: Vec<[f32; 3]>,
    /// The network's prediction (pinned vertices at their targets).
    predicted: Vec<[f32; 3]>,
    /// The last refinement's report (a refused step puts back the one before, through
    /// [`solved`](Self::solved) and [`restore_last`](Self::restore_last)).
    last: Option<Solved>,
    /// Wall time of one step, ns (`None`: the iteration count alone ends its refinement).
    budget_ns: Option<u64>,
    /// Clock reading at the start of the current step, with a budget.
    step_start_ns: Option<u64>,
}

impl Refiner {
    /// `iterations` L-BFGS iterations per step for `garment` (its materials), with contact
    /// terms against `mesh` when the scene has a body.
    ///
    /// With `budget_ns`, a refinement also ends before an iteration it predicts would end later
    /// than that much wall time after its step began ([`start_step`](Self::start_step); at
    /// least one iteration runs), by the clock [`apply`](Self::apply) is given.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for 0 or more than [`MAX_REFINE_ITERATIONS`] iterations.
    pub(super) fn new(
        garment: &Garment,
        mesh: Option<&BodyMesh>,
        iterations: u32,
        budget_ns: Option<u64>,
    ) -> Result<Refiner> {
        if !(1..=MAX_REFINE_ITERATIONS).contains(&iterations) {
            return Err(Error::OutOfRange { what: "refinement iterations (1 ..= 1000)", index: iterations as usize });
        }
        let n = garment.n_vertices();
        let objective = match mesh {
            Some(_) => Objective::training(REFINE_COLLISION_WEIGHT),
            None => Objective::cloth_only(),
        };
        let params = LbfgsParams { max_iterations: iterations as usize, ..LbfgsParams::default() };
        let cloth = Cloth::new(garment);
        Ok(Refiner {
            solver: ImplicitStep::with_tasks(&cloth, REFINE_MEMORY.min(iterations as usize)),
            cloth,
            objective,
            params,
            coast: vec![[0.0; 3]; n],
            predicted: vec![[0.0; 3]; n],
            last: None,
            budget_ns,
            step_start_ns: None,
        })
    }

    /// Notes the start of a step on `clock`, from which a time budget counts (the frame's
    /// checks and the body's grids are part of the step's time). Reads no clock without a budget.
    pub(super) fn start_step(&mut self, clock: Option<&dyn Clock>) {
        self.step_start_ns = match (self.budget_ns, clock) {
            (Some(_), Some(c)) => Some(c.now_ns()),
            _ => None,
        };
    }

    /// The last refinement's report (iterations, objective before and after, J).
    pub(super) fn last(&self) -> Option<&LbfgsReport> {
        self.last.as_ref().map(|s| &s.report)
    }

    /// How the last refined step kept its time budget (`None` without one).
    pub(super) fn last_budget(&self) -> Option<BudgetUse> {
        self.last.as_ref().and_then(|s| s.budget)
    }

    /// Refines the prediction `new_pos` (m, world, pinned vertices at their targets) in place and
    /// adds each vertex's move to `new_vel`, in tasks of `exec` (the same bits for any number of
    /// threads); a time budget reads `clock`. Allocates nothing.
    ///
    /// # Errors
    /// Errors of the objective (none for the buffers of [`new`](Self::new));
    /// [`Error::UnsupportedEffect`] for a time budget without a clock. Nothing is written on
    /// error but `new_pos`, which the caller discards. (A non-finite result is refused by the
    /// pass's one check before it commits.)
    pub(super) fn apply(
        &mut self,
        exec: &dyn Executor,
        input: &RefineInput<'_>,
        clock: Option<&dyn Clock>,
        new_pos: &mut [[f32; 3]],
        new_vel: &mut [[f32; 3]],
    ) -> Result<()> {
        let mut deadline = match (self.budget_ns, clock) {
            (None, _) => None,
            (Some(b), Some(c)) => Some(Deadline::new(c, self.step_start_ns, b)),
            (Some(_), None) => {
                return Err(Error::UnsupportedEffect { effect: "solver time budget without a clock (Sim::set_clock)" })
            }
        };
        let c = input.carry;
        for (o, v) in self.coast.iter_mut().zip(input.velocity) {
            *o = [v[0] + c[0], v[1] + c[1], v[2] + c[2]];
        }
        self.predicted.copy_from_slice(new_pos);
        let body = input.body.map(|b| StepBody {
            prev: b.now.frame, // not read: friction uses the current and next frames
            current: b.now.frame,
            next: b.next.frame,
            query_prev: b.now.grid as &Query,
            query_current: b.now.grid,
            query_next: b.next.grid,
        });
        let state = StepState {
            pos: input.pos,
            velocity: &self.coast,
            dt: input.dt,
            pinned: input.pinned,
            targets: &self.predicted,
        };
        let mut stop = || deadline.as_mut().is_some_and(Deadline::stop_before_next);
        let report = self.solver.refine_until(
            exec,
            &self.cloth,
            &self.objective,
            &state,
            body.as_ref(),
            &self.params,
            new_pos,
            &mut stop,
        )?;
        for ((v, x), p) in new_vel.iter_mut().zip(new_pos.iter()).zip(&self.predicted) {
            for k in 0..3 {
                v[k] += x[k] - p[k];
            }
        }
        let budget = match (self.budget_ns, self.step_start_ns, clock) {
            (Some(budget_ns), Some(start), Some(c)) => {
                Some(BudgetUse { budget_ns, used_ns: c.now_ns().saturating_sub(start) })
            }
            _ => None,
        };
        self.last = Some(Solved { report, budget });
        Ok(())
    }

    /// Forgets the last report: no refinement ran in the sim's last step (it slept or
    /// teleported) or no step has run from its state.
    pub(super) fn forget_last(&mut self) {
        self.last = None;
    }

    /// The last refinement, as [`restore_last`](Self::restore_last) takes it.
    pub(super) fn solved(&self) -> Option<Solved> {
        self.last
    }

    /// Puts back the refinement `solved` of the last step that ran (a refused step changed it).
    pub(super) fn restore_last(&mut self, solved: Option<Solved>) {
        self.last = solved;
    }
}
