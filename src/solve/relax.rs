//! Rest-shape relaxation (supplement section 1.2): relax an overly tight or smooth rest shape by
//! minimising stretching against separate 2D rest triangles, bending, gravity and collision with
//! the body in its rest pose (no inertia, no friction).

use super::{Lbfgs, LbfgsParams, LbfgsReport};
use crate::error::Result;
use crate::math::Real;
use crate::mesh::Garment;
use crate::physics::{check_len, CentroidQuery, Cloth, CollisionInput, FaceFrame, Objective, StepInputs};
use alloc::vec;

/// The body in its rest pose, for [`relax_rest_shape`].
#[derive(Clone, Copy)]
pub struct RestBody<'a, T> {
    /// Body faces (centroids and unit normals).
    pub faces: FaceFrame<'a, T>,
    /// Nearest-centroid query over the same centroids.
    pub query: &'a dyn CentroidQuery,
}

/// Relaxes the garment shape `x` (initial guess in, result out, m) against the 2D rest triangles
/// `rest_2d` (one point per vertex, m; e.g. the UV layout): minimises stretching (rest frames
/// from `rest_2d`), bending, gravity and, with a body, collision (eps 2e-3 m, weight
/// `collision_weight`). The garment's pinned vertices stay where they are in `x`. The nearest
/// body faces are recomputed from the current shape in `rounds` successive minimisations.
/// Without a body or pinned vertices gravity is unbounded below: give one or the other.
///
/// # Errors
/// See [`Cloth::with_rest_2d`]; [`crate::Error::SizeMismatch`] for `x` of the wrong length.
pub fn relax_rest_shape<T: Real>(
    garment: &Garment,
    rest_2d: &[[f32; 2]],
    body: Option<&RestBody<'_, T>>,
    collision_weight: f64,
    rounds: usize,
    params: &LbfgsParams,
    x: &mut [[T; 3]],
) -> Result<LbfgsReport> {
    let cloth = Cloth::<T>::with_rest_2d(garment, rest_2d)?;
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    let mut objective = Objective::relaxation(collision_weight);
    if body.is_none() {
        objective.collision = None;
    }
    let pinned = garment.pinned();
    let mut lbfgs = Lbfgs::<T>::new(n, 10);
    let mut diag = vec![T::ZERO; n];
    cloth.stretch_stiffness_into(&mut diag)?;
    diag.iter_mut().for_each(|d| *d = T::ONE / *d);
    lbfgs.set_preconditioner(Some(&diag))?;
    let mut nearest = vec![0u32; n];
    let mut x32 = vec![[0.0f32; 3]; n];
    let mut round = |x: &mut [[T; 3]]| -> Result<LbfgsReport> {
        if let Some(b) = body {
            for (o, p) in x32.iter_mut().zip(x.iter()) {
                *o = p.map(|c| c.to_f64() as f32);
            }
            b.query.nearest_into(&x32, &mut nearest);
        }
        lbfgs.minimize(x, params, |y, grad| {
            let inputs = StepInputs {
                pos: &[],
                velocity: &[],
                dt: T::ONE,
                collision: body.map(|b| CollisionInput { nearest: &nearest, next: b.faces }),
                friction: None,
            };
            let t = objective.eval(&cloth, &inputs, y, Some(grad))?;
            for (g, &p) in grad.iter_mut().zip(pinned) {
                if p {
                    *g = [T::ZERO; 3];
                }
            }
            Ok(t.total())
        })
    };
    let mut report = round(x)?;
    for _ in 1..rounds {
        // A new round only matters when the nearest faces may have changed.
        if body.is_none() || (report.converged() && report.iterations <= 1) {
            break;
        }
        report = round(x)?;
    }
    Ok(report)
}
