//! One pass of a step, as a pipeline of stages ([`Sim::advance`]): pins, the prediction (the
//! network's, `predict.rs`, or the solver modes' coasting guess), back to the world frame,
//! refinement, collision projection, body tethers, commit. Each stage writes the pass's next
//! positions (m) and velocities (m/frame) into the sim's `new_pos` / `new_vel`; the state changes
//! only at the commit, so that a refused pass leaves it as it was.

use super::body_query::BodyQuery;
use super::network::Probe;
use super::refine::{RefineBody, RefineInput};
use super::{body_query, BodyState, Sim, SimState, StepMode};
use crate::error::{Error, Result};
use crate::features::DT_STARTUP;
use crate::math::finite3;
use alloc::vec::Vec;

/// One pass of a step: where the body goes and in which frame of reference.
///
/// The pass runs in the speed limit's frame of reference, translated to coincide with the world
/// at the current frame: it moved by `last_carry` over the last step and moves by `carry` over
/// this pass (both zero under the limit). In it the body's previous frame lies at
/// `body_prev + last_carry` and its next at `body_next - carry`; the garment's velocity is
/// already relative to it, and its new positions are moved by `+carry` to return to the world.
#[derive(Clone, Copy)]
pub(super) struct Pass<'a> {
    /// The body at the next frame, m (`None`: no body, or a static one in the start-up pass).
    pub body_next: Option<&'a [[f32; 3]]>,
    /// The speed limit's carry over this pass, m.
    pub carry: [f32; 3],
    /// The speed limit's carry over the last step, m (zero in the start-up pass).
    pub last_carry: [f32; 3],
    /// Time step, s: [`DT`](crate::features::DT), or [`DT_STARTUP`] for the start-up pass.
    pub dt: f32,
}

impl Pass<'_> {
    /// The start-up (relaxation) pass: a static body at dt = 1/3 s.
    pub(super) fn startup(&self) -> bool {
        self.dt == DT_STARTUP
    }

    /// Whether the speed limit's frame moved over the last step or moves over this pass.
    pub(super) fn shifted(&self) -> bool {
        self.carry != [0.0; 3] || self.last_carry != [0.0; 3]
    }
}

impl Sim<'_> {
    /// One pass from the current state to `body_next` (`None`: static body) at time step `dt`
    /// (s), in the speed limit's frame of reference, which moves by `carry` (m) over it (see
    /// [`Pass`]). The stages write into `new_pos` / `new_vel`; the last one commits them.
    pub(super) fn advance(
        &mut self,
        mut query: Option<&mut BodyQuery>,
        body_next: Option<&[[f32; 3]]>,
        carry: [f32; 3],
        dt: f32,
        observer: Option<&mut dyn FnMut(Probe<'_>)>,
    ) -> Result<()> {
        let last_carry = if dt == DT_STARTUP { [0.0; 3] } else { self.last_carry };
        let pass = Pass { body_next, carry, last_carry, dt };
        if let Some(t) = self.body.as_mut().and_then(|b| b.tethers.as_mut()).filter(|t| !t.tied()) {
            // The first pass from a new placement ties the tethers where the garment is now.
            t.tie(&self.state.pos, &self.pinned, &self.state.body_pos)?;
        }
        pin(&self.state.pos, &self.pinned, &self.pin_targets, carry, &mut self.new_pos);
        match self.cfg.step {
            StepMode::Network => self.predict(query.as_deref_mut(), &pass, observer)?,
            StepMode::Solver { .. } | StepMode::SolverBudget { .. } => {
                coast(&self.state, &self.pinned, &mut self.new_pos, &mut self.new_vel)
            }
        }
        to_world(carry, &mut self.new_pos);
        // Not the start-up pass: its optimum at dt = 1/3 s is a relaxation (for cloth without a
        // body, a free fall of a metre), and the velocity it leaves would carry that into the
        // first frame. The network's own start-up prediction is HOOD's.
        if let Some(r) = self.refiner.as_mut().filter(|_| !pass.startup()) {
            // Refinement: L-BFGS on the implicit step's objective, from the guess so far.
            let body = refine_body(
                query.as_deref_mut(),
                &mut self.query,
                self.body.as_ref(),
                &self.state.body_pos,
                body_next,
            )?;
            let (pos, velocity, pinned) = (&self.state.pos[..], &self.state.velocity[..], &self.pinned[..]);
            let input = RefineInput { pos, velocity, carry, dt, pinned, body };
            r.apply(&*self.exec, &input, self.clock.as_deref(), &mut self.new_pos, &mut self.new_vel)?;
        }
        if let Some(b) = &mut self.body {
            let mut projected = false;
            if let Some(proj) = &mut b.projection {
                if let Some(t) = &mut b.tethers {
                    // Where the tethers' follow counts moves from.
                    t.start(&self.new_pos);
                }
                // Collision projection; a refined pass has built the faces at the same frame.
                let faces =
                    body_query(query, &mut self.query)?.faces_at(&b.mesh, body_next.unwrap_or(&self.state.body_pos))?;
                proj.apply(&*self.exec, faces, &self.pinned, &mut self.new_pos, &mut self.new_vel)?;
                projected = proj.moved() > 0;
            }
            if let Some(t) = &mut b.tethers {
                // Tethers last, the cloth following the projection's moves as well as the pulls:
                // the projection pushes each vertex out along its own nearest face, and after the
                // tethers it undid their follow (on the held-out back flip a largest strain of
                // 37.6; the t-shirt dancing 3.8 when only the pulls were followed, 1.4 now).
                let body = body_next.unwrap_or(&self.state.body_pos);
                t.apply(body, &mut self.new_pos, &mut self.new_vel, projected);
            }
        }
        // The one check of the whole pass's result: every stage above can only have made it
        // non-finite from finite inputs by overflow (a far carry, a runaway prediction).
        let n = self.new_pos.len().max(1);
        if let Some(i) = self.new_pos.iter().chain(&self.new_vel).position(|p| !finite3(*p)) {
            return Err(Error::NonFinite { what: "stepped garment vertex", index: i % n });
        }
        // Commit: nothing was refused.
        commit(&mut self.state, &mut self.new_pos, &mut self.new_vel, body_next);
        self.update_output_normals();
        self.last_carry = carry;
        Ok(())
    }
}

/// Pins: the pass starts from the current positions (`pos`, m) with each pinned vertex at its
/// target (`targets`, m) in the speed limit's frame, that is moved back by `carry` (m), into
/// `new_pos`. Before the prediction: the network's graph is built with the pins in place.
fn pin(pos: &[[f32; 3]], pinned: &[bool], targets: &[[f32; 3]], carry: [f32; 3], new_pos: &mut [[f32; 3]]) {
    new_pos.copy_from_slice(pos);
    let carried = carry != [0.0; 3];
    for i in 0..new_pos.len() {
        if pinned[i] {
            let t = targets[i];
            new_pos[i] = if carried { [t[0] - carry[0], t[1] - carry[1], t[2] - carry[2]] } else { t };
        }
    }
}

/// The solver modes' coasting guess, which the refinement then solves into the implicit step:
/// every free vertex moves on at its velocity (m/frame, relative to the speed limit's frame);
/// pinned vertices stay at their targets (already in `new_pos`) with no velocity.
fn coast(state: &SimState, pinned: &[bool], new_pos: &mut [[f32; 3]], new_vel: &mut [[f32; 3]]) {
    for i in 0..new_pos.len() {
        let v = if pinned[i] { [0.0; 3] } else { state.velocity[i] };
        new_vel[i] = v;
        if !pinned[i] {
            let p = state.pos[i];
            new_pos[i] = [p[0] + v[0], p[1] + v[1], p[2] + v[2]];
        }
    }
}

/// Back to the world frame: the speed limit's frame moved by `carry` (m) over the pass, and the
/// garment's new positions with it (nothing to do when it did not move).
fn to_world(carry: [f32; 3], new_pos: &mut [[f32; 3]]) {
    if carry != [0.0; 3] {
        for p in new_pos.iter_mut() {
            *p = [p[0] + carry[0], p[1] + carry[1], p[2] + carry[2]];
        }
    }
}

/// What the refinement reads of the body: its faces at the current frame (`now`, m) and at the
/// pass's next one (`next`; `None`: static body), from the shared body query, else the sim's
/// `own` (`None` without a body).
fn refine_body<'q>(
    shared: Option<&'q mut BodyQuery>,
    own: &'q mut Option<BodyQuery>,
    body: Option<&BodyState>,
    now: &[[f32; 3]],
    next: Option<&[[f32; 3]]>,
) -> Result<Option<RefineBody<'q>>> {
    let Some(b) = body else { return Ok(None) };
    let [now, next] = body_query(shared, own)?.faces(&b.mesh, now, next.unwrap_or(now))?;
    Ok(Some(RefineBody { now, next }))
}

/// Commit: the pass's positions (m) and velocities (m/frame) become the state (the buffers are
/// swapped, not copied), and the body moves on a frame: previous ← current ← `body_next`
/// (a static body, or none: previous ← current).
fn commit(
    state: &mut SimState,
    new_pos: &mut Vec<[f32; 3]>,
    new_vel: &mut Vec<[f32; 3]>,
    body_next: Option<&[[f32; 3]]>,
) {
    core::mem::swap(&mut state.pos, new_pos);
    core::mem::swap(&mut state.velocity, new_vel);
    if let Some(next) = body_next {
        core::mem::swap(&mut state.body_prev, &mut state.body_pos);
        state.body_pos.copy_from_slice(next);
    } else if !state.body_pos.is_empty() {
        state.body_prev.copy_from_slice(&state.body_pos);
    }
}
