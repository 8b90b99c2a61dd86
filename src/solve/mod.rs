//! Solvers on the physics objective: L-BFGS, the implicit reference step, rest-shape relaxation
//! and collision push-out.
