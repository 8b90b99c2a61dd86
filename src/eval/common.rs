//! One step from common states: every method advances the garment one frame from the same
//! states, those of a reference rollout of the converged implicit step, and is scored against
//! the converged step from that state. A rollout scored on its own states (see [`rollout`])
//! compares methods on unequal terms: a calmer rollout has less descent available, which raises
//! its relative gap at an equal absolute one, and one that blows up has more. From common states
//! the descent is the same for every method, and small changes to a model do not change the
//! states it is scored on.
//!
//! [`rollout`]: fn@super::rollout

use super::rollout::{advance, check_frames, step_kind, store};
use super::scoring::{InsideCounter, Scorer};
use super::summary::summarise;
use super::{Animation, Gap, Rollout, RolloutOptions, StepKind, Summary};
use crate::error::{Error, Result};
use crate::model::file::Model;
use crate::physics::Objective;
use crate::sim::{BodyDesc, Sim, SimConfig, SimState};
use crate::solve::LbfgsParams;
use alloc::boxed::Box;
use alloc::vec;
use alloc::vec::Vec;

/// A way to advance the garment one frame.
#[derive(Clone, Copy)]
pub enum Method<'a> {
    /// The runtime: a [`Sim`] of the model under this configuration (refinement included),
    /// past its start-up step.
    Network {
        /// The model.
        model: &'a Model<'a>,
        /// Its runtime configuration.
        cfg: SimConfig,
    },
    /// The implicit step (f64 L-BFGS under these rules, from the coasting guess) on the
    /// scoring objective.
    Implicit(LbfgsParams),
}

/// Where the common states come from.
#[derive(Clone, Copy)]
pub enum Reference<'a> {
    /// A rollout of the converged implicit step (`RolloutOptions::gap_solver`) of this
    /// objective (contact terms dropped without a body), pinned vertices at their targets: the
    /// states the physics leads to.
    Converged(Objective),
    /// A rollout of the runtime (its start-up step first, as [`rollout`](fn@super::rollout)
    /// plays it): the states a model reaches on its own.
    Network {
        /// The model.
        model: &'a Model<'a>,
        /// Its runtime configuration.
        cfg: SimConfig,
    },
}

/// Plays a `reference` rollout of `anim` over frames `1..=frames`, from
/// [`Animation::initial_garment`] moving at [`Animation::initial_velocity`]. On the frames `options.gap_every` picks (every
/// frame when 0), every method steps once from the reference's state and is scored as in
/// [`rollout`](fn@super::rollout) under `options.objective`: terms, penetration, strain, speed,
/// step time, the inside count on the frames `options.inside_every` picks, and the [`Gap`]
/// against the converged step of the scoring objective from that state (for a converged
/// reference of the same objective, its own step). One [`Rollout`] per method, its records on
/// the picked frames only; `kept` is empty. A method's non-finite output is recorded as its
/// [`Rollout::failure`] (the first one) and the frame left out of its records. A network method
/// starts every step from the state alone, past its start-up step (the speed limit's carry of
/// an earlier step, if any, is not part of the state).
///
/// # Errors
/// [`Error::Empty`] for `frames == 0`; [`Error::OutOfRange`] when `frames` is past the
/// animation's last frame; [`Error::NonFinite`] when a reference step is not finite (for a
/// network reference, its refused output); errors of
/// [`Sim::new`] (an effect a model lacks, ...), of the animation and of the scoring; runtime
/// errors other than a non-finite output.
pub fn common_state_gaps(
    anim: &dyn Animation,
    frames: usize,
    methods: &[Method<'_>],
    reference: Reference<'_>,
    options: &RolloutOptions,
) -> Result<Vec<Rollout>> {
    check_frames(anim, frames)?;
    let garment = anim.garment();
    let n = garment.n_vertices();
    let pinned = garment.pinned().to_vec();
    let mut scorer = Scorer::new(anim, &options.objective)?;
    let scoring = scorer.objective;
    let b0 = anim.body_frame(0);
    fn new_sim<'m>(anim: &dyn Animation, model: &'m Model<'m>, cfg: SimConfig) -> Result<Sim<'m>> {
        let body = anim.body_mesh().map(|mesh| BodyDesc { mesh, positions: anim.body_frame(0) });
        Sim::new(model, anim.garment(), body, cfg)
    }
    // The reference: a converged objective (`same`: the scoring one), or a runtime rollout.
    let (mut converged, mut same, mut runtime) = (scoring, true, None);
    match reference {
        Reference::Converged(mut objective) => {
            if anim.body_mesh().is_none() {
                objective.collision = None;
                objective.friction = None;
            }
            (converged, same) = (objective, objective == scoring);
        }
        Reference::Network { model, cfg } => runtime = Some(new_sim(anim, model, cfg)?),
    }
    // Every method with what it runs on: a network method's Sim, made once.
    let mut runners = Vec::with_capacity(methods.len());
    for m in methods {
        runners.push(match m {
            Method::Network { model, cfg } => Runner::Network(Box::new(new_sim(anim, model, *cfg)?)),
            Method::Implicit(params) => Runner::Implicit(*params),
        });
    }
    let mut inside = InsideCounter::new(anim, options.inside_every)?;
    let mut outs: Vec<Rollout> = methods
        .iter()
        .map(|_| Rollout { frames: Vec::new(), kept: Vec::new(), failure: None, summary: Summary::default() })
        .collect();
    let every = options.gap_every.max(1);
    let mut pos = anim.initial_garment()?;
    let mut vel = anim.initial_velocity()?;
    if let Some(sim) = &mut runtime {
        let body_state = if sim.state().body_pos.is_empty() { vec![] } else { b0.to_vec() };
        sim.set_state(&SimState {
            pos: pos.clone(),
            velocity: vel.clone(),
            body_prev: body_state.clone(),
            body_pos: body_state,
            started: sim.state().started,
        })?;
    }
    let mut targets = vec![[0.0f32; 3]; n];
    let mut next = vec![[0.0f32; 3]; n];
    let mut x32 = vec![[0.0f32; 3]; n];
    for t in 1..=frames {
        anim.pin_targets(t, &mut targets)?;
        scorer.load_parts(StepKind::Stepped, &pos, &vel, &targets, &pos, &vel);
        let body_frames = [t.saturating_sub(2), t - 1, t];
        let picked = t % every == 0;
        // On picked frames, the optimum of the scoring objective from the state.
        let optimum = if picked || (same && runtime.is_none()) {
            Some(scorer.optimum(anim, body_frames, &options.gap_solver)?)
        } else {
            None
        };
        if let (true, Some(optimum)) = (picked, optimum) {
            let (body_prev, body_pos) = match anim.body_mesh() {
                Some(_) => (anim.body_frame(t.saturating_sub(2)).to_vec(), anim.body_frame(t - 1).to_vec()),
                None => (vec![], vec![]),
            };
            for (runner, out) in runners.iter_mut().zip(outs.iter_mut()) {
                let clock = std::time::Instant::now();
                let kind = match runner {
                    Runner::Network(sim) => {
                        let sim_body = !sim.state().body_pos.is_empty();
                        let before = SimState {
                            pos: pos.clone(),
                            velocity: vel.clone(),
                            body_prev: if sim_body { body_prev.clone() } else { vec![] },
                            body_pos: if sim_body { body_pos.clone() } else { vec![] },
                            started: true,
                        };
                        sim.set_state(&before)?;
                        sim.set_pin_targets(&targets)?;
                        let body_next = anim.body_frame(t);
                        match sim.step(body_next) {
                            Ok(_) => {}
                            Err(e @ Error::NonFinite { what, .. }) if what.starts_with("network output") => {
                                out.failure.get_or_insert((t, e));
                                continue;
                            }
                            Err(e) => return Err(e),
                        }
                        let after = sim.state();
                        let kind = step_kind(sim_body, &before, after, body_next);
                        scorer.load_parts(kind, &pos, &vel, &targets, &after.pos, &after.velocity);
                        x32.copy_from_slice(&after.pos);
                        kind
                    }
                    Runner::Implicit(params) => {
                        scorer.load_parts(StepKind::Stepped, &pos, &vel, &targets, &pos, &vel);
                        scorer.implicit(anim, body_frames, params)?;
                        if let Err(e) = store(&scorer.x, &mut x32) {
                            out.failure.get_or_insert((t, e));
                            continue;
                        }
                        StepKind::Stepped
                    }
                };
                let step_ms = clock.elapsed().as_secs_f64() * 1e3;
                let stepped = matches!(kind, StepKind::Stepped | StepKind::StartUp);
                let (terms, penetrating, _) = scorer.score(anim, body_frames, stepped, None)?;
                let gap: Option<Gap> = terms.map(|terms| optimum.gap(terms.total()));
                let mut rec = scorer.record(t, kind, terms, penetrating, step_ms, gap);
                rec.inside_percent = InsideCounter::count(&mut inside, anim, t, &x32)?;
                out.frames.push(rec);
            }
        }
        // The reference step: the converged step of the scoring objective is the optimum
        // already solved.
        if let Some(sim) = &mut runtime {
            sim.set_pin_targets(&targets)?;
            sim.step(anim.body_frame(t))?;
            pos.copy_from_slice(&sim.state().pos);
            vel.copy_from_slice(&sim.state().velocity);
        } else {
            if same {
                store(&scorer.x_star, &mut next)?;
            } else {
                scorer.load_parts(StepKind::Stepped, &pos, &vel, &targets, &pos, &vel);
                scorer.objective = converged;
                let solved = scorer.implicit(anim, body_frames, &options.gap_solver);
                scorer.objective = scoring;
                solved?;
                store(&scorer.x, &mut next)?;
            }
            advance(&pinned, &next, &mut pos, &mut vel);
        }
    }
    for out in &mut outs {
        out.summary = summarise(&out.frames, out.failure.is_none());
    }
    Ok(outs)
}

/// A method ready to step: a network method's Sim, or the implicit step's rules.
enum Runner<'m> {
    Network(Box<Sim<'m>>),
    Implicit(LbfgsParams),
}
