//! The objective: the sum of the terms a scene enables, each reported separately.

use super::{bending, check_len, collision, friction, gravity, inertia, stretching, Cloth, FrictionParams};
use crate::error::{Error, Result};
use crate::math::Real;

use super::FaceFrame;

/// Collision penalty parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionParams {
    /// Target clearance from the face plane, m.
    pub eps: f64,
    /// Weight of the cubic penalty.
    pub weight: f64,
}

impl CollisionParams {
    /// The evaluation form: eps 1e-3 m, weight 1.
    pub const EVALUATION: CollisionParams = CollisionParams { eps: 1e-3, weight: 1.0 };

    /// The training form: eps 2e-3 m with the given (ramped, 5e3 → 5e5) weight.
    pub fn training(weight: f64) -> CollisionParams {
        CollisionParams { eps: 2e-3, weight }
    }
}

/// What the collision term reads besides `x`.
#[derive(Clone, Copy, Debug)]
pub struct CollisionInput<'a, T> {
    /// Per garment vertex, the body face whose centroid is nearest at the current frame.
    pub nearest: &'a [u32],
    /// The body faces at the next frame.
    pub next: FaceFrame<'a, T>,
}

/// What the friction term reads besides `pos` and `x` (see [`friction()`]).
#[derive(Clone, Copy, Debug)]
pub struct FrictionInput<'a, T> {
    /// Body faces at frame `B_a`.
    pub frame_a: FaceFrame<'a, T>,
    /// Body faces at frame `B_b`.
    pub frame_b: FaceFrame<'a, T>,
    /// Nearest face centroid at `B_a` of every current position `pos`.
    pub nearest_a: &'a [u32],
    /// Nearest face centroid at `B_b` of every predicted position `x`.
    pub nearest_b: &'a [u32],
}

/// The state a step starts from, and the body data of the enabled contact terms.
#[derive(Clone, Copy, Debug)]
pub struct StepInputs<'a, T> {
    /// Garment positions at the current frame, m (may be empty when neither inertia nor
    /// friction is enabled).
    pub pos: &'a [[T; 3]],
    /// Garment velocity, m/frame (may be empty when inertia is disabled).
    pub velocity: &'a [[T; 3]],
    /// Time step, s.
    pub dt: T,
    /// Needed when the collision term is enabled.
    pub collision: Option<CollisionInput<'a, T>>,
    /// Needed when the friction term is enabled.
    pub friction: Option<FrictionInput<'a, T>>,
}

/// The value of every term (J; collision in penalty units). Disabled terms are 0.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Terms<T> {
    /// Stretching energy.
    pub stretching: T,
    /// Bending energy.
    pub bending: T,
    /// Inertia.
    pub inertia: T,
    /// Gravitational energy.
    pub gravity: T,
    /// Weighted collision penalty.
    pub collision: T,
    /// Friction energy.
    pub friction: T,
}

impl<T: Real> Terms<T> {
    /// The plain sum of the terms.
    pub fn total(&self) -> T {
        self.stretching + self.bending + self.inertia + self.gravity + self.collision + self.friction
    }

    /// The terms in `f64`.
    pub fn to_f64(&self) -> Terms<f64> {
        Terms {
            stretching: self.stretching.to_f64(),
            bending: self.bending.to_f64(),
            inertia: self.inertia.to_f64(),
            gravity: self.gravity.to_f64(),
            collision: self.collision.to_f64(),
            friction: self.friction.to_f64(),
        }
    }

    /// The terms as `(name, value)` pairs, in a fixed order.
    pub fn named(&self) -> [(&'static str, T); 6] {
        [
            ("stretching", self.stretching),
            ("bending", self.bending),
            ("inertia", self.inertia),
            ("gravity", self.gravity),
            ("collision", self.collision),
            ("friction", self.friction),
        ]
    }
}

/// Which terms a scene enables, with their parameters. Stateless: evaluate with [`Objective::eval`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Objective {
    /// StVK stretching.
    pub stretching: bool,
    /// Dihedral bending.
    pub bending: bool,
    /// Inertia.
    pub inertia: bool,
    /// Gravity.
    pub gravity: bool,
    /// Collision penalty, when enabled.
    pub collision: Option<CollisionParams>,
    /// Friction, when enabled.
    pub friction: Option<FrictionParams>,
}

impl Objective {
    /// Every term, collision at eps 2e-3 m with `collision_weight`, physical friction.
    pub fn training(collision_weight: f64) -> Objective {
        Objective {
            stretching: true,
            bending: true,
            inertia: true,
            gravity: true,
            collision: Some(CollisionParams::training(collision_weight)),
            friction: Some(FrictionParams::PHYSICAL),
        }
    }

    /// The evaluation form (EVALUATION.md): every term, collision at eps 1e-3 m and weight 1,
    /// physical friction.
    pub fn evaluation() -> Objective {
        Objective { collision: Some(CollisionParams::EVALUATION), ..Objective::training(1.0) }
    }

    /// Rest-shape relaxation: stretching, bending, gravity and collision (eps 2e-3 m with
    /// `collision_weight`); no inertia, no friction.
    pub fn relaxation(collision_weight: f64) -> Objective {
        Objective { inertia: false, friction: None, ..Objective::training(collision_weight) }
    }

    /// Only the cloth's own terms (stretching, bending, inertia, gravity): scenes without a body.
    pub fn cloth_only() -> Objective {
        Objective { collision: None, friction: None, ..Objective::training(1.0) }
    }

    /// Evaluates every enabled term at `x` (m). When `grad` is given it is **overwritten** with
    /// `dE_total/dx`. Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for buffers of the wrong length; [`Error::Empty`] when an enabled
    /// contact term has no input; [`Error::IndexOutOfRange`] for a bad nearest-face index.
    pub fn eval<T: Real>(
        &self,
        cloth: &Cloth<T>,
        inputs: &StepInputs<'_, T>,
        x: &[[T; 3]],
        mut grad: Option<&mut [[T; 3]]>,
    ) -> Result<Terms<T>> {
        check_len("positions", x.len(), cloth.n_vertices())?;
        if let Some(g) = grad.as_deref_mut() {
            check_len("gradient", g.len(), cloth.n_vertices())?;
            g.iter_mut().for_each(|v| *v = [T::ZERO; 3]);
        }
        let mut t = Terms::<T>::default();
        if self.stretching {
            t.stretching = stretching(cloth, x, grad.as_deref_mut())?;
        }
        if self.bending {
            t.bending = bending(cloth, x, grad.as_deref_mut())?;
        }
        if self.inertia {
            t.inertia = inertia(cloth, inputs.pos, inputs.velocity, inputs.dt, x, grad.as_deref_mut())?;
        }
        if self.gravity {
            t.gravity = gravity(cloth, x, grad.as_deref_mut())?;
        }
        if let Some(p) = &self.collision {
            let c = inputs.collision.ok_or(Error::Empty { what: "collision input" })?;
            t.collision =
                collision(x, c.nearest, c.next, T::from_f64(p.eps), T::from_f64(p.weight), grad.as_deref_mut())?;
        }
        if let Some(p) = &self.friction {
            let f = inputs.friction.ok_or(Error::Empty { what: "friction input" })?;
            t.friction = friction(cloth, inputs.pos, x, f.frame_a, f.frame_b, f.nearest_a, f.nearest_b, p, grad)?;
        }
        Ok(t)
    }
}
