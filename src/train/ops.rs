//! Differentiable building blocks over row-major matrices, generic over [`Real`]: Linear
//! layers on column parts of their input, ReLU, LayerNorm and MLPs that keep what their
//! backward pass needs. Parameters live in a flat vector (see [`super::layout`]); gradients are
//! accumulated into a vector of the same layout.

use super::layout::{LinearAt, MlpAt};
use crate::math::Real;
use crate::model::params::LAYER_NORM_EPS;
use alloc::vec;
use alloc::vec::Vec;

/// A column block of a Linear weight: output rows `n`, input columns `col..col + k` of a
/// row-major `[n, ld]` matrix starting at `w` in the flat vector.
#[derive(Clone, Copy, Debug)]
pub struct Part {
    /// Offset of the weight in the flat vector.
    pub w: usize,
    /// Row stride (the layer's full input width).
    pub ld: usize,
    /// First input column of the part.
    pub col: usize,
    /// Input columns of the part.
    pub k: usize,
    /// Outputs.
    pub n: usize,
}

impl Part {
    /// The whole weight of `l`.
    pub fn whole(l: &LinearAt) -> Part {
        Part { w: l.w, ld: l.inp, col: 0, k: l.inp, n: l.out }
    }

    /// Input columns `col..col + k` of `l`.
    pub fn cols(l: &LinearAt, col: usize, k: usize) -> Part {
        Part { w: l.w, ld: l.inp, col, k, n: l.out }
    }

    fn row<'a, R>(&self, theta: &'a [R], o: usize) -> &'a [R] {
        let s = self.w + o * self.ld + self.col;
        &theta[s..s + self.k]
    }
}

/// `y += x · Wᵀ` over all rows of `x` (`rows × k`) into `y` (`rows × n`). The part is
/// transposed once so that the inner loop runs over contiguous outputs (and zero inputs, common
/// after a ReLU, are skipped four at a time).
pub fn matmul_acc<R: Real>(theta: &[R], p: Part, x: &[R], y: &mut [R]) {
    let mut wt = vec![R::ZERO; p.k * p.n];
    for o in 0..p.n {
        for (i, &w) in p.row(theta, o).iter().enumerate() {
            wt[i * p.n + o] = w;
        }
    }
    let n = p.n;
    for (xr, yr) in x.chunks_exact(p.k).zip(y.chunks_exact_mut(n)) {
        // Four inputs at a time, so that the output row is loaded and stored once per four.
        let mut i = 0;
        while i + 4 <= p.k {
            let a = [xr[i], xr[i + 1], xr[i + 2], xr[i + 3]];
            if a.iter().any(|&v| v != R::ZERO) {
                let w4 = &wt[i * n..(i + 4) * n];
                let (w0, w1, w2, w3) = (&w4[..n], &w4[n..2 * n], &w4[2 * n..3 * n], &w4[3 * n..]);
                for (o, yo) in yr.iter_mut().enumerate() {
                    *yo += (a[0] * w0[o] + a[1] * w1[o]) + (a[2] * w2[o] + a[3] * w3[o]);
                }
            }
            i += 4;
        }
        for i in i..p.k {
            let a = xr[i];
            if a != R::ZERO {
                for (yo, &w) in yr.iter_mut().zip(&wt[i * n..(i + 1) * n]) {
                    *yo += a * w;
                }
            }
        }
    }
}

/// Backward of [`matmul_acc`]: `dW += dyᵀ · x` into `grad`, and `dx += dy · W` when asked.
pub fn matmul_backward<R: Real>(theta: &[R], grad: &mut [R], p: Part, x: &[R], dy: &[R], dx: Option<&mut [R]>) {
    // dW: four rows at a time, so that each gradient row is loaded and stored once per four.
    let (xb, dyb) = (x.chunks_exact(4 * p.k), dy.chunks_exact(4 * p.n));
    let (xt, dyt) = (xb.remainder(), dyb.remainder());
    for (x4, dy4) in xb.zip(dyb) {
        let (x0, x1, x2, x3) = (&x4[..p.k], &x4[p.k..2 * p.k], &x4[2 * p.k..3 * p.k], &x4[3 * p.k..]);
        for o in 0..p.n {
            let d = [dy4[o], dy4[p.n + o], dy4[2 * p.n + o], dy4[3 * p.n + o]];
            if d.iter().all(|&v| v == R::ZERO) {
                continue;
            }
            let s = p.w + o * p.ld + p.col;
            for (i, g) in grad[s..s + p.k].iter_mut().enumerate() {
                *g += (d[0] * x0[i] + d[1] * x1[i]) + (d[2] * x2[i] + d[3] * x3[i]);
            }
        }
    }
    for (xr, dyr) in xt.chunks_exact(p.k).zip(dyt.chunks_exact(p.n)) {
        for (o, &d) in dyr.iter().enumerate() {
            if d == R::ZERO {
                continue;
            }
            let s = p.w + o * p.ld + p.col;
            for (g, a) in grad[s..s + p.k].iter_mut().zip(xr) {
                *g += d * *a;
            }
        }
    }
    // dx: the part transposed is the forward's layout; sum over outputs four at a time.
    if let Some(dx) = dx {
        let mut w = vec![R::ZERO; p.n * p.k];
        for o in 0..p.n {
            w[o * p.k..(o + 1) * p.k].copy_from_slice(p.row(theta, o));
        }
        for (dxr, dyr) in dx.chunks_exact_mut(p.k).zip(dy.chunks_exact(p.n)) {
            let mut o = 0;
            while o + 4 <= p.n {
                let d = [dyr[o], dyr[o + 1], dyr[o + 2], dyr[o + 3]];
                if d.iter().any(|&v| v != R::ZERO) {
                    let w4 = &w[o * p.k..(o + 4) * p.k];
                    let (w0, w1, w2, w3) = (&w4[..p.k], &w4[p.k..2 * p.k], &w4[2 * p.k..3 * p.k], &w4[3 * p.k..]);
                    for (i, g) in dxr.iter_mut().enumerate() {
                        *g += (d[0] * w0[i] + d[1] * w1[i]) + (d[2] * w2[i] + d[3] * w3[i]);
                    }
                }
                o += 4;
            }
            for o in o..p.n {
                let d = dyr[o];
                if d != R::ZERO {
                    for (g, wv) in dxr.iter_mut().zip(&w[o * p.k..(o + 1) * p.k]) {
                        *g += d * *wv;
                    }
                }
            }
        }
    }
}

/// `y[r] = b` for every row.
pub fn fill_bias<R: Real>(theta: &[R], l: &LinearAt, y: &mut [R]) {
    let b = &theta[l.b..l.b + l.out];
    for yr in y.chunks_exact_mut(l.out) {
        yr.copy_from_slice(b);
    }
}

/// Adds the column sums of `dy` (`rows × out`) to the bias gradient of `l`.
pub fn bias_backward<R: Real>(grad: &mut [R], l: &LinearAt, dy: &[R]) {
    let g = &mut grad[l.b..l.b + l.out];
    for dr in dy.chunks_exact(l.out) {
        for (a, b) in g.iter_mut().zip(dr) {
            *a += *b;
        }
    }
}

/// What an MLP's backward needs from its forward (besides its input).
#[derive(Clone, Debug, Default)]
pub struct MlpCache<R> {
    /// Rows.
    pub rows: usize,
    /// Post-ReLU output of every hidden layer (`rows × width`); ReLU's mask is `> 0`.
    pub hidden: Vec<Vec<R>>,
    /// LayerNorm's normalised values `(y - mean) / std` (`rows × out`), if the MLP has one.
    pub xhat: Vec<R>,
    /// LayerNorm's `1 / sqrt(var + eps)` per row.
    pub inv_std: Vec<R>,
}

/// Runs an MLP from the pre-activation of its first layer (`a0`, bias included, `rows × out0`),
/// writing (or, with `residual`, adding) its output into `out`.
pub fn mlp_from_first<R: Real>(
    theta: &[R],
    m: &MlpAt,
    a0: Vec<R>,
    rows: usize,
    out: &mut [R],
    residual: bool,
) -> MlpCache<R> {
    let mut cache = MlpCache { rows, ..MlpCache::default() };
    let mut a = a0;
    for l in &m.layers[1..] {
        a.iter_mut().for_each(|v| *v = v.max(R::ZERO));
        let mut next = vec![R::ZERO; rows * l.out];
        fill_bias(theta, l, &mut next);
        matmul_acc(theta, Part::whole(l), &a, &mut next);
        cache.hidden.push(a);
        a = next;
    }
    let n = m.output();
    if let Some((g, b)) = m.norm {
        cache.xhat = vec![R::ZERO; rows * n];
        cache.inv_std = vec![R::ZERO; rows];
        let eps = R::from_f32(LAYER_NORM_EPS);
        let nr = R::from_f64(n as f64);
        for (r, yr) in a.chunks_exact_mut(n).enumerate() {
            let mut mean = R::ZERO;
            yr.iter().for_each(|v| mean += *v);
            mean = mean / nr;
            let mut var = R::ZERO;
            yr.iter().for_each(|v| var += (*v - mean) * (*v - mean));
            let inv = R::ONE / (var / nr + eps).sqrt();
            cache.inv_std[r] = inv;
            for (c, v) in yr.iter_mut().enumerate() {
                let xh = (*v - mean) * inv;
                cache.xhat[r * n + c] = xh;
                *v = xh * theta[g + c] + theta[b + c];
            }
        }
    }
    if residual {
        out.iter_mut().zip(&a).for_each(|(o, v)| *o += *v);
    } else {
        out.copy_from_slice(&a);
    }
    cache
}

/// An MLP over input parts (`inputs[i]` holds `rows × k_i` columns, concatenated in order).
pub fn mlp_forward<R: Real>(
    theta: &[R],
    m: &MlpAt,
    inputs: &[&[R]],
    rows: usize,
    out: &mut [R],
    residual: bool,
) -> MlpCache<R> {
    let l0 = &m.layers[0];
    let mut a0 = vec![R::ZERO; rows * l0.out];
    fill_bias(theta, l0, &mut a0);
    let mut col = 0;
    for x in inputs {
        let k = x.len() / rows.max(1);
        if rows > 0 {
            matmul_acc(theta, Part::cols(l0, col, k), x, &mut a0);
        }
        col += k;
    }
    mlp_from_first(theta, m, a0, rows, out, residual)
}

/// Backward of [`mlp_from_first`] from `dout` (gradient of the MLP's own output, the residual
/// path excluded): accumulates the gradients of every layer but the first layer's weight, and
/// returns the gradient of the first layer's pre-activation (`rows × out0`).
pub fn mlp_backward_to_first<R: Real>(
    theta: &[R],
    grad: &mut [R],
    m: &MlpAt,
    cache: &MlpCache<R>,
    dout: &[R],
) -> Vec<R> {
    let n = m.output();
    let mut d = dout.to_vec();
    if let Some((g, b)) = m.norm {
        let nr = R::from_f64(n as f64);
        for (r, dr) in d.chunks_exact_mut(n).enumerate() {
            let xh = &cache.xhat[r * n..(r + 1) * n];
            let (mut s1, mut s2) = (R::ZERO, R::ZERO);
            for c in 0..n {
                grad[g + c] += dr[c] * xh[c];
                grad[b + c] += dr[c];
                let dxh = dr[c] * theta[g + c];
                dr[c] = dxh;
                s1 += dxh;
                s2 += dxh * xh[c];
            }
            let (m1, m2, inv) = (s1 / nr, s2 / nr, cache.inv_std[r]);
            for c in 0..n {
                dr[c] = inv * (dr[c] - m1 - xh[c] * m2);
            }
        }
    }
    for (li, l) in m.layers.iter().enumerate().skip(1).rev() {
        let x = &cache.hidden[li - 1];
        bias_backward(grad, l, &d);
        let mut dx = vec![R::ZERO; x.len()];
        matmul_backward(theta, grad, Part::whole(l), x, &d, Some(&mut dx));
        // ReLU: the gradient passes where the activation is positive.
        for (g, a) in dx.iter_mut().zip(x) {
            if *a <= R::ZERO {
                *g = R::ZERO;
            }
        }
        d = dx;
    }
    bias_backward(grad, &m.layers[0], &d);
    d
}

/// Backward of [`mlp_forward`]: parameter gradients, and the gradient of each input part added
/// into `dinputs[i]` where given.
pub fn mlp_backward<R: Real>(
    theta: &[R],
    grad: &mut [R],
    m: &MlpAt,
    cache: &MlpCache<R>,
    inputs: &[&[R]],
    dout: &[R],
    dinputs: &mut [Option<&mut [R]>],
) {
    let d0 = mlp_backward_to_first(theta, grad, m, cache, dout);
    let l0 = &m.layers[0];
    let rows = cache.rows;
    let mut col = 0;
    for (i, x) in inputs.iter().enumerate() {
        let k = x.len() / rows.max(1);
        let dx = dinputs.get_mut(i).and_then(|d| d.as_deref_mut());
        matmul_backward(theta, grad, Part::cols(l0, col, k), x, &d0, dx);
        col += k;
    }
}
