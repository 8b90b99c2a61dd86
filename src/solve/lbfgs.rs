//! Limited-memory BFGS over vertex positions, with a backtracking Armijo line search that only
//! accepts steps that decrease the objective. All buffers live in a reusable [`Lbfgs`]
//! workspace: nothing is allocated per iteration.

use crate::error::{Error, Result};
use crate::math::Real;
use alloc::vec;
use alloc::vec::Vec;

/// Stopping rules and line-search constants.
///
/// Built from [`Default`] and the `with_` methods (new fields may come, so it has no struct
/// literal outside this crate).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct LbfgsParams {
    /// Iteration cap (an iteration = one accepted step).
    pub max_iterations: usize,
    /// Stop when the largest gradient component is at most this (objective units per metre).
    pub grad_tol: f64,
    /// Stop when the last step's decrease `f_k - f_{k+1}` is at most this fraction of the total
    /// decrease so far `f_0 - f_{k+1}` (invariant to constant offsets of the objective, such as
    /// the gravitational energy of the garment's height).
    pub rel_decrease_tol: f64,
    /// Armijo sufficient-decrease constant `c1`.
    pub armijo: f64,
    /// Most objective evaluations in one line search before giving up.
    pub max_line_search: usize,
    /// Longest first step along the steepest-descent direction, in metres of the largest
    /// vertex move (the first iteration has no curvature information to scale it). Not used
    /// with a preconditioner, whose first step `-P g` is already scaled.
    pub first_step: f64,
}

impl Default for LbfgsParams {
    fn default() -> Self {
        LbfgsParams {
            max_iterations: 200,
            grad_tol: 1e-6,
            rel_decrease_tol: 1e-10,
            armijo: 1e-4,
            max_line_search: 30,
            first_step: 1e-3,
        }
    }
}

impl LbfgsParams {
    with_fields! {
        /// Sets [`max_iterations`](Self::max_iterations): the iteration cap.
        with_max_iterations => max_iterations: usize;
        /// Sets [`grad_tol`](Self::grad_tol): the gradient tolerance, objective units per metre.
        with_grad_tol => grad_tol: f64;
        /// Sets [`rel_decrease_tol`](Self::rel_decrease_tol): the relative decrease tolerance.
        with_rel_decrease_tol => rel_decrease_tol: f64;
        /// Sets [`armijo`](Self::armijo): the Armijo sufficient-decrease constant.
        with_armijo => armijo: f64;
        /// Sets [`max_line_search`](Self::max_line_search): evaluations per line search.
        with_max_line_search => max_line_search: usize;
        /// Sets [`first_step`](Self::first_step): the longest first step, metres.
        with_first_step => first_step: f64;
    }
}

/// Why the minimisation stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// The gradient fell below `grad_tol`.
    Gradient,
    /// The last step's decrease fell below `rel_decrease_tol` of the total decrease.
    RelativeDecrease,
    /// `max_iterations` reached.
    MaxIterations,
    /// The caller's stop rule said stop (a time budget, see [`Lbfgs::minimize_until`]).
    Stopped,
    /// No step along the search direction decreased the objective (at numerical precision).
    LineSearch,
}

/// The outcome of [`Lbfgs::minimize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LbfgsReport {
    /// Accepted steps.
    pub iterations: usize,
    /// Objective evaluations (each with its gradient).
    pub evaluations: usize,
    /// Objective at the start.
    pub f_start: f64,
    /// Objective at the returned point.
    pub f: f64,
    /// Largest gradient component at the returned point.
    pub grad_max: f64,
    /// Why it stopped.
    pub termination: Termination,
}

impl LbfgsReport {
    /// True when a convergence criterion (gradient or relative decrease) was met.
    pub fn converged(&self) -> bool {
        matches!(self.termination, Termination::Gradient | Termination::RelativeDecrease)
    }
}

/// L-BFGS workspace for problems of `n` vertices (3 unknowns each) with `memory` correction
/// pairs.
#[derive(Clone, Debug)]
pub struct Lbfgs<T: Real> {
    n: usize,
    memory: usize,
    s: Vec<[T; 3]>,
    y: Vec<[T; 3]>,
    rho: Vec<T>,
    alpha: Vec<T>,
    g: Vec<[T; 3]>,
    g_new: Vec<[T; 3]>,
    d: Vec<[T; 3]>,
    x_new: Vec<[T; 3]>,
    /// Inverse diagonal preconditioner per vertex (same for x, y, z); empty: identity.
    precond: Vec<T>,
}

fn dot<T: Real>(a: &[[T; 3]], b: &[[T; 3]]) -> T {
    let mut acc = T::ZERO;
    for (p, q) in a.iter().zip(b) {
        acc += p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    }
    acc
}

/// `a += s b`.
fn axpy<T: Real>(a: &mut [[T; 3]], s: T, b: &[[T; 3]]) {
    for (p, q) in a.iter_mut().zip(b) {
        for k in 0..3 {
            p[k] += s * q[k];
        }
    }
}

fn max_abs<T: Real>(a: &[[T; 3]]) -> T {
    let mut m = T::ZERO;
    for p in a {
        for &c in p {
            m = m.max(c.abs());
        }
    }
    m
}

impl<T: Real> Lbfgs<T> {
    /// A workspace for `n` vertices keeping `memory` (≥ 1) correction pairs.
    pub fn new(n: usize, memory: usize) -> Lbfgs<T> {
        let memory = memory.max(1);
        let z = [T::ZERO; 3];
        Lbfgs {
            n,
            memory,
            s: vec![z; n * memory],
            y: vec![z; n * memory],
            rho: vec![T::ZERO; memory],
            alpha: vec![T::ZERO; memory],
            g: vec![z; n],
            g_new: vec![z; n],
            d: vec![z; n],
            x_new: vec![z; n],
            // Room for a preconditioner now, so that setting one in a step allocates nothing.
            precond: Vec::with_capacity(n),
        }
    }

    /// Sets (or, with `None`, clears) a diagonal preconditioner: the inverse of an estimate of
    /// the Hessian's diagonal, one positive value per vertex (same for its three coordinates).
    /// The initial inverse Hessian becomes `γ P` instead of `γ I`, and the first step is `-P g`.
    /// Allocates nothing (the workspace has room for one).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for a slice of the wrong length; [`Error::OutOfRange`] for a
    /// non-positive or non-finite value (naming the vertex).
    pub fn set_preconditioner(&mut self, inverse_diagonal: Option<&[T]>) -> Result<()> {
        match inverse_diagonal {
            None => self.precond.clear(),
            Some(p) => {
                if p.len() != self.n {
                    return Err(Error::SizeMismatch { what: "preconditioner", expected: self.n, got: p.len() });
                }
                if let Some(i) = p.iter().position(|v| !(v.is_finite() && *v > T::ZERO)) {
                    return Err(Error::OutOfRange { what: "preconditioner entry", index: i });
                }
                self.precond.clear();
                self.precond.extend_from_slice(p);
            }
        }
        Ok(())
    }

    /// Number of vertices this workspace is sized for.
    pub fn n_vertices(&self) -> usize {
        self.n
    }

    /// Minimises `f` from `x` (overwritten with the result). `f(x, grad)` returns the objective
    /// and writes its gradient into `grad` (overwriting it). Steps that would not decrease `f`
    /// are never taken. Allocates nothing.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `x` does not have the workspace's length; errors of `f`
    /// are passed through; [`Error::NonFinite`] when `f` is not finite at the start.
    pub fn minimize(
        &mut self,
        x: &mut [[T; 3]],
        params: &LbfgsParams,
        f: impl FnMut(&[[T; 3]], &mut [[T; 3]]) -> Result<T>,
    ) -> Result<LbfgsReport> {
        self.minimize_until(x, params, f, &mut || false)
    }

    /// As [`Lbfgs::minimize`], also stopping ([`Termination::Stopped`]) when `stop()` says so,
    /// asked before every iteration after the first (so at least one is taken): a time budget
    /// reads a clock there. Allocates nothing.
    ///
    /// # Errors
    /// As [`Lbfgs::minimize`].
    pub fn minimize_until(
        &mut self,
        x: &mut [[T; 3]],
        params: &LbfgsParams,
        mut f: impl FnMut(&[[T; 3]], &mut [[T; 3]]) -> Result<T>,
        stop: &mut dyn FnMut() -> bool,
    ) -> Result<LbfgsReport> {
        if x.len() != self.n {
            return Err(Error::SizeMismatch { what: "L-BFGS unknowns", expected: self.n, got: x.len() });
        }
        let n = self.n;
        let mut fx = f(x, &mut self.g)?;
        if !fx.is_finite() {
            return Err(Error::NonFinite { what: "objective at the starting point", index: 0 });
        }
        let mut evaluations = 1;
        let f_start = fx.to_f64();
        let c1 = T::from_f64(params.armijo);
        let (mut stored, mut head) = (0usize, 0usize); // ring buffer of correction pairs
        let mut iterations = 0;
        let termination = loop {
            let gmax = max_abs(&self.g);
            if gmax.to_f64() <= params.grad_tol {
                break Termination::Gradient;
            }
            if iterations >= params.max_iterations {
                break Termination::MaxIterations;
            }
            if iterations > 0 && stop() {
                break Termination::Stopped;
            }
            // Two-loop recursion: d = -H g.
            self.d.copy_from_slice(&self.g);
            for j in 0..stored {
                let k = (head + self.memory - 1 - j) % self.memory;
                let (s, y) = (&self.s[k * n..(k + 1) * n], &self.y[k * n..(k + 1) * n]);
                let a = self.rho[k] * dot(s, &self.d);
                self.alpha[k] = a;
                axpy(&mut self.d, -a, y);
            }
            let mut step = T::ONE;
            let preconditioned = !self.precond.is_empty();
            if preconditioned {
                self.d.iter_mut().zip(&self.precond).for_each(|(p, &w)| *p = p.map(|c| c * w));
            }
            if stored > 0 {
                let k = (head + self.memory - 1) % self.memory;
                let (s, y) = (&self.s[k * n..(k + 1) * n], &self.y[k * n..(k + 1) * n]);
                let ypy = if preconditioned {
                    let mut acc = T::ZERO;
                    for (q, &w) in y.iter().zip(&self.precond) {
                        acc += (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]) * w;
                    }
                    acc
                } else {
                    dot(y, y)
                };
                let gamma = dot(s, y) / ypy;
                self.d.iter_mut().for_each(|p| *p = p.map(|c| c * gamma));
                for j in (0..stored).rev() {
                    let k = (head + self.memory - 1 - j) % self.memory;
                    let (s, y) = (&self.s[k * n..(k + 1) * n], &self.y[k * n..(k + 1) * n]);
                    let b = self.rho[k] * dot(y, &self.d);
                    axpy(&mut self.d, self.alpha[k] - b, s);
                }
            } else if !preconditioned {
                step = (T::from_f64(params.first_step) / gmax).min(T::ONE);
            }
            self.d.iter_mut().for_each(|p| *p = p.map(|c| -c));
            let mut slope = dot(&self.g, &self.d);
            let descent = slope < T::ZERO;
            if !descent {
                // Not a descent direction (lost curvature information): restart from -g.
                self.d.iter_mut().zip(&self.g).for_each(|(p, q)| *p = q.map(|c| -c));
                slope = dot(&self.g, &self.d);
                step = (T::from_f64(params.first_step) / gmax).min(T::ONE);
                stored = 0;
            }
            // Backtracking with safeguarded quadratic interpolation.
            let mut accepted = None;
            for _ in 0..params.max_line_search {
                self.x_new.copy_from_slice(x);
                axpy(&mut self.x_new, step, &self.d);
                let f_new = f(&self.x_new, &mut self.g_new)?;
                evaluations += 1;
                if f_new.is_finite() && f_new <= fx + c1 * step * slope && f_new < fx {
                    accepted = Some(f_new);
                    break;
                }
                let shrink = if f_new.is_finite() {
                    let denom = T::from_f64(2.0) * (f_new - fx - slope * step);
                    let q = -slope * step * step / denom;
                    (q / step).max(T::from_f64(0.1)).min(T::from_f64(0.5))
                } else {
                    T::from_f64(0.1)
                };
                step *= shrink;
            }
            let Some(f_new) = accepted else {
                break Termination::LineSearch;
            };
            // Correction pair s = x_new - x, y = g_new - g.
            let k = head;
            for i in 0..n {
                for c in 0..3 {
                    self.s[k * n + i][c] = self.x_new[i][c] - x[i][c];
                    self.y[k * n + i][c] = self.g_new[i][c] - self.g[i][c];
                }
            }
            let ys = dot(&self.s[k * n..(k + 1) * n], &self.y[k * n..(k + 1) * n]);
            if ys > T::ZERO && ys.is_finite() {
                self.rho[k] = T::ONE / ys;
                head = (head + 1) % self.memory;
                stored = (stored + 1).min(self.memory);
            }
            x.copy_from_slice(&self.x_new);
            core::mem::swap(&mut self.g, &mut self.g_new);
            let decrease = (fx - f_new).to_f64();
            let total = f_start - f_new.to_f64();
            fx = f_new;
            iterations += 1;
            if decrease <= params.rel_decrease_tol * total {
                break Termination::RelativeDecrease;
            }
        };
        Ok(LbfgsReport {
            iterations,
            evaluations,
            f_start,
            f: fx.to_f64(),
            grad_max: max_abs(&self.g).to_f64(),
            termination,
        })
    }
}
