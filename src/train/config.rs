//! What a training run does: model size, the recipe's constants (MODEL.md section 7) and the
//! data. Read from a JSON file (every key optional; defaults are the recipe's) and stored in
//! checkpoints and exported models, so that a run can be resumed and traced.

use crate::error::{Error, Result};
use crate::io::json::{self, Value};
use crate::mesh::Material;
use crate::model::{ModelSpec, HOOD_SCHEDULE};
use crate::scene::{GarmentKind, MotionKind};
use alloc::format;
use alloc::string::{String, ToString};
use alloc::vec;
use alloc::vec::Vec;

/// One family of training scenes.
#[derive(Clone, Debug, PartialEq)]
pub enum SceneSource {
    /// A procedural garment of about `vertices` vertices on the procedural mannequin doing
    /// `motion` for `seconds`.
    Procedural {
        /// Which garment.
        garment: GarmentKind,
        /// Target vertex count.
        vertices: usize,
        /// Which motion.
        motion: MotionKind,
        /// Motion length, s.
        seconds: f32,
    },
    /// A MakeHuman garment (a [`crate::scene::MakeHumanGarment`] name: `"tee"`, `"jeans"`,
    /// `"crop-top"`, `"leggings"`; the men's outfit is held out) on the CMU walk, or on `motion` when given, at
    /// most `frames` frames (the scene is skipped with a warning when `../shared/assets` is
    /// absent).
    MakeHuman {
        /// The [`crate::scene::MakeHumanGarment`] name.
        garment: String,
        /// Frame limit.
        frames: usize,
        /// A procedural or corpus motion instead of the CMU walk.
        motion: Option<MotionKind>,
    },
}

impl SceneSource {
    /// A short name for logs: `skirt-500/walk`, `makehuman-jeans`.
    pub fn name(&self) -> String {
        match self {
            SceneSource::Procedural { garment, vertices, motion, .. } => {
                format!("{}-{}/{}", garment.name(), vertices, motion.name())
            }
            SceneSource::MakeHuman { garment, motion: None, .. } => format!("makehuman-{garment}"),
            SceneSource::MakeHuman { garment, motion: Some(m), .. } => format!("makehuman-{garment}/{}", m.name()),
        }
    }
}

/// A training run's settings.
///
/// Built from [`Default`] (the recipe's) and the `with_` methods, or read from JSON
/// ([`TrainConfig::from_json`]); new fields may come, so it has no struct literal outside this
/// crate.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct TrainConfig {
    /// Latent width h.
    pub latent: usize,
    /// Hidden layers per MLP (the runtime needs 2).
    pub hidden_layers: usize,
    /// Coarse levels built per garment.
    pub levels: usize,
    /// Block schedule (MODEL.md section 4).
    pub schedule: String,
    /// Iterations (samples) to run in total.
    pub iterations: u64,
    /// Iterations at the start that only accumulate normaliser statistics.
    pub warmup_iterations: u64,
    /// Base learning rate (the recipe's 5e-5).
    pub learning_rate: f64,
    /// Optimiser steps per halving of the learning rate (the recipe's 50,000).
    pub lr_halving_steps: u64,
    /// Global gradient-norm clip.
    pub clip: f64,
    /// Longest rollout (optimiser steps per sample, start-up step included).
    pub rollout_max: usize,
    /// Iterations per increase of the rollout length (the recipe's 5,000).
    pub rollout_every: u64,
    /// Standard deviation of the noise on garment positions and previous positions, m.
    pub noise: f32,
    /// Collision weight at the start and at the end of the ramp.
    pub collision_weight: (f64, f64),
    /// Iterations over which the collision weight grows (log-linearly) to its final value.
    pub collision_ramp: u64,
    /// Scale of the decoder's last layer at initialisation (1: PyTorch's initialisation as
    /// the reference; smaller starts the model near the no-force prediction `pos + velocity`
    /// instead of random accelerations).
    pub decoder_init_scale: f32,
    /// Draw a random material per sample (otherwise [`material`](Self::material)).
    pub random_materials: bool,
    /// The material of every sample when [`random_materials`](Self::random_materials) is off,
    /// and of the scenes' reference rollouts and the validation rollouts: the default
    /// ([`Material::default`]) unless set, for example to one end of the training ranges
    /// ([`Material::preset`]) to train a model for that regime. JSON key `material`: a preset
    /// name or `density,mu,lambda,bending`, as [`Material::parse`] reads it.
    pub material: Material,
    /// Draw a random hierarchy centre per sample (otherwise the first candidate).
    pub random_centres: bool,
    /// Scenes to sample from (uniformly).
    pub scenes: Vec<SceneSource>,
    /// Iterations between checkpoints (and exports).
    pub checkpoint_every: u64,
    /// Iterations between validations.
    pub validate_every: u64,
    /// Validation rollouts: number of fixed samples and frames each.
    pub validation: (usize, usize),
    /// Supervised pull toward the step's optimum (a warm start; off by default): its weight
    /// (see [`crate::train::StepLoss::add_pull`]), the iteration it stops at, and the L-BFGS
    /// iterations of the f32 implicit step that finds the optimum.
    pub supervised: (f64, u64, usize),
    /// Where the supervised pull's L-BFGS starts: from coasting (the pull's target is the
    /// step's optimum, or close to it) or from the network's own prediction (the target is the
    /// prediction refined by a few quasi-Newton iterations: a small, curvature-aware
    /// improvement of what the network does, which weighs the objective's soft directions more
    /// than its raw gradient does).
    pub supervised_start: PullStart,
    /// Carried rollouts (off when 0 tracks): the number of tracks and the probability that a
    /// track is restarted from the skinned garment when drawn. A track keeps the state its last
    /// rollout ended in and the next draw of it continues from there, so that the network also
    /// learns from the states of its own long rollouts (a sample otherwise starts from the
    /// skinned garment and ends `rollout_max` steps later).
    pub carry: (usize, f64),
    /// Probability (0-1) that a fresh sample starts from a state of its scene's reference
    /// rollout (the converged implicit step of the training objective, in
    /// [`material`](Self::material); see [`crate::train::Dataset::attach_reference_states`])
    /// rather than from the skinned garment with a start-up step: the network then also learns
    /// from the states the physics leads to, not only from its own. Off (0) by default.
    pub reference_states: f64,
    /// Decay of an exponential moving average of the weights taken after every optimiser step
    /// (off when 0; e.g. 0.999 averages over about the last 1,000 steps). When on, exports and
    /// the periodic validation use the averaged weights: they vary less from snapshot to
    /// snapshot than the weights the optimiser holds, which move with every noisy step.
    pub ema: f64,
    /// Train the weights that bf16 precision runs in bf16 (every Linear weight outside the
    /// encoders) as bf16 values: the passes use them rounded to bf16, the optimiser updates
    /// the f32 weights with the gradient at the rounded ones (a straight-through estimate), and
    /// exports and validation round them. The exported model's f32 and bf16 weights are then
    /// the same values, so its two precisions differ only where bf16 products round the
    /// activations. Off by default.
    pub bf16_weights: bool,
    /// Worker threads for the network passes.
    pub threads: usize,
    /// Seed of the model initialisation and of the sample stream.
    pub seed: u64,
}

impl Default for TrainConfig {
    /// The compact real-time model on small procedural garments and the MakeHuman garments.
    fn default() -> Self {
        let p = |garment, vertices, motion| SceneSource::Procedural { garment, vertices, motion, seconds: 6.0 };
        TrainConfig {
            latent: 32,
            hidden_layers: 2,
            levels: 3,
            schedule: HOOD_SCHEDULE.to_string(),
            iterations: 30_000,
            warmup_iterations: 100,
            learning_rate: 5e-5,
            lr_halving_steps: 50_000,
            clip: 1.0,
            rollout_max: 5,
            rollout_every: 5_000,
            noise: 3e-3,
            collision_weight: (5e3, 5e5),
            collision_ramp: 20_000,
            decoder_init_scale: 1.0,
            random_materials: true,
            material: Material::default(),
            random_centres: true,
            scenes: vec![
                p(GarmentKind::Skirt, 500, MotionKind::Walk),
                p(GarmentKind::Skirt, 500, MotionKind::RandomPoses(1)),
                p(GarmentKind::Dress, 800, MotionKind::Walk),
                p(GarmentKind::Dress, 800, MotionKind::Run),
                p(GarmentKind::Dress, 800, MotionKind::RandomPoses(2)),
                p(GarmentKind::Cape, 400, MotionKind::ArmSwings),
                p(GarmentKind::Cape, 400, MotionKind::Turn),
                p(GarmentKind::Skirt, 500, MotionKind::Jump),
                SceneSource::MakeHuman { garment: "jeans".into(), frames: 300, motion: None },
                SceneSource::MakeHuman { garment: "tee".into(), frames: 300, motion: None },
            ],
            checkpoint_every: 250,
            validate_every: 500,
            validation: (4, 30),
            supervised: (0.0, 0, 30),
            supervised_start: PullStart::Coasting,
            carry: (0, 0.0),
            reference_states: 0.0,
            ema: 0.0,
            bf16_weights: false,
            threads: 2,
            seed: 1,
        }
    }
}

impl TrainConfig {
    with_fields! {
        /// Sets [`latent`](Self::latent): the latent width.
        with_latent => latent: usize;
        /// Sets [`hidden_layers`](Self::hidden_layers): hidden layers per MLP.
        with_hidden_layers => hidden_layers: usize;
        /// Sets [`levels`](Self::levels): coarse levels built per garment.
        with_levels => levels: usize;
        /// Sets [`schedule`](Self::schedule): the block schedule.
        with_schedule => schedule: String;
        /// Sets [`iterations`](Self::iterations): iterations (samples) in total.
        with_iterations => iterations: u64;
        /// Sets [`warmup_iterations`](Self::warmup_iterations): statistics-only iterations.
        with_warmup_iterations => warmup_iterations: u64;
        /// Sets [`learning_rate`](Self::learning_rate): the base learning rate.
        with_learning_rate => learning_rate: f64;
        /// Sets [`lr_halving_steps`](Self::lr_halving_steps): optimiser steps per halving.
        with_lr_halving_steps => lr_halving_steps: u64;
        /// Sets [`clip`](Self::clip): the global gradient-norm clip.
        with_clip => clip: f64;
        /// Sets [`rollout_max`](Self::rollout_max): optimiser steps per sample at most.
        with_rollout_max => rollout_max: usize;
        /// Sets [`rollout_every`](Self::rollout_every): iterations per rollout increase.
        with_rollout_every => rollout_every: u64;
        /// Sets [`noise`](Self::noise): the standard deviation of the position noise, metres.
        with_noise => noise: f32;
        /// Sets [`collision_weight`](Self::collision_weight): the ramp's first and last weight.
        with_collision_weight => collision_weight: (f64, f64);
        /// Sets [`collision_ramp`](Self::collision_ramp): iterations of the weight's ramp.
        with_collision_ramp => collision_ramp: u64;
        /// Sets [`decoder_init_scale`](Self::decoder_init_scale): the decoder's initial scale.
        with_decoder_init_scale => decoder_init_scale: f32;
        /// Sets [`random_materials`](Self::random_materials): a random material per sample.
        with_random_materials => random_materials: bool;
        /// Sets [`material`](Self::material): the material when not random, of the reference
        /// and validation rollouts too.
        with_material => material: Material;
        /// Sets [`random_centres`](Self::random_centres): a random hierarchy centre per sample.
        with_random_centres => random_centres: bool;
        /// Sets [`scenes`](Self::scenes): the scenes to sample from.
        with_scenes => scenes: Vec<SceneSource>;
        /// Sets [`checkpoint_every`](Self::checkpoint_every): iterations between checkpoints.
        with_checkpoint_every => checkpoint_every: u64;
        /// Sets [`validate_every`](Self::validate_every): iterations between validations.
        with_validate_every => validate_every: u64;
        /// Sets [`validation`](Self::validation): validation samples and frames each.
        with_validation => validation: (usize, usize);
        /// Sets [`supervised`](Self::supervised): the pull's weight, last iteration, L-BFGS iterations.
        with_supervised => supervised: (f64, u64, usize);
        /// Sets [`supervised_start`](Self::supervised_start): where the pull's L-BFGS starts.
        with_supervised_start => supervised_start: PullStart;
        /// Sets [`carry`](Self::carry): carried rollout tracks and their restart probability.
        with_carry => carry: (usize, f64);
        /// Sets [`reference_states`](Self::reference_states): the chance of a reference start (0-1).
        with_reference_states => reference_states: f64;
        /// Sets [`ema`](Self::ema): the decay of the weights' moving average (0: off).
        with_ema => ema: f64;
        /// Sets [`bf16_weights`](Self::bf16_weights): train and export bf16-exact weights.
        with_bf16_weights => bf16_weights: bool;
        /// Sets [`threads`](Self::threads): worker threads for the network passes.
        with_threads => threads: usize;
        /// Sets [`seed`](Self::seed): the seed of the initialisation and the sample stream.
        with_seed => seed: u64;
    }
}

fn bad(key: &str, why: &str) -> Error {
    Error::parse("training config", 0, format!("'{key}': {why}"))
}

fn uint(j: &Value, key: &str) -> Result<u64> {
    uint_of(j.as_f64().ok_or_else(|| bad(key, "expected a number"))?, key)
}

fn uint_of(v: f64, key: &str) -> Result<u64> {
    if v < 0.0 || v.fract() != 0.0 || v > 1e15 {
        return Err(bad(key, "expected a non-negative integer"));
    }
    Ok(v as u64)
}

fn float(j: &Value, key: &str) -> Result<f64> {
    let v = j.as_f64().ok_or_else(|| bad(key, "expected a number"))?;
    if !v.is_finite() {
        return Err(bad(key, "expected a finite number"));
    }
    Ok(v)
}

fn boolean(j: &Value, key: &str) -> Result<bool> {
    j.as_bool().ok_or_else(|| bad(key, "expected true or false"))
}

fn scene(j: &Value) -> Result<SceneSource> {
    let s = |k: &str| j.get(k).and_then(Value::as_str).ok_or_else(|| bad("scenes", &format!("each needs '{k}'")));
    let garment = s("garment")?;
    let motion_named = |name: &str| {
        let m = MotionKind::parse(name).ok_or_else(|| {
            bad("motion", "walk, run, jump, turn, arm-swings, random-<seed> or <corpus family>-<seed> (jumps-3)")
        })?;
        if m.is_held_out() {
            return Err(bad(
                "motion",
                "held out for validation (seeds from 1000 on and every backflip): not for training",
            ));
        }
        Ok(m)
    };
    if let Some(which) = crate::scene::MakeHumanGarment::parse(garment) {
        if which.is_held_out() {
            return Err(bad("garment", "held out for validation (the men's outfit): not for training"));
        }
        let frames = j.get("frames").map(|v| uint(v, "frames")).transpose()?.unwrap_or(300) as usize;
        let motion = j.get("motion").map(|_| s("motion").and_then(motion_named)).transpose()?;
        return Ok(SceneSource::MakeHuman { garment: garment.to_string(), frames, motion });
    }
    let kind = GarmentKind::parse(garment)
        .ok_or_else(|| bad("garment", "skirt, dress, cape, tee, jeans, crop-top or leggings"))?;
    let motion = motion_named(s("motion")?)?;
    let vertices = j.get("vertices").map(|v| uint(v, "vertices")).transpose()?.unwrap_or(600) as usize;
    crate::limits::garment(vertices, 0)?;
    let seconds = j.get("seconds").map(|v| float(v, "seconds")).transpose()?.unwrap_or(6.0) as f32;
    if seconds.is_nan() || seconds < 0.2 {
        return Err(bad("seconds", "at least 0.2"));
    }
    Ok(SceneSource::Procedural { garment: kind, vertices, motion, seconds })
}

/// `[tracks, reset_probability]`, the probability within `0..=1`.
fn carry(j: &Value) -> Result<(usize, f64)> {
    let key = "carry";
    let a =
        json::f64_vec(j).filter(|a| a.len() == 2).ok_or_else(|| bad(key, "expected [tracks, reset_probability]"))?;
    let tracks = uint_of(a[0], key)?;
    if tracks > 4096 || !(0.0..=1.0).contains(&a[1]) {
        return Err(bad(key, "at most 4096 tracks, a reset probability within 0..=1"));
    }
    Ok((tracks as usize, a[1]))
}

/// `[weight, until_iteration, lbfgs_iterations]`, all non-negative (at least one L-BFGS
/// iteration is run).
fn supervised(j: &Value) -> Result<(f64, u64, usize)> {
    let a = json::f64_vec(j)
        .filter(|a| a.len() == 3 && a.iter().all(|x| x.is_finite() && *x >= 0.0))
        .ok_or_else(|| bad("supervised", "expected [weight, until_iteration, lbfgs_iterations], non-negative"))?;
    Ok((a[0], a[1] as u64, (a[2] as usize).max(1)))
}

/// Where the supervised pull's L-BFGS starts (config key `supervised_start`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PullStart {
    /// From coasting, `pos + velocity`: the target is the step's optimum (as converged as the
    /// iteration count allows).
    Coasting,
    /// From the network's prediction: the target is that prediction refined.
    Prediction,
}

impl PullStart {
    /// The config's name: `coasting` or `prediction`.
    pub fn name(self) -> &'static str {
        match self {
            PullStart::Coasting => "coasting",
            PullStart::Prediction => "prediction",
        }
    }

    /// Reads a [`name`](Self::name).
    ///
    /// # Errors
    /// [`Error::Parse`] for any other word.
    pub fn parse(name: &str) -> Result<PullStart> {
        match name {
            "coasting" => Ok(PullStart::Coasting),
            "prediction" => Ok(PullStart::Prediction),
            _ => Err(bad("supervised_start", "expected \"coasting\" or \"prediction\"")),
        }
    }
}

/// Parses `WEIGHT,UNTIL,ITERATIONS` (the config key `supervised` without brackets), e.g. for a
/// command-line override.
pub fn parse_supervised(text: &str) -> Result<(f64, u64, usize)> {
    supervised(&json::parse(&format!("[{text}]"))?)
}

/// Checks a weight-average decay (config key `ema`): within `[0, 1)`.
pub fn ema(decay: f64) -> Result<f64> {
    if (0.0..1.0).contains(&decay) {
        Ok(decay)
    } else {
        Err(bad("ema", "expected a decay within [0, 1)"))
    }
}

/// `p` if it is a probability (0 to 1), else an error naming `key`.
pub fn probability(p: f64, key: &str) -> Result<f64> {
    if (0.0..=1.0).contains(&p) {
        Ok(p)
    } else {
        Err(bad(key, "expected a probability from 0 to 1"))
    }
}

/// Parses `TRACKS,RESET` (the command line's form of the `carry` key).
///
/// # Errors
/// [`Error::Parse`] as for the JSON key.
pub fn parse_carry(text: &str) -> Result<(usize, f64)> {
    carry(&json::parse(&format!("[{text}]"))?)
}

impl TrainConfig {
    /// Reads a JSON object; absent keys keep their [`Default`] values.
    ///
    /// # Errors
    /// [`Error::Parse`] naming the offending key; [`Error::CapacityExceeded`] for a scene of more
    /// than [`crate::limits::MAX_VERTICES`] vertices.
    pub fn from_json(text: &str) -> Result<TrainConfig> {
        let j = json::parse(text)?;
        let obj = j.as_object().ok_or_else(|| bad("config", "expected a JSON object"))?;
        let mut c = TrainConfig::default();
        for (k, v) in obj {
            let key = k.as_str();
            match key {
                "latent" => c.latent = uint(v, key)? as usize,
                "hidden_layers" => c.hidden_layers = uint(v, key)? as usize,
                "levels" => c.levels = uint(v, key)? as usize,
                "schedule" => c.schedule = v.as_str().ok_or_else(|| bad(key, "expected a string"))?.to_string(),
                "iterations" => c.iterations = uint(v, key)?,
                "warmup_iterations" => c.warmup_iterations = uint(v, key)?,
                "learning_rate" => c.learning_rate = float(v, key)?,
                "lr_halving_steps" => c.lr_halving_steps = uint(v, key)?.max(1),
                "clip" => c.clip = float(v, key)?,
                "rollout_max" => c.rollout_max = uint(v, key)?.max(1) as usize,
                "rollout_every" => c.rollout_every = uint(v, key)?.max(1),
                "noise" => c.noise = float(v, key)? as f32,
                "collision_weight" => {
                    let a =
                        json::f64_vec(v).filter(|a| a.len() == 2).ok_or_else(|| bad(key, "expected [start, end]"))?;
                    c.collision_weight = (a[0], a[1]);
                }
                "collision_ramp" => c.collision_ramp = uint(v, key)?,
                "decoder_init_scale" => c.decoder_init_scale = float(v, key)? as f32,
                "random_materials" => c.random_materials = boolean(v, key)?,
                "random_centres" => c.random_centres = boolean(v, key)?,
                "material" => {
                    c.material = Material::parse(v.as_str().ok_or_else(|| bad(key, "expected a string"))?)?;
                }
                "scenes" => {
                    let a = v.as_array().ok_or_else(|| bad(key, "expected an array"))?;
                    c.scenes = a.iter().map(scene).collect::<Result<_>>()?;
                }
                "checkpoint_every" => c.checkpoint_every = uint(v, key)?.max(1),
                "validate_every" => c.validate_every = uint(v, key)?.max(1),
                "validation" => {
                    let a = json::f64_vec(v)
                        .filter(|a| a.len() == 2)
                        .ok_or_else(|| bad(key, "expected [samples, frames]"))?;
                    c.validation = (a[0].max(0.0) as usize, a[1].max(1.0) as usize);
                }
                "supervised" => c.supervised = supervised(v)?,
                "supervised_start" => {
                    c.supervised_start = PullStart::parse(v.as_str().unwrap_or(""))?;
                }
                "carry" => c.carry = carry(v)?,
                "reference_states" => c.reference_states = probability(float(v, key)?, key)?,
                "ema" => c.ema = ema(float(v, key)?)?,
                "bf16_weights" => c.bf16_weights = boolean(v, key)?,
                "threads" => c.threads = uint(v, key)?.max(1) as usize,
                "seed" => c.seed = uint(v, key)?,
                _ => return Err(bad(key, "unknown key")),
            }
        }
        c.spec()?;
        if c.random_materials && c.material != Material::default() {
            return Err(bad("material", "a fixed material needs \"random_materials\": false"));
        }
        if c.scenes.is_empty() {
            return Err(bad("scenes", "at least one scene"));
        }
        Ok(c)
    }

    /// The model shape.
    ///
    /// # Errors
    /// Errors of [`ModelSpec::with_schedule`].
    pub fn spec(&self) -> Result<ModelSpec> {
        ModelSpec::with_schedule(self.latent, self.hidden_layers, self.levels, &self.schedule)
    }

    /// The same settings as JSON (what [`from_json`](Self::from_json) reads back), indented.
    pub fn to_json(&self) -> String {
        let scenes = self
            .scenes
            .iter()
            .map(|s| match s {
                SceneSource::Procedural { garment, vertices, motion, seconds } => SceneFile {
                    garment: garment.name().to_string(),
                    vertices: Some(*vertices),
                    frames: None,
                    motion: Some(motion.name()),
                    seconds: Some(*seconds),
                },
                SceneSource::MakeHuman { garment, frames, motion } => SceneFile {
                    garment: garment.clone(),
                    vertices: None,
                    frames: Some(*frames),
                    motion: motion.map(|m| m.name()),
                    seconds: None,
                },
            })
            .collect();
        json::to_pretty(&ConfigFile {
            latent: self.latent,
            hidden_layers: self.hidden_layers,
            levels: self.levels,
            schedule: &self.schedule,
            iterations: self.iterations,
            warmup_iterations: self.warmup_iterations,
            learning_rate: self.learning_rate,
            lr_halving_steps: self.lr_halving_steps,
            clip: self.clip,
            rollout_max: self.rollout_max,
            rollout_every: self.rollout_every,
            noise: self.noise,
            collision_weight: self.collision_weight,
            collision_ramp: self.collision_ramp,
            decoder_init_scale: self.decoder_init_scale,
            random_materials: self.random_materials,
            material: (self.material != Material::default()).then(|| self.material.to_string()),
            random_centres: self.random_centres,
            checkpoint_every: self.checkpoint_every,
            validate_every: self.validate_every,
            validation: self.validation,
            supervised: self.supervised,
            supervised_start: self.supervised_start.name(),
            carry: self.carry,
            reference_states: self.reference_states,
            ema: self.ema,
            bf16_weights: self.bf16_weights,
            threads: self.threads,
            seed: self.seed,
            scenes,
        })
    }

    /// Rollout length (optimiser steps, start-up included) at `iteration`:
    /// `min(1 + iteration / rollout_every, rollout_max)`.
    pub fn rollout_length(&self, iteration: u64) -> usize {
        (1 + iteration / self.rollout_every).min(self.rollout_max as u64) as usize
    }

    /// Collision weight at `iteration`: log-linear from the start to the end value over
    /// `collision_ramp` iterations, then constant.
    pub fn collision_weight_at(&self, iteration: u64) -> f64 {
        let (a, b) = self.collision_weight;
        if self.collision_ramp == 0 || a <= 0.0 || b <= 0.0 {
            return b;
        }
        let t = (iteration as f64 / self.collision_ramp as f64).min(1.0);
        libm::exp(libm::log(a) + t * (libm::log(b) - libm::log(a)))
    }

    /// Weight of the supervised pull at `iteration` (0 once it has ended, or when off).
    pub fn supervised_weight_at(&self, iteration: u64) -> f64 {
        if iteration < self.supervised.1 {
            self.supervised.0
        } else {
            0.0
        }
    }

    /// Learning rate at optimiser step `s`: `base · (0.5^floor(s / halving) + 0.01)`.
    pub fn learning_rate_at(&self, s: u64) -> f64 {
        super::optim::step_decay(self.learning_rate, self.lr_halving_steps, s)
    }
}

/// The JSON form of a [`TrainConfig`], keys in the order [`TrainConfig::to_json`] writes them.
#[derive(serde::Serialize)]
struct ConfigFile<'a> {
    latent: usize,
    hidden_layers: usize,
    levels: usize,
    schedule: &'a str,
    iterations: u64,
    warmup_iterations: u64,
    learning_rate: f64,
    lr_halving_steps: u64,
    clip: f64,
    rollout_max: usize,
    rollout_every: u64,
    noise: f32,
    collision_weight: (f64, f64),
    collision_ramp: u64,
    decoder_init_scale: f32,
    random_materials: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    material: Option<String>,
    random_centres: bool,
    checkpoint_every: u64,
    validate_every: u64,
    validation: (usize, usize),
    supervised: (f64, u64, usize),
    supervised_start: &'static str,
    carry: (usize, f64),
    reference_states: f64,
    ema: f64,
    // Written only when on, so that other configs keep their keys.
    #[serde(skip_serializing_if = "core::ops::Not::not")]
    bf16_weights: bool,
    threads: usize,
    seed: u64,
    scenes: Vec<SceneFile>,
}

/// The JSON form of a [`SceneSource`]: a procedural scene has `vertices` and `seconds`, a
/// MakeHuman one `frames`.
#[derive(serde::Serialize)]
struct SceneFile {
    garment: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    vertices: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    frames: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    motion: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    seconds: Option<f32>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A config as earlier versions wrote it (numbers in exponent form, keys on few lines).
    const EARLIER: &str = r#"{
  "latent": 32, "hidden_layers": 2, "levels": 3, "schedule": "SSSL:SL:LS",
  "iterations": 30000, "warmup_iterations": 100, "learning_rate": 5e-5, "lr_halving_steps": 50000, "clip": 1,
  "rollout_max": 5, "rollout_every": 5000, "noise": 3e-3, "collision_weight": [5e3, 5e5], "collision_ramp": 20000,
  "decoder_init_scale": 1, "random_materials": true, "random_centres": true, "checkpoint_every": 250, "validate_every": 500, "validation": [4, 30], "supervised": [0e0, 0, 30], "supervised_start": "coasting", "carry": [0, 0], "reference_states": 0, "ema": 0, "threads": 2, "seed": 1,
  "scenes": [
    {"garment": "skirt", "vertices": 500, "motion": "walk", "seconds": 6},
    {"garment": "jeans", "frames": 300},
    {"garment": "tee", "frames": 120, "motion": "walk"}
  ]
}
"#;

    #[test]
    fn configs_written_earlier_still_read_and_round_trip() {
        let c = TrainConfig::from_json(&EARLIER.replace("SSSL:SL:LS", HOOD_SCHEDULE)).unwrap();
        assert_eq!(c.learning_rate, 5e-5);
        assert_eq!(c.noise, 3e-3);
        assert_eq!(c.scenes.len(), 3);
        assert_eq!(
            c.scenes[2],
            SceneSource::MakeHuman { garment: "tee".into(), frames: 120, motion: Some(MotionKind::Walk) }
        );
        let text = c.to_json();
        assert_eq!(TrainConfig::from_json(&text).unwrap(), c);
        // The same keys, in the same order, as before.
        let keys = |t: &str| -> Vec<String> { json::parse(t).unwrap().as_object().unwrap().keys().cloned().collect() };
        assert_eq!(keys(&text), keys(EARLIER));
        assert!(text.contains("\"noise\": 0.003"), "{text}");
    }
}
