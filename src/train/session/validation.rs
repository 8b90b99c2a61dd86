//! Validation of a training run: rollouts of fixed samples with the current weights, scored with
//! the evaluation-form objective ([`Trainer::validate`]).

use super::{finite, frames_of, graph_of, Trainer, ValidationReport};
use crate::error::Result;
use crate::features::DT;
use crate::physics::{score_rollout, Objective};
use crate::rng::Rng;
use crate::train::data::Sample;
use crate::train::inputs::{BodyFrames, GarmentState};
use crate::train::network::Stats;
use std::vec;
use std::vec::Vec;

impl Trainer {
    /// The fixed validation samples: seeded independently of the training stream, the config's
    /// [`material`](crate::train::TrainConfig::material), first hierarchy centre, spread over
    /// the scenes.
    fn validation_samples(&self) -> Result<Vec<Sample>> {
        let (count, frames) = self.cfg.validation;
        let mut rng = Rng::new(self.cfg.seed ^ 0x0a11_da7e);
        let mut cfg = self.cfg.clone();
        cfg.random_materials = false;
        cfg.random_centres = false;
        let mut out = Vec::new();
        for i in 0..count {
            let mut s = self.data.sample(&mut rng, frames, &cfg)?;
            s.scene = i % self.data.scenes.len();
            let sc = &self.data.scenes[s.scene];
            s.start = rng.below(sc.n_frames().saturating_sub(frames + 1).max(1));
            s.garment = sc.garment_with_material(s.material)?;
            out.push(s);
        }
        Ok(out)
    }

    /// Rolls out the fixed validation samples (start-up step, then `frames - 1` regular steps)
    /// with the current weights and scores them with the evaluation-form objective.
    ///
    /// # Errors
    /// Errors of the data, features and scoring.
    pub fn validate(&mut self) -> Result<ValidationReport> {
        let frames = self.cfg.validation.1.max(2);
        let stats = Stats::<f32>::of(&self.params);
        let mut report = ValidationReport { iteration: self.iteration, rollouts: Vec::new() };
        let weights = self.export_weights().into_owned();
        for sample in self.validation_samples()? {
            let scene = &self.data.scenes[sample.scene];
            let graph = graph_of(&sample, self.cfg.levels)?;
            let garment = &sample.garment;
            let pinned = garment.pinned().to_vec();
            let n = garment.n_vertices();
            let mut pos = scene.initial_garment(sample.start)?;
            let mut velocity = vec![[0.0f32; 3]; n];
            let mut targets = vec![[0.0f32; 3]; n];
            let mut out_frames: Vec<Vec<[f32; 3]>> = Vec::new();
            let mut body_frames: Vec<Vec<[f32; 3]>> = Vec::new();
            let mut ok = true;
            for k in 0..frames {
                let (fp, fc, fnx, dt) = frames_of(sample.start, k, true);
                scene.skinned_garment(fnx, &mut targets)?;
                let gs = GarmentState { pos: &pos, velocity: &velocity, pinned: &pinned, pin_targets: &targets };
                let body = BodyFrames {
                    mesh: &scene.body,
                    prev: scene.body_frame(fp),
                    pos: scene.body_frame(fc),
                    next: scene.body_frame(fnx),
                };
                self.builder.build(&self.net.spec, garment, &graph, &gs, Some(&body), dt, &mut self.step)?;
                let step = &self.step;
                self.net.forward_fast(&mut self.ws, &self.pool, &weights, &stats, &graph, step)?;
                let new_pos = &self.ws.new_pos;
                if !finite(new_pos) {
                    ok = false;
                    break;
                }
                for i in 0..n {
                    velocity[i] = [0, 1, 2].map(|c| new_pos[i][c] - step.pos[i][c]);
                }
                pos.copy_from_slice(new_pos);
                out_frames.push(pos.clone());
                body_frames.push(scene.body_frame(fnx).to_vec());
            }
            let name = self.data.names[sample.scene].clone();
            let score = if ok {
                score_rollout(
                    garment,
                    &Objective::evaluation(),
                    &out_frames,
                    &body_frames,
                    scene.body.faces(),
                    DT as f64,
                )
                .ok()
                .filter(|s| s.mean.total.is_finite())
            } else {
                None
            };
            report.rollouts.push((name, score));
        }
        Ok(report)
    }
}
