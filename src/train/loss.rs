//! The training loss of one step: the physics objective (MODEL.md section 6) at the network's
//! predicted positions, with the body queries it needs, and its gradient with respect to those
//! positions (the seed of the network's backward pass).

use crate::body::{BodyFrame, BodyMesh, Nearest};
use crate::error::Result;
use crate::mesh::Garment;
use crate::physics::{Cloth, CollisionInput, FaceFrame, FrictionInput, Objective, StepInputs, Terms};
use crate::solve::{ImplicitStep, LbfgsParams, LbfgsReport, StepBody, StepState};
use alloc::vec;
use alloc::vec::Vec;

/// Buffers for the loss of steps on one garment and one body (reused across steps).
pub struct StepLoss {
    cloth: Cloth<f32>,
    current: BodyFrame,
    next: BodyFrame,
    nearest: Vec<Nearest>,
    nearest_current: Vec<u32>,
    nearest_next: Vec<u32>,
    grad: Vec<[f32; 3]>,
}

/// The body at the two frames the loss reads, m.
#[derive(Clone, Copy, Debug)]
pub struct LossBody<'a> {
    /// Body topology.
    pub mesh: &'a BodyMesh,
    /// Current frame (where the step starts).
    pub current: &'a [[f32; 3]],
    /// Next frame (where the predicted positions are).
    pub next: &'a [[f32; 3]],
}

impl StepLoss {
    /// Buffers for `garment` (its materials and rest shape) on `body`.
    ///
    /// # Errors
    /// Errors of the body frames.
    pub fn new(garment: &Garment, body: &BodyMesh) -> Result<StepLoss> {
        let n = garment.n_vertices();
        Ok(StepLoss {
            cloth: Cloth::new(garment),
            current: BodyFrame::new(body)?,
            next: BodyFrame::new(body)?,
            nearest: vec![Nearest { index: 0, distance: 0.0 }; n],
            nearest_current: vec![0; n],
            nearest_next: vec![0; n],
            grad: vec![[0.0; 3]; n],
        })
    }

    /// The objective's terms at predicted positions `x` for the step from (`pos`, `velocity`)
    /// over `dt` seconds, and `dE/dx` (returned slice, one entry per garment vertex).
    /// Collision: the face nearest to `pos` at the current frame, taken at the next frame.
    /// Friction: frames (current, next).
    ///
    /// # Errors
    /// Size mismatches; non-finite body positions.
    pub fn eval(
        &mut self,
        objective: &Objective,
        body: &LossBody<'_>,
        pos: &[[f32; 3]],
        velocity: &[[f32; 3]],
        dt: f32,
        x: &[[f32; 3]],
    ) -> Result<(Terms<f32>, &[[f32; 3]])> {
        self.current.update(body.mesh, body.current)?;
        self.next.update(body.mesh, body.next)?;
        self.current.nearest_faces(pos, &mut self.nearest)?;
        for (o, n) in self.nearest_current.iter_mut().zip(&self.nearest) {
            *o = n.index;
        }
        self.next.nearest_faces(x, &mut self.nearest)?;
        for (o, n) in self.nearest_next.iter_mut().zip(&self.nearest) {
            *o = n.index;
        }
        let frame_a = FaceFrame { centroids: self.current.centroids(), normals: self.current.face_normals() };
        let frame_b = FaceFrame { centroids: self.next.centroids(), normals: self.next.face_normals() };
        let inputs = StepInputs {
            pos,
            velocity,
            dt,
            collision: Some(CollisionInput { nearest: &self.nearest_current, next: frame_b }),
            friction: Some(FrictionInput {
                frame_a,
                frame_b,
                nearest_a: &self.nearest_current,
                nearest_b: &self.nearest_next,
            }),
        };
        let terms = objective.eval(&self.cloth, &inputs, x, Some(&mut self.grad))?;
        Ok((terms, &self.grad))
    }

    /// The step's optimum `x*` (the implicit step of the physics issue, L-BFGS in f32 under
    /// `params`) into `x_star`, under the same contact rules as [`StepLoss::eval`], whose body
    /// frames it reuses: call `eval` first, for the same step. The L-BFGS starts from the
    /// coasting guess, or, with `from_x_star`, from the positions already in `x_star` (a
    /// prediction to refine).
    ///
    /// # Errors
    /// Errors of [`ImplicitStep::step`].
    #[allow(clippy::too_many_arguments)]
    pub fn optimum(
        &self,
        solver: &mut ImplicitStep<f32>,
        objective: &Objective,
        state: &StepState<'_, f32>,
        params: &LbfgsParams,
        from_x_star: bool,
        x_star: &mut [[f32; 3]],
    ) -> Result<LbfgsReport> {
        let current = FaceFrame { centroids: self.current.centroids(), normals: self.current.face_normals() };
        let next = FaceFrame { centroids: self.next.centroids(), normals: self.next.face_normals() };
        // The training objective's friction reads (current, next): the previous frame is unused.
        let body = StepBody {
            prev: current,
            current,
            next,
            query_prev: &self.current,
            query_current: &self.current,
            query_next: &self.next,
        };
        if from_x_star {
            solver.refine(&self.cloth, objective, state, Some(&body), params, x_star)
        } else {
            solver.step(&self.cloth, objective, state, Some(&body), params, x_star)
        }
    }

    /// Adds the supervised pull toward the optimum, `weight · Σ m_i |x_i − x*_i|² / (2 dt²)`
    /// (the inertia term's metric: weight 1 doubles the objective's curvature in the mass
    /// norm), to the gradient of the last [`StepLoss::eval`]; returns the pull's value.
    pub fn add_pull(&mut self, x: &[[f32; 3]], x_star: &[[f32; 3]], weight: f32, dt: f32) -> f32 {
        let k = weight / (dt * dt);
        let mut value = 0.0f64;
        for (((g, p), q), &m) in self.grad.iter_mut().zip(x).zip(x_star).zip(self.cloth.mass()) {
            for c in 0..3 {
                let d = p[c] - q[c];
                g[c] += k * m * d;
                value += 0.5 * f64::from(k * m * d * d);
            }
        }
        value as f32
    }

    /// The gradient of the last [`StepLoss::eval`] (with any pull added).
    pub fn grad(&self) -> &[[f32; 3]] {
        &self.grad
    }
}
