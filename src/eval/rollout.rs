//! Driving rollouts: a [`Sim`] of a model ([`rollout`], [`rollout_observed`]) or the implicit
//! solver ([`implicit_rollout`]) stepped through an animation's frames, every frame scored.

use super::off_body::OffBody;
use super::scoring::{InsideCounter, Scorer};
use super::summary::{summarise, Summary};
use super::{Animation, FrameObserver, Rollout, RolloutOptions, StepKind};
use crate::error::{Error, Result};
use crate::math::sub3;
use crate::model::file::Model;
use crate::sim::{BodyDesc, Sim, SimConfig, SimState};
use crate::solve::LbfgsParams;
use alloc::vec;
use alloc::vec::Vec;

/// What the runtime did in a step from `before` to `after` toward the body frame `body_next`
/// (`sim_body`: whether the Sim has a body).
pub(super) fn step_kind(sim_body: bool, before: &SimState, after: &SimState, body_next: &[[f32; 3]]) -> StepKind {
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
pub(super) fn store(x: &[[f64; 3]], out: &mut [[f32; 3]]) -> Result<()> {
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
pub(super) fn advance(pinned: &[bool], next: &[[f32; 3]], pos: &mut [[f32; 3]], vel: &mut [[f32; 3]]) {
    for (i, (p, v)) in pos.iter_mut().zip(vel.iter_mut()).enumerate() {
        *v = if pinned[i] { [0.0; 3] } else { sub3(next[i], *p) };
        *p = next[i];
    }
}

/// Refuses a rollout of no frames or past the animation's last frame.
pub(super) fn check_frames(anim: &dyn Animation, frames: usize) -> Result<()> {
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
        let clock = std::time::Instant::now();
        match sim.step(body_next) {
            Ok(_) => {}
            Err(e @ Error::NonFinite { what, .. }) if what.starts_with("network output") => {
                out.failure = Some((t, e));
                break;
            }
            Err(e) => return Err(e),
        }
        let step_ms = clock.elapsed().as_secs_f64() * 1e3;
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
        rec.over_budget = sim.last_effects().over_budget;
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
///
/// [`ImplicitStep`]: crate::solve::ImplicitStep
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
        let clock = std::time::Instant::now();
        scorer.implicit(anim, body_frames, solver)?;
        let step_ms = clock.elapsed().as_secs_f64() * 1e3;
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
