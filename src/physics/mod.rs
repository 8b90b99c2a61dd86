//! The physics objective (MODEL.md section 6): energy terms with analytic gradients, the
//! objective that sums them, and the evaluation metrics (EVALUATION.md "Accuracy").
//!
//! Every term is generic over [`Real`](crate::math::Real) so the same code runs in `f32` (runtime, trainer) and
//! `f64` (gradient checks, reference solves). Terms take plain slices (garment positions, body
//! face centroids and normals, nearest-face indices), **add** their gradient with respect to the
//! predicted positions `x` into a caller buffer, and allocate nothing.
//!
//! Per-vertex materials: a triangle uses the mean of its three vertices' `mu` and `lambda`, a
//! bending hinge the mean of its two edge vertices' `k_bend`; masses are per vertex already.
//!
//! Units: metres, kilograms, seconds; energies in joules (the collision penalty in its own units,
//! weight × m³); `dt` in seconds; velocities in metres per frame (as in HOOD).
//!
//! * Terms: [`stretching()`], [`bending()`], [`inertia()`], [`gravity()`], [`collision()`],
//!   [`friction()`]; garment constants precomputed once in [`Cloth`] (rest frames, or separate
//!   2D rest triangles with [`Cloth::with_rest_2d`]).
//! * [`Objective`]: which terms a scene enables ([`Objective::training`],
//!   [`Objective::evaluation`], [`Objective::relaxation`], [`Objective::cloth_only`]), evaluated
//!   with [`Objective::eval`] into [`Terms`], or as tasks of an executor with
//!   [`ObjectiveTasks`] (the same bits for any number of threads).
//! * Body data: [`face_frames`] (centroids and unit normals per face); nearest face centroids
//!   through [`CentroidQuery`], implemented by the body module's
//!   [`PointGrid`](crate::body::PointGrid) and [`BodyFrame`](crate::body::BodyFrame), and by
//!   [`BruteForceCentroids`].
//! * Friction's three reference quirks are [`FrictionParams`] fields:
//!   [`FrictionParams::PHYSICAL`] (hood) and [`FrictionParams::REFERENCE`] (postcvpr).
//! * Metrics: [`score_rollout`] (per-frame and mean terms, % penetrating vertices, largest edge
//!   strain, largest speed).
//! * Solvers on this objective (L-BFGS, implicit step, relaxation, push-out): [`crate::solve`].

mod bending;
mod cloth;
mod collision;
mod friction;
mod inertia;
mod metrics;
mod objective;
mod stretching;
mod tasks;

pub use bending::bending;
pub use cloth::{BendHinge, Cloth};
pub use collision::{
    collision, face_frames, plane_distance, plane_distances, push_out, BruteForceCentroids, CentroidQuery, FaceFrame,
};
pub use friction::{friction, within_friction_radius, FrictionFrames, FrictionParams, RadiusMode};
pub use inertia::{gravity, inertia};
pub use metrics::{
    max_edge_strain, max_edge_strains, quarter_median_edge_length, score_rollout, score_rollout_with, FrameScore,
    RolloutScore, PENETRATION_DEPTH,
};
pub use objective::{CollisionInput, CollisionParams, FrictionInput, Objective, StepInputs, Terms};
pub use stretching::stretching;
pub use tasks::ObjectiveTasks;

/// Thickness factor of the stretching energy (the reference's StVK thickness), metres.
pub const THICKNESS: f64 = 4.7e-4;
/// Gravitational acceleration, m/s², acting along -y.
pub const GRAVITY: f64 = 9.81;

pub(crate) use crate::error::check_len;

#[cfg(all(test, feature = "tools"))]
mod parity_tests;
#[cfg(test)]
mod tests;
