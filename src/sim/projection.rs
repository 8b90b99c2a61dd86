//! Collision projection: an optional post-step push-out of garment vertices that end up in (or
//! too close to) the body. Not part of HOOD (its network alone keeps the cloth out); engines that
//! must never show skin through cloth turn it on, and pay one nearest-face search per step.
//!
//! A vertex is tested against the face whose centroid is nearest to it at the new frame, as the
//! collision term of MODEL.md section 6 measures penetration (there with the face chosen at the
//! current frame): when its distance to that face's plane is below the margin, it moves along the
//! face's normal to the margin, and its velocity takes the same move, so the next step sees the
//! cloth where it was put.

use super::body_query::BodyFaces;
use crate::body::Nearest;
use crate::error::{Error, Result};
use crate::exec::Executor;
use crate::physics::push_out;
use alloc::vec;
use alloc::vec::Vec;

/// How far (m) from its nearest body face centroid a vertex may be and still be projected:
/// beyond it the plane of the nearest face says little about inside and outside (a hem far
/// below the hips can lie behind the plane of a thigh face), so the vertex is left alone.
pub const PROJECTION_REACH: f32 = 0.05;

/// Default projection margin (m): the training collision term's eps (MODEL.md section 6), twice
/// the 1 mm within which evaluation counts a vertex as penetrating.
pub const DEFAULT_PROJECTION_MARGIN: f32 = 2e-3;

/// Buffers of the projection, sized once for one body and one garment.
#[derive(Clone, Debug)]
pub(super) struct Projection {
    margin: f32,
    nearest: Vec<Option<Nearest>>,
    /// Last step's nearest face of every garment vertex (`u32::MAX`: none): only a search hint.
    hints: Vec<u32>,
    /// Vertices moved by the last [`apply`](Self::apply).
    moved: usize,
}

impl Projection {
    /// Projection onto the faces of `mesh` for `n_garment` vertices, with `margin` metres.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a margin that is negative, not finite, or not below
    /// [`PROJECTION_REACH`].
    pub(super) fn new(n_garment: usize, margin: f32) -> Result<Projection> {
        if !(0.0..PROJECTION_REACH).contains(&margin) {
            return Err(Error::OutOfRange { what: "collision projection margin (0 <= m < reach)", index: 0 });
        }
        Ok(Projection { margin, nearest: vec![None; n_garment], hints: vec![u32::MAX; n_garment], moved: 0 })
    }

    /// Vertices moved by the last step.
    pub(super) fn moved(&self) -> usize {
        self.moved
    }

    /// Puts back the count `moved` of the last step that ran (a refused step changed it).
    pub(super) fn restore_last(&mut self, moved: usize) {
        self.moved = moved;
    }

    /// Forgets the last count: the sim's last step projected nothing (it slept or teleported)
    /// or no step has run from its state.
    pub(super) fn forget_last(&mut self) {
        self.moved = 0;
    }

    /// Pushes every free vertex of `pos` (m) out of the body, whose `faces` are those of the
    /// frame `pos` belongs to, adding each move to `velocity` too. Pinned vertices stay.
    /// Allocates nothing.
    ///
    /// # Errors
    /// Size mismatches of the grid query (none for the buffers of [`new`](Self::new)).
    pub(super) fn apply(
        &mut self,
        exec: &dyn Executor,
        faces: BodyFaces<'_>,
        pinned: &[bool],
        pos: &mut [[f32; 3]],
        velocity: &mut [[f32; 3]],
    ) -> Result<()> {
        let BodyFaces { frame, grid } = faces;
        grid.nearest_within_on(exec, pos, PROJECTION_REACH, &self.hints, &mut self.nearest)?;
        let mut moved = 0;
        for (i, near) in self.nearest.iter().enumerate() {
            let Some(near) = near else { continue };
            self.hints[i] = near.index;
            if pinned[i] {
                continue;
            }
            let d = push_out(pos[i], near.index as usize, frame, self.margin);
            if d != [0.0; 3] {
                for k in 0..3 {
                    pos[i][k] += d[k];
                    velocity[i][k] += d[k];
                }
                moved += 1;
            }
        }
        self.moved = moved;
        Ok(())
    }
}
