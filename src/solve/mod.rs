//! Solvers on the physics objective: L-BFGS, the implicit reference step, rest-shape relaxation
//! and collision push-out.
//!
//! The implicit step is a real (slow) cloth simulator: it minimises the full objective over the
//! next positions, which gives the lowest objective a step can reach, the yardstick of every
//! model's accuracy (EVALUATION.md "Distance to the optimum").

mod implicit;
mod lbfgs;
mod push_out;
mod relax;

pub use implicit::{ImplicitStep, Query, StepBody, StepState};
pub use lbfgs::{Lbfgs, LbfgsParams, LbfgsReport, Termination};
pub use push_out::{push_out, push_out_of, INITIAL_CLEARANCE};
pub use relax::{relax_rest_shape, RestBody};

#[cfg(test)]
mod tests;
