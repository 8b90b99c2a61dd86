//! The optimiser of MODEL.md section 7: Adam, the step-decay learning-rate schedule and global
//! gradient-norm clipping, over flat f32 parameter vectors.

use crate::exec::par::{split, Disjoint};
use crate::exec::{Executor, Serial};
use alloc::vec;
use alloc::vec::Vec;

/// Learning rate at optimiser step `s` (0-based) of the recipe:
/// `5e-5 · (0.5^floor(s / 50000) + 0.01)`.
pub fn learning_rate(step: u64) -> f64 {
    step_decay(5e-5, 50_000, step)
}

/// The recipe's schedule with another base rate and halving period:
/// `base · (0.5^floor(s / halving) + 0.01)`.
pub fn step_decay(base: f64, halving: u64, step: u64) -> f64 {
    let halvings = (step / halving.max(1)).min(1_000) as i32;
    base * (libm::pow(0.5, halvings as f64) + 0.01)
}

/// Scales `grad` so that its L2 norm is at most `max_norm`; returns the norm before clipping.
/// A non-finite norm leaves `grad` unchanged (the caller decides to skip the step).
pub fn clip_global_norm(grad: &mut [f32], max_norm: f64) -> f64 {
    let norm = crate::math::sqrt_f64(grad.iter().map(|&g| (g as f64) * (g as f64)).sum::<f64>());
    if norm.is_finite() && norm > max_norm {
        let s = (max_norm / norm) as f32;
        grad.iter_mut().for_each(|g| *g *= s);
    }
    norm
}

/// Adam (Kingma & Ba) with bias correction, as PyTorch's `torch.optim.Adam` without weight
/// decay.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    /// First-moment decay (0.9).
    pub beta1: f64,
    /// Second-moment decay (0.999).
    pub beta2: f64,
    /// Denominator guard (1e-8).
    pub eps: f64,
    /// Steps taken.
    pub t: u64,
    /// First moments.
    pub m: Vec<f32>,
    /// Second moments.
    pub v: Vec<f32>,
}

impl Adam {
    /// Zero moments for `n` parameters, the HOOD hyper-parameters.
    pub fn new(n: usize) -> Adam {
        Adam { beta1: 0.9, beta2: 0.999, eps: 1e-8, t: 0, m: vec![0.0; n], v: vec![0.0; n] }
    }

    /// One update `θ -= lr · m̂ / (sqrt(v̂) + eps)`.
    pub fn step(&mut self, theta: &mut [f32], grad: &[f32], lr: f64) {
        self.step_on(&Serial, theta, grad, lr);
    }

    /// [`Adam::step`] with the parameters split between `exec`'s threads (the same result: each
    /// parameter's update is independent).
    pub fn step_on(&mut self, exec: &dyn Executor, theta: &mut [f32], grad: &[f32], lr: f64) {
        self.t += 1;
        let (b1, b2) = (self.beta1 as f32, self.beta2 as f32);
        let bc1 = 1.0 - libm::pow(self.beta1, self.t as f64);
        let bc2 = 1.0 - libm::pow(self.beta2, self.t as f64);
        let step = (lr / bc1) as f32;
        let inv_sqrt_bc2 = (1.0 / crate::math::sqrt_f64(bc2)) as f32;
        let eps = self.eps as f32;
        let n = theta.len().min(grad.len()).min(self.m.len()).min(self.v.len());
        let (th, ms, vs) = (Disjoint::new(theta), Disjoint::new(&mut self.m), Disjoint::new(&mut self.v));
        let parts = 4 * exec.parallelism();
        exec.run(parts, &|t| {
            let r = split(n, parts, t);
            // SAFETY: the ranges of different tasks are disjoint.
            let (th, ms, vs) = unsafe { (th.range(r.clone()), ms.range(r.clone()), vs.range(r.clone())) };
            for (((p, &g), m), v) in th.iter_mut().zip(&grad[r]).zip(ms).zip(vs) {
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                // std's square root: libm's is legacy-SSE inline assembly, slow next to AVX code.
                *p -= step * *m / (v.sqrt() * inv_sqrt_bc2 + eps);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn train_learning_rate_schedule() {
        assert!((learning_rate(0) - 5e-5 * 1.01).abs() < 1e-15);
        assert!((learning_rate(49_999) - 5e-5 * 1.01).abs() < 1e-15);
        assert!((learning_rate(50_000) - 5e-5 * 0.51).abs() < 1e-15);
        assert!((learning_rate(120_000) - 5e-5 * 0.26).abs() < 1e-15);
        assert!(learning_rate(10_000_000) > 5e-7 && learning_rate(10_000_000) < 5.0001e-7);
    }

    #[test]
    fn train_clipping_caps_the_norm_exactly() {
        let mut g: Vec<f32> = (0..1000).map(|i| ((i * 37 % 101) as f32 - 50.0) * 0.1).collect();
        let before = clip_global_norm(&mut g, 1.0);
        assert!(before > 10.0);
        let after = crate::math::sqrt_f64(g.iter().map(|&x| (x as f64).powi(2)).sum::<f64>());
        assert!((after - 1.0).abs() < 1e-6, "norm after clipping {after}");
        // Below the cap: untouched.
        let mut small = vec![0.3f32, -0.4];
        assert!((clip_global_norm(&mut small, 1.0) - 0.5).abs() < 1e-7);
        assert_eq!(small, vec![0.3, -0.4]);
    }

    #[test]
    fn train_adam_converges_on_a_quadratic() {
        // f(θ) = Σ c_i (θ_i - t_i)² with condition number 1e4.
        let n = 16;
        let c: Vec<f32> = (0..n).map(|i| libm::powf(10.0, 4.0 * i as f32 / (n - 1) as f32 - 2.0)).collect();
        let target: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
        let mut theta = vec![0.0f32; n];
        let mut adam = Adam::new(n);
        let mut g = vec![0.0f32; n];
        for s in 0..4000 {
            for i in 0..n {
                g[i] = 2.0 * c[i] * (theta[i] - target[i]);
            }
            let lr = if s < 2000 { 1e-2 } else { 1e-3 };
            adam.step(&mut theta, &g, lr);
        }
        for i in 0..n {
            assert!((theta[i] - target[i]).abs() < 1e-2, "θ[{i}] = {} vs {}", theta[i], target[i]);
        }
        // The first step moves every coordinate by lr against the gradient's sign.
        let mut adam = Adam::new(2);
        let mut th = vec![1.0f32, 1.0];
        adam.step(&mut th, &[3.0, -1e-3], 0.1);
        assert!((th[0] - 0.9).abs() < 1e-6 && (th[1] - 1.1).abs() < 1e-4, "{th:?}");
    }
}
