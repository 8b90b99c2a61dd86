//! Several garments on one body: a sim per garment (each with its own model, configuration and
//! step mode), stepped together on the same body frames, sharing the body's grids and normals so
//! that each frame's body structures are built once, not once per garment. Garments do not
//! collide with each other (as in HOOD, each knows only the body).
//!
//! ```
//! use hood::body::BodyMesh;
//! use hood::mesh::{Garment, GarmentDesc};
//! use hood::model::ModelBytes;
//! use hood::sim::{BodyDesc, Outfit, Sim, SimConfig};
//!
//! // Two squares of cloth, 0.4 m and 0.2 m, held over a tetrahedron "body".
//! let square = |n: u32, side: f32, y: f32| -> hood::Result<Garment> {
//!     let h = side / (n - 1) as f32;
//!     let rest: Vec<[f32; 3]> =
//!         (0..n * n).map(|i| [(i % n) as f32 * h - side / 2.0, y, (i / n) as f32 * h - side / 2.0]).collect();
//!     let faces: Vec<[u32; 3]> = (0..(n - 1) * (n - 1))
//!         .map(|q| q + q / (n - 1))
//!         .flat_map(|v| [[v, v + n, v + 1], [v + 1, v + n, v + n + 1]])
//!         .collect();
//!     Garment::new(GarmentDesc::new(&rest, &faces))
//! };
//! let body = BodyMesh::new(4, &[[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])?;
//! let mut frame = vec![[-0.4, 0.0, -0.4], [0.4, 0.0, -0.4], [0.0, 0.0, 0.4], [0.0, 1.0, 0.0]];
//! let bytes = ModelBytes::read(concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood"))?;
//! let model = bytes.model()?;
//! let desc = BodyDesc { mesh: &body, positions: &frame };
//! let mut outfit = Outfit::new(vec![
//!     Sim::new(&model, &square(9, 0.4, 1.1)?, Some(desc), SimConfig::default())?, // the solver
//!     Sim::new(&model, &square(5, 0.2, 1.3)?, Some(desc), SimConfig::network())?, // HOOD's network
//! ])?;
//! for _ in 0..10 {
//!     frame.iter_mut().for_each(|p| p[0] += 0.01);
//!     outfit.step(&frame)?; // both garments, the body's grids built once
//! }
//! assert!(outfit.positions(1)?.iter().flatten().all(|c| c.is_finite()));
//! # Ok::<(), hood::Error>(())
//! ```

use super::body_query::{BodyNeeds, BodyQuery};
use super::{copy_state, LastStepFigures, Sim, SimState};
use crate::error::{Error, Result};
use alloc::vec::Vec;

/// What a garment's step changed besides its state, restored with it when another garment's
/// step of the same frame is refused.
struct Before {
    state: SimState,
    rest_frames: u32,
    last_carry: [f32; 3],
    /// Moved by an automatic teleport.
    pin_targets: Vec<[f32; 3]>,
    /// What the garment's accessors reported about its last step.
    figures: LastStepFigures,
}

/// Garments on one body, stepped together. Allocates nothing per step.
pub struct Outfit<'m> {
    sims: Vec<Sim<'m>>,
    /// The body's structures, shared by every garment (`None` when no garment reads the body).
    query: Option<BodyQuery>,
    /// Each garment before the step in progress.
    before: Vec<Before>,
}

impl<'m> Outfit<'m> {
    /// The garments of `sims` on one body. Each sim must have a body (or none, for every one
    /// of them) of the same [`crate::body::BodyMesh`] at the same current frame (bit for bit):
    /// sims made from the same [`super::BodyDesc`], or stepped together since.
    ///
    /// # Errors
    /// [`Error::Empty`] for no sims; [`Error::OutOfRange`] naming the first sim on another body
    /// or at another frame; errors of the shared query's buffers.
    pub fn new(mut sims: Vec<Sim<'m>>) -> Result<Outfit<'m>> {
        let first = sims.first().ok_or(Error::Empty { what: "outfit garments" })?;
        let (mesh, at) = (first.body.as_ref().map(|b| &b.mesh), &first.state.body_pos);
        for (i, sim) in sims.iter().enumerate().skip(1) {
            let same_frame = bytemuck::cast_slice::<_, u32>(&sim.state.body_pos) == bytemuck::cast_slice::<_, u32>(at);
            if sim.body.as_ref().map(|b| &b.mesh) != mesh || !same_frame {
                return Err(Error::OutOfRange { what: "outfit garment on another body or frame", index: i });
            }
        }
        let needs = sims.iter().fold(BodyNeeds::default(), |n, s| n.union(s.needs));
        let query = match mesh {
            Some(m) if !needs.none() => Some(BodyQuery::new(m, needs)?),
            _ => None,
        };
        let before = sims
            .iter()
            .map(|s| Before {
                state: s.state.clone(),
                rest_frames: 0,
                last_carry: [0.0; 3],
                pin_targets: s.pin_targets.clone(),
                figures: s.last_step_figures(),
            })
            .collect();
        // Each sim's own query is now the shared one.
        for sim in &mut sims {
            sim.query = None;
        }
        Ok(Outfit { sims, query, before })
    }

    /// The garments' sims, in the order given.
    pub fn sims(&self) -> &[Sim<'m>] {
        &self.sims
    }

    /// Garment `i`'s positions (m).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for no garment `i`.
    pub fn positions(&self, i: usize) -> Result<&[[f32; 3]]> {
        self.sim(i).map(Sim::positions)
    }

    /// Targets of garment `i`'s pinned vertices at the next frame, as [`Sim::set_pin_targets`].
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for no garment `i`; errors of [`Sim::set_pin_targets`].
    pub fn set_pin_targets(&mut self, i: usize, targets: &[[f32; 3]]) -> Result<()> {
        self.sims.get_mut(i).ok_or(Error::OutOfRange { what: "outfit garment", index: i })?.set_pin_targets(targets)
    }

    /// Grids the shared body query has built so far: one per body frame (two for the solver's
    /// two frames at the first step) however many garments read it.
    pub fn body_builds(&self) -> u64 {
        self.query.as_ref().map_or(0, BodyQuery::builds)
    }

    /// Advances every garment one frame, with `body_next` the body's vertices at the next frame
    /// (ignored, and may be empty, without a body), in the order of the sims.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] or [`Error::NonFinite`] for bad body input, before any garment
    /// steps; any garment's step error (the garment is named nowhere: step that sim alone to
    /// find it). On error every garment is as before the call, as after a refused step of a sim
    /// alone: those that had stepped are put back, and so is what they report about their last
    /// step ([`Sim::last_effects`], [`Sim::last_step_flops`] and the like).
    pub fn step(&mut self, body_next: &[[f32; 3]]) -> Result<()> {
        // Once for all garments (they share the body), before any steps.
        self.sims[0].check_body_frame(body_next)?;
        for (k, sim) in self.sims.iter_mut().enumerate() {
            let before = &mut self.before[k];
            copy_state(&mut before.state, &sim.state);
            before.rest_frames = sim.rest_frames;
            before.last_carry = sim.last_carry;
            before.pin_targets.copy_from_slice(&sim.pin_targets);
            before.figures = sim.last_step_figures();
            // The figures just kept serve this garment's own refusal as well as the put-back of
            // those that stepped before it: one snapshot per garment and frame.
            if let Err(e) = sim.step_frame(self.query.as_mut(), body_next, None) {
                sim.restore_last_step_figures(before.figures);
                for (done, before) in self.sims[..k].iter_mut().zip(&self.before) {
                    copy_state(&mut done.state, &before.state);
                    done.rest_frames = before.rest_frames;
                    done.last_carry = before.last_carry;
                    done.pin_targets.copy_from_slice(&before.pin_targets);
                    done.restore_last_step_figures(before.figures);
                    done.update_output_normals();
                }
                return Err(e);
            }
        }
        Ok(())
    }

    /// Garment `i`'s sim.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for no garment `i`.
    pub fn sim(&self, i: usize) -> Result<&Sim<'m>> {
        self.sims.get(i).ok_or(Error::OutOfRange { what: "outfit garment", index: i })
    }

    /// The sims back, each with its own body query again (this allocates).
    ///
    /// # Errors
    /// Errors of the queries' buffers.
    pub fn into_sims(self) -> Result<Vec<Sim<'m>>> {
        let mut sims = self.sims;
        for sim in &mut sims {
            if let (Some(b), false) = (&sim.body, sim.needs.none()) {
                sim.query = Some(BodyQuery::new(&b.mesh, sim.needs)?);
            }
        }
        Ok(sims)
    }
}
