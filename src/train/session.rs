//! A training run (MODEL.md section 7): samples drawn from the dataset, rollouts of up to
//! `rollout_max` steps where every step takes its own optimiser step and hands its (detached)
//! prediction to the next, normaliser statistics accumulated on every pass, checkpoints that
//! resume exactly, validation rollouts and export to `.hood`.

use super::config::{PullStart, TrainConfig};
use super::data::{Dataset, Sample};
use super::fast::FastWorkspace;
use super::inputs::{BodyFrames, GarmentState, InputBuilder, StepData};
use super::layout::Layout;
use super::loss::{LossBody, StepLoss};
use super::network::{Network, Stats};
use super::optim::{clip_global_norm, Adam};
use crate::error::{Error, Result};
use crate::eval::converged_solver;
use crate::exec::{Executor, ThreadPool};
use crate::features::{DT, DT_STARTUP, EDGE_WIDTH, NODE_WIDTH};
use crate::hierarchy::{CentreChoice, Hierarchy, HierarchyConfig};
use crate::model::{write_model, Model, Normalisers, Params};
use crate::physics::{Objective, RolloutScore, Terms};
use crate::rng::Rng;
use crate::sim::Graph;
use crate::solve::{ImplicitStep, LbfgsParams, StepState};
use std::borrow::Cow;
use std::format;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

mod checkpoint;
mod validation;
pub use checkpoint::checkpoint_config;

/// What one optimiser step saw.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepReport {
    /// The objective's terms at the prediction (training form).
    pub terms: Terms<f32>,
    /// Their sum.
    pub total: f32,
    /// The supervised pull toward the step's optimum (0 when off).
    pub supervised: f32,
    /// Gradient norm before clipping.
    pub grad_norm: f64,
    /// Whether this was the start-up step (static body, dt = 1/3 s).
    pub startup: bool,
    /// Whether the step was skipped (non-finite loss or gradient): no update was made.
    pub skipped: bool,
}

/// What one iteration (one sample, one rollout) did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IterationReport {
    /// The iteration's index (0-based).
    pub iteration: u64,
    /// Scene index in the dataset.
    pub scene: usize,
    /// Garment vertices.
    pub vertices: usize,
    /// Warm-up iteration (statistics only, no optimiser steps).
    pub warmup: bool,
    /// Learning rate of the iteration's first optimiser step.
    pub learning_rate: f64,
    /// Collision weight.
    pub collision_weight: f64,
    /// The body frame the rollout starts at.
    pub start_frame: usize,
    /// The frame a carried rollout continued from (`None`: a fresh sample, from the skinned
    /// garment with a start-up step first or from a reference state).
    pub carried_from: Option<usize>,
    /// Whether the rollout started from a state of the scene's reference rollout (config
    /// `reference_states`).
    pub from_reference: bool,
    /// One entry per optimiser step.
    pub steps: Vec<StepReport>,
}

/// Validation figures: fixed samples rolled out with the current weights, scored in the
/// evaluation form (EVALUATION.md).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ValidationReport {
    /// The iteration it was taken at.
    pub iteration: u64,
    /// Per fixed sample: scene name and the rollout's score (`None` when it went non-finite).
    pub rollouts: Vec<(String, Option<RolloutScore>)>,
}

impl ValidationReport {
    /// Whether every rollout stayed finite.
    pub fn finite(&self) -> bool {
        self.rollouts.iter().all(|r| r.1.is_some())
    }

    /// Mean over finite rollouts of (objective total, % penetrating).
    pub fn means(&self) -> (f64, f64) {
        let ok: Vec<&RolloutScore> = self.rollouts.iter().filter_map(|r| r.1.as_ref()).collect();
        let n = ok.len().max(1) as f64;
        (
            ok.iter().map(|s| s.mean.total).sum::<f64>() / n,
            ok.iter().map(|s| s.mean.penetrating_percent).sum::<f64>() / n,
        )
    }
}

/// A training run's whole state.
pub struct Trainer {
    /// Settings.
    pub cfg: TrainConfig,
    /// The scenes.
    pub data: Dataset,
    net: Network,
    /// Shape and normalisers (the weights live in `theta`).
    params: Params,
    theta: Vec<f32>,
    /// Moving average of `theta` (config `ema`; empty while off or before the first step).
    ema: Vec<f32>,
    /// The weights the passes use under config `bf16_weights`: `theta` with its bf16 weights
    /// rounded, refreshed before every step (empty while off).
    rounded: Vec<f32>,
    adam: Adam,
    rng: Rng,
    /// Iterations done.
    pub iteration: u64,
    /// Optimiser steps taken.
    pub optimiser_steps: u64,
    /// Wall time spent training so far (restored from checkpoints), s.
    pub seconds: f64,
    /// The network passes' workers, activations and inputs (reused step after step).
    pool: ThreadPool,
    ws: FastWorkspace,
    builder: InputBuilder,
    step: StepData,
    /// Carried rollouts (config `carry`), one slot per track.
    tracks: Vec<Option<Track>>,
}

/// A rollout's end state kept for a later iteration to continue from (config `carry`).
#[derive(Clone, Debug)]
pub struct Track {
    /// The sample it belongs to (scene, material, hierarchy centre).
    pub sample: Sample,
    /// The body frame `pos` is at.
    pub frame: usize,
    /// Garment positions at `frame`, m.
    pub pos: Vec<[f32; 3]>,
    /// `pos` minus the positions one frame earlier, m per frame.
    pub velocity: Vec<[f32; 3]>,
}

fn noisy(rng: &mut Rng, x: &[[f32; 3]], pinned: &[bool], std: f32) -> Vec<[f32; 3]> {
    x.iter()
        .zip(pinned)
        .map(|(p, &pin)| if pin || std == 0.0 { *p } else { p.map(|c| c + (rng.normal() as f32) * std) })
        .collect()
}

fn finite(x: &[[f32; 3]]) -> bool {
    x.iter().flatten().all(|c| c.is_finite())
}

/// Feeds one pass's features to the normalisers (MODEL.md section 3); the node normaliser sees
/// the embedding columns as the forward writes them from the current tables.
fn accumulate(lay: &Layout, theta: &[f32], n: &mut Normalisers, step: &StepData) {
    let mut rows = step.node_features.clone();
    lay.fill_embeddings(theta, &step.node_type, &step.node_level, &mut rows);
    n.node.accumulate(&rows, NODE_WIDTH);
    for f in &step.edge_features {
        n.edge.accumulate(f, EDGE_WIDTH);
    }
    n.body_edge.accumulate(&step.g2b_features, crate::features::BODY_EDGE_WIDTH);
    n.body_edge.accumulate(&step.b2g_features, crate::features::BODY_EDGE_WIDTH);
}

/// The graph of a sample's garment with its hierarchy centre.
fn graph_of(sample: &Sample, levels: usize) -> Result<Graph> {
    let centre = sample.centre_seed.map_or(CentreChoice::First, CentreChoice::Seeded);
    let h = Hierarchy::build(&sample.garment, &HierarchyConfig { levels, centre })?;
    Graph::new(&sample.garment, &h)
}

/// Body frames (previous, current, next) and dt of rollout step `k` starting at frame `start`.
/// A fresh rollout (`startup`) begins with the start-up step, static at `start`; its step
/// `k >= 1` goes from `start + k - 1` to `start + k`, as `Sim` does after its start-up step. A
/// carried rollout's step `k` goes from `start + k` to `start + k + 1`.
fn frames_of(start: usize, k: usize, startup: bool) -> (usize, usize, usize, f32) {
    match (startup, k) {
        (true, 0) => (start, start, start, DT_STARTUP),
        (true, _) => (start + k.max(2) - 2, start + k - 1, start + k, DT),
        (false, _) => ((start + k).saturating_sub(1), start + k, start + k + 1, DT),
    }
}

impl Trainer {
    /// A fresh run: parameters initialised from `cfg.seed`, empty normalisers.
    ///
    /// # Errors
    /// Errors of the spec and of the network layout.
    pub fn new(cfg: TrainConfig, data: Dataset) -> Result<Trainer> {
        let spec = cfg.spec()?;
        let mut params = Params::init(&spec, cfg.seed)?;
        if let Some(last) = params.mlps.decoder.layers.last_mut() {
            let k = cfg.decoder_init_scale;
            last.weight.iter_mut().chain(last.bias.iter_mut()).for_each(|w| *w *= k);
        }
        let net = Network::of(&params)?;
        let theta = net.layout.flatten::<f32>(&params);
        let adam = Adam::new(theta.len());
        let rng = Rng::new(cfg.seed ^ 0x7a1e_5eed);
        let pool = ThreadPool::new(cfg.threads);
        let cfg_tracks = cfg.carry.0;
        Ok(Trainer {
            cfg,
            data,
            net,
            params,
            theta,
            ema: Vec::new(),
            rounded: Vec::new(),
            adam,
            rng,
            iteration: 0,
            optimiser_steps: 0,
            seconds: 0.0,
            pool,
            ws: FastWorkspace::default(),
            builder: InputBuilder::default(),
            step: StepData::default(),
            tracks: vec![None; cfg_tracks],
        })
    }

    /// Changes the carried rollouts (config `carry`) of the following iterations: tracks beyond
    /// the new count are dropped, new ones start empty.
    pub fn set_carry(&mut self, carry: (usize, f64)) {
        self.cfg.carry = carry;
        self.tracks.resize(carry.0, None);
    }

    /// The state a carried track holds (config `carry`), open to change (for tools and tests;
    /// keep its vertex count); `None` for an empty or absent slot.
    pub fn track_mut(&mut self, slot: usize) -> Option<&mut Track> {
        self.tracks.get_mut(slot)?.as_mut()
    }

    /// Draws a track for a rollout of `steps` steps: its slot, and its state unless the slot is
    /// empty, the scene ends too soon or the draw restarts it. Draws nothing when carrying is
    /// off, so that such runs keep their sample stream.
    fn draw_track(&mut self, steps: usize) -> (Option<usize>, Option<Track>) {
        if self.tracks.is_empty() {
            return (None, None);
        }
        let slot = self.rng.below(self.tracks.len());
        let restart = self.rng.uniform(0.0, 1.0) < self.cfg.carry.1;
        let track = self.tracks[slot]
            .take()
            .filter(|t| !restart && t.frame + steps < self.data.scenes[t.sample.scene].n_frames());
        (Some(slot), track)
    }

    /// Runs the following iterations on `threads` threads (at least 1). Results do not depend on
    /// it: the fast path splits work into fixed parts and sums them in order, so a run can
    /// resume on another thread count and stay bitwise the same.
    pub fn set_threads(&mut self, threads: usize) {
        let threads = threads.max(1);
        if threads != self.cfg.threads {
            self.cfg.threads = threads;
            self.pool = ThreadPool::new(threads);
        }
    }

    /// The current parameters (weights from the flat vector, current normaliser statistics).
    pub fn params(&self) -> Params {
        let mut p = self.params.clone();
        self.net.layout.unflatten(&self.theta, &mut p);
        p
    }

    /// The parameters exports and validation use: the moving average of the weights when
    /// config `ema` is on (and a step has been taken), else the current ones, their bf16
    /// weights rounded when config `bf16_weights` is on, with the current normaliser
    /// statistics.
    pub fn model_params(&self) -> Params {
        let mut p = self.params.clone();
        self.net.layout.unflatten(&self.export_weights(), &mut p);
        p
    }

    /// The flat weights of [`model_params`](Self::model_params).
    fn export_weights(&self) -> Cow<'_, [f32]> {
        let w = model_weights(self.cfg.ema, &self.ema, &self.theta);
        if !self.cfg.bf16_weights {
            return Cow::Borrowed(w);
        }
        let mut rounded = w.to_vec();
        self.net.layout.round_bf16_weights(&mut rounded);
        Cow::Owned(rounded)
    }

    /// Changes the weight average's decay (config `ema`) from now on; turning it on starts the
    /// average at the current weights (also when it was on before with another decay: the
    /// average so far is kept).
    pub fn set_ema(&mut self, decay: f64) -> Result<()> {
        self.cfg.ema = super::config::ema(decay)?;
        if decay == 0.0 {
            self.ema = Vec::new();
        }
        Ok(())
    }

    /// Parameter count.
    pub fn parameter_count(&self) -> usize {
        self.theta.len()
    }

    /// Runs one iteration: one sample, its rollout, one optimiser step per rollout step (none
    /// during warm-up).
    ///
    /// # Errors
    /// Errors of the data, the features and the network (a non-finite loss is not an error:
    /// the step is skipped and reported).
    pub fn iteration(&mut self) -> Result<IterationReport> {
        let it = self.iteration;
        let warmup = it < self.cfg.warmup_iterations;
        let steps = if warmup { self.cfg.rollout_max.min(3) } else { self.cfg.rollout_length(it) };
        let (slot, carried) = if warmup { (None, None) } else { self.draw_track(steps) };
        let (sample, mut carried) = match carried {
            Some(t) => (t.sample, Some((t.frame, t.pos, t.velocity))),
            None => (self.data.sample(&mut self.rng, steps, &self.cfg)?, None),
        };
        // A fresh sample may start from the reference state one frame after its start frame
        // (a state with a velocity; the rollout still ends within the scene). Draws nothing
        // when the option is off, so that such runs keep their sample stream.
        let mut from_reference = false;
        if carried.is_none() && !warmup && self.cfg.reference_states > 0.0 {
            let draw = self.rng.uniform(0.0, 1.0) < self.cfg.reference_states;
            let frame = sample.start + 1;
            if let Some((pos, velocity)) = draw.then(|| self.data.reference_state(sample.scene, frame)).flatten() {
                let pos = noisy(&mut self.rng, &pos, sample.garment.pinned(), self.cfg.noise);
                carried = Some((frame, pos, velocity));
                from_reference = true;
            }
        }
        let graph = graph_of(&sample, self.cfg.levels)?;
        let scene = &self.data.scenes[sample.scene];
        let garment = &sample.garment;
        let pinned = garment.pinned().to_vec();
        let n = garment.n_vertices();
        let cw = self.cfg.collision_weight_at(it);
        let objective = Objective::training(cw);
        let mut report = IterationReport {
            iteration: it,
            scene: sample.scene,
            vertices: n,
            warmup,
            learning_rate: self.cfg.learning_rate_at(self.optimiser_steps),
            collision_weight: cw,
            start_frame: carried.as_ref().map_or(sample.start, |c| c.0),
            carried_from: carried.as_ref().filter(|_| !from_reference).map(|c| c.0),
            from_reference,
            steps: Vec::new(),
        };
        let startup = carried.is_none();
        let (start, mut pos, mut velocity) = match carried {
            Some(c) => c,
            None => {
                let x0 = scene.initial_garment(sample.start)?;
                let pos = noisy(&mut self.rng, &x0, &pinned, self.cfg.noise);
                let prev = noisy(&mut self.rng, &x0, &pinned, self.cfg.noise);
                let velocity = pos.iter().zip(&prev).map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]]).collect();
                (sample.start, pos, velocity)
            }
        };
        let mut loss = StepLoss::new(garment, &scene.body)?;
        let mut skinned = [vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n]];
        let mut grad = vec![0.0f32; self.theta.len()];
        let (mut solver, mut x_star) = (None, vec![[0.0f32; 3]; n]);
        let spec = self.net.spec.clone();
        for k in 0..steps {
            let (fp, fc, fnx, dt) = frames_of(start, k, startup);
            // The skinned garment two frames back, one back and at the next frame: true
            // frame-to-frame differences (unlike the body frames right after the start-up step).
            for (buf, f) in skinned.iter_mut().zip([fnx.saturating_sub(2), fnx.saturating_sub(1), fnx]) {
                scene.skinned_garment(f, buf)?;
            }
            let targets = &skinned[2];
            let gs = GarmentState { pos: &pos, velocity: &velocity, pinned: &pinned, pin_targets: targets };
            let body = BodyFrames {
                mesh: &scene.body,
                prev: scene.body_frame(fp),
                pos: scene.body_frame(fc),
                next: scene.body_frame(fnx),
            };
            self.builder.build(&spec, garment, &graph, &gs, Some(&body), dt, &mut self.step)?;
            let step = &self.step;
            accumulate(&self.net.layout, &self.theta, &mut self.params.normalisers, step);
            if k > 0 {
                // The output normaliser: linear-blend-skinning accelerations (MODEL.md section 3).
                let acc: Vec<f32> = (0..n)
                    .flat_map(|i| (0..3).map(move |c| (i, c)))
                    .map(|(i, c)| skinned[2][i][c] - 2.0 * skinned[1][i][c] + skinned[0][i][c])
                    .collect();
                self.params.normalisers.output.accumulate(&acc, 3);
            }
            if warmup {
                // Statistics only: follow the skinned garment.
                pos.copy_from_slice(&skinned[2]);
                for i in 0..n {
                    velocity[i] = [0, 1, 2].map(|c| skinned[2][i][c] - skinned[1][i][c]);
                }
                continue;
            }
            let stats = Stats::<f32>::of(&self.params);
            let exec: &dyn Executor = &self.pool;
            let weights = pass_weights(&self.cfg, &self.net.layout, &self.theta, &mut self.rounded);
            self.net.forward_fast(&mut self.ws, exec, weights, &stats, &graph, step)?;
            let lb = LossBody { mesh: &scene.body, current: scene.body_frame(fc), next: scene.body_frame(fnx) };
            let mut sr = StepReport { startup: startup && k == 0, ..StepReport::default() };
            let ok = finite(&self.ws.new_pos);
            if ok {
                let (terms, _) = loss.eval(&objective, &lb, &step.pos, &step.velocity, dt, &self.ws.new_pos)?;
                sr.terms = terms;
                sr.total = terms.total();
                let pull = self.cfg.supervised_weight_at(it) as f32;
                if pull > 0.0 && sr.total.is_finite() {
                    // The network's own pinned positions are the targets, so pinned vertices add
                    // nothing.
                    let state = StepState {
                        pos: &step.pos,
                        velocity: &step.velocity,
                        dt,
                        pinned: &pinned,
                        targets: &self.ws.new_pos,
                    };
                    let solver = solver.get_or_insert_with(|| ImplicitStep::new(n, 10));
                    let params = LbfgsParams { max_iterations: self.cfg.supervised.2, ..converged_solver() };
                    let from_prediction = self.cfg.supervised_start == PullStart::Prediction;
                    if from_prediction {
                        x_star.copy_from_slice(&self.ws.new_pos);
                    }
                    loss.optimum(solver, &objective, &state, &params, from_prediction, &mut x_star)?;
                    sr.supervised = loss.add_pull(&self.ws.new_pos, &x_star, pull, dt);
                }
                let dx = loss.grad();
                if sr.total.is_finite() && finite(dx) {
                    grad.iter_mut().for_each(|g| *g = 0.0);
                    self.net.backward_fast(&mut self.ws, exec, weights, &stats, &graph, step, dx, &mut grad)?;
                    sr.grad_norm = clip_global_norm(&mut grad, self.cfg.clip);
                }
            }
            if !(ok && sr.total.is_finite() && sr.grad_norm.is_finite()) {
                // A diverged prediction ends the rollout without an update.
                sr.skipped = true;
                report.steps.push(sr);
                break;
            }
            let lr = self.cfg.learning_rate_at(self.optimiser_steps);
            self.adam.step_on(&self.pool, &mut self.theta, &grad, lr);
            self.optimiser_steps += 1;
            update_average(&mut self.ema, &self.theta, self.cfg.ema);
            report.steps.push(sr);
            // Detached hand-over: the prediction becomes the next step's state.
            for i in 0..n {
                velocity[i] = [0, 1, 2].map(|c| self.ws.new_pos[i][c] - step.pos[i][c]);
            }
            pos.copy_from_slice(&self.ws.new_pos);
        }
        if let Some(slot) = slot {
            // A rollout that diverged leaves its track empty (the next draw starts afresh).
            let done = report.steps.len();
            if report.steps.last().is_some_and(|s| !s.skipped) && done == steps {
                let frame = if startup { start + done - 1 } else { start + done };
                self.tracks[slot] = Some(Track { sample, frame, pos, velocity });
            }
        }
        self.iteration += 1;
        Ok(report)
    }

    /// The current model as `.hood` bytes (f32 and bf16 weights), with provenance: the config,
    /// iterations, optimiser steps, wall time and `extra` entries.
    ///
    /// # Errors
    /// Errors of [`write_model`].
    pub fn export(&self, extra: &[(&str, &str)]) -> Result<Vec<u8>> {
        let cfg = self.cfg.to_json();
        let its = self.iteration.to_string();
        let steps = self.optimiser_steps.to_string();
        let secs = format!("{:.0}", self.seconds);
        let scenes = self.data.names.join(", ");
        let mut prov: Vec<(&str, &str)> = vec![
            ("trainer", "hood train"),
            ("config", &cfg),
            ("iterations", &its),
            ("optimiser_steps", &steps),
            ("train_seconds", &secs),
            ("scenes", &scenes),
        ];
        let ema = format!("{}", self.cfg.ema);
        if self.cfg.ema > 0.0 && !self.ema.is_empty() {
            prov.push(("weights", "moving average"));
            prov.push(("ema", &ema));
        }
        prov.extend_from_slice(extra);
        write_model(&self.model_params(), true, &prov)
    }

    /// Continues from an exported model (when the checkpoint is gone): its weights and
    /// normaliser statistics (as accumulators of weight `count_scale` rows), a fresh optimiser,
    /// the iteration counters from its provenance.
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] when the model's shape differs from `cfg`'s.
    pub fn from_model(cfg: TrainConfig, data: Dataset, model: &Model<'_>) -> Result<Trainer> {
        let mut t = Trainer::new(cfg, data)?;
        let p = model.to_params();
        if p.spec != t.params.spec {
            return Err(Error::IncompatibleModel { reason: "the model's shape differs from the config's" });
        }
        t.theta = t.net.layout.flatten::<f32>(&p);
        t.params.normalisers = p.normalisers;
        let prov = |k: &str| model.provenance().find(|(key, _)| *key == k).and_then(|(_, v)| v.parse::<f64>().ok());
        t.iteration = prov("iterations").unwrap_or(0.0) as u64;
        t.optimiser_steps = prov("optimiser_steps").unwrap_or(0.0) as u64;
        t.seconds = prov("train_seconds").unwrap_or(0.0);
        // A different stream from the original run's, reproducible from the iteration.
        t.rng = Rng::new(t.cfg.seed ^ 0x7a1e_5eed ^ t.iteration.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        Ok(t)
    }
}

/// The weights a step's passes use: `theta`, or under config `bf16_weights` its copy in
/// `rounded` with the bf16 weights rounded (the gradient at those then updates `theta`).
fn pass_weights<'a>(cfg: &TrainConfig, layout: &Layout, theta: &'a [f32], rounded: &'a mut Vec<f32>) -> &'a [f32] {
    if !cfg.bf16_weights {
        return theta;
    }
    rounded.clear();
    rounded.extend_from_slice(theta);
    layout.round_bf16_weights(rounded);
    rounded
}

/// `ema ← d·ema + (1 − d)·theta` after an optimiser step, with `d = decay` (nothing when 0;
/// the first step copies `theta`).
fn update_average(ema: &mut Vec<f32>, theta: &[f32], decay: f64) {
    if decay <= 0.0 {
        return;
    }
    if ema.len() != theta.len() {
        ema.clear();
        ema.extend_from_slice(theta);
        return;
    }
    let w = (1.0 - decay) as f32;
    for (a, &t) in ema.iter_mut().zip(theta) {
        *a += w * (t - *a);
    }
}

/// The weights exports and validation use: the moving average `ema` when the decay is on and
/// the average has started, else `theta`.
fn model_weights<'a>(decay: f64, ema: &'a [f32], theta: &'a [f32]) -> &'a [f32] {
    if decay > 0.0 && !ema.is_empty() {
        ema
    } else {
        theta
    }
}
