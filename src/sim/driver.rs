//! A fixed-step driver: the model runs at its 30 Hz; engines call it at their own frame rate
//! with the body at engine time, and get the garment interpolated between the last two model
//! frames (MODEL.md section 5: resample the body, interpolate the output, never feed another dt).

use super::Sim;
use crate::error::{Error, Result};
use crate::math::finite3;
use alloc::vec::Vec;

/// Model frame length, seconds.
pub const MODEL_DT: f64 = 1.0 / 30.0;

/// The longest engine frame an update simulates, seconds (30 model steps): time beyond it is
/// dropped, as engines clamp their physics time step after a hitch (a pause, a loading stall), so
/// that one update's cost stays bounded. The body still ends at the frame's pose.
pub const MAX_ENGINE_DT: f64 = 1.0;

/// Drives a [`Sim`] at 30 Hz from engine frames of any length. Allocates nothing per update.
pub struct FixedStep<'m> {
    sim: Sim<'m>,
    clock: Interpolator,
}

impl<'m> FixedStep<'m> {
    /// Wraps `sim`; the body starts where the sim's state has it.
    pub fn new(sim: Sim<'m>) -> FixedStep<'m> {
        FixedStep { clock: Interpolator::new(&sim), sim }
    }

    /// The wrapped simulation.
    pub fn sim(&self) -> &Sim<'m> {
        &self.sim
    }

    /// Model steps taken so far.
    pub fn model_steps(&self) -> u64 {
        self.clock.model_steps()
    }

    /// Advances engine time by `dt` seconds, with `body_now` the body at the new engine time
    /// (ignored without a body). Runs as many model steps as 30 Hz frames were crossed, with
    /// the body linearly interpolated to each frame's time, and returns the garment
    /// interpolated to engine time (one model frame behind, as fixed-step rendering is). A `dt`
    /// over [`MAX_ENGINE_DT`] is simulated as that long.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a negative or non-finite `dt`; bad body input is refused
    /// before any step (state unchanged); errors of [`Sim::step`].
    pub fn update(&mut self, dt: f32, body_now: &[[f32; 3]]) -> Result<&[[f32; 3]]> {
        self.clock.update(&mut self.sim, dt, body_now)
    }
}

/// The clock and interpolation of [`FixedStep`] apart from the sim they drive, for a caller that
/// keeps the sim elsewhere (the C ABI's driver). It belongs to the sim it was made for: a sim of
/// another garment or body is refused.
pub struct Interpolator {
    /// Engine seconds since the last model frame, in `[0, MODEL_DT)`.
    since_frame: f64,
    engine_body: Vec<[f32; 3]>,
    body_sample: Vec<[f32; 3]>,
    prev_out: Vec<[f32; 3]>,
    /// The garment before the step in progress, which becomes `prev_out` when the step succeeds.
    before_step: Vec<[f32; 3]>,
    out: Vec<[f32; 3]>,
    steps: u64,
}

impl Interpolator {
    /// A clock at a model frame, with the body and garment where `sim`'s state has them.
    pub fn new(sim: &Sim<'_>) -> Interpolator {
        let body = sim.state().body_pos.clone();
        let pos = sim.positions().to_vec();
        Interpolator {
            since_frame: 0.0,
            body_sample: body.clone(),
            engine_body: body,
            prev_out: pos.clone(),
            before_step: pos.clone(),
            out: pos,
            steps: 0,
        }
    }

    /// Model steps taken so far.
    pub fn model_steps(&self) -> u64 {
        self.steps
    }

    /// [`FixedStep::update`] of `sim`.
    ///
    /// # Errors
    /// As [`FixedStep::update`]; [`Error::SizeMismatch`] for a sim other than the one this
    /// clock was made for.
    pub fn update(&mut self, sim: &mut Sim<'_>, dt: f32, body_now: &[[f32; 3]]) -> Result<&[[f32; 3]]> {
        let dt = dt as f64;
        if !(dt >= 0.0 && dt.is_finite()) {
            return Err(Error::OutOfRange { what: "engine frame time", index: 0 });
        }
        let dt = dt.min(MAX_ENGINE_DT);
        for (what, expected, got) in [
            ("driven sim garment vertices", self.out.len(), sim.positions().len()),
            ("driven sim body vertices", self.engine_body.len(), sim.state().body_pos.len()),
        ] {
            if expected != got {
                return Err(Error::SizeMismatch { what, expected, got });
            }
        }
        let has_body = !self.engine_body.is_empty();
        if has_body {
            if body_now.len() != self.engine_body.len() {
                return Err(Error::SizeMismatch {
                    what: "body vertices",
                    expected: self.engine_body.len(),
                    got: body_now.len(),
                });
            }
            if let Some(i) = body_now.iter().position(|p| !finite3(*p)) {
                return Err(Error::NonFinite { what: "body vertex", index: i });
            }
        }
        let mut elapsed = 0.0; // engine seconds of this update already simulated
        while self.since_frame + (dt - elapsed) >= MODEL_DT {
            let to_frame = MODEL_DT - self.since_frame;
            elapsed += to_frame;
            // Body at the frame's time: between the previous engine body and `body_now`.
            if has_body {
                let f = if dt > 0.0 { (elapsed / dt) as f32 } else { 1.0 };
                for ((s, a), b) in self.body_sample.iter_mut().zip(&self.engine_body).zip(body_now) {
                    *s = [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
                }
            }
            // `prev_out` changes only with a step that succeeds, so that a refused one leaves
            // the interpolation as it was.
            self.before_step.copy_from_slice(sim.positions());
            sim.step(&self.body_sample)?;
            core::mem::swap(&mut self.prev_out, &mut self.before_step);
            self.steps += 1;
            self.since_frame = 0.0;
        }
        self.since_frame += dt - elapsed;
        if has_body {
            self.engine_body.copy_from_slice(body_now);
        }
        let alpha = (self.since_frame / MODEL_DT) as f32;
        for ((o, a), b) in self.out.iter_mut().zip(&self.prev_out).zip(sim.positions()) {
            *o = [a[0] + alpha * (b[0] - a[0]), a[1] + alpha * (b[1] - a[1]), a[2] + alpha * (b[2] - a[2])];
        }
        Ok(&self.out)
    }
}
