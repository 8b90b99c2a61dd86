//! The scalar reference: the plain definition of every kernel, one output at a time. Every SIMD
//! path is tested against it. Arguments are validated by the caller (`Kernels`).

use super::frame::{layer_norm_row, round_bf16};
use super::{EdgeInputs, EdgeMlp, Epilogue, LayerNorm, Operand, Weights};

/// `x · w[:, o]` in the operand's precision: bf16 weights take bf16-rounded activations.
fn dot(x: &[f32], w: &Weights<'_>, o: usize) -> f32 {
    let mut acc = 0.0f32;
    match w {
        Weights::F32(w) => {
            for (kk, &xv) in x.iter().enumerate() {
                acc += xv * w.get(kk, o);
            }
        }
        Weights::Bf16(w) => {
            for (kk, &xv) in x.iter().enumerate() {
                acc += round_bf16(xv) * w.get(kk, o);
            }
        }
    }
    acc
}

/// One output row `y = Σ x_i · W_iᵀ + b`, then ReLU and LayerNorm as asked.
fn row(inputs: &[(&[f32], Weights<'_>)], bias: Option<&[f32]>, relu: bool, ln: Option<&LayerNorm<'_>>, y: &mut [f32]) {
    for (o, yo) in y.iter_mut().enumerate() {
        let mut v = bias.map_or(0.0, |b| b[o]);
        for (x, w) in inputs {
            v += dot(x, w, o);
        }
        *yo = if relu { v.max(0.0) } else { v };
    }
    if let Some(ln) = ln {
        layer_norm_row(y, ln.gamma, ln.beta);
    }
}

pub(crate) fn linear(
    ops: &[Operand<'_>],
    bias: Option<&[f32]>,
    epi: &Epilogue<'_>,
    out: &mut [f32],
    scratch: &mut [f32],
) {
    let n = ops[0].w.n();
    let y = &mut scratch[..n];
    let mut inputs = [(&[][..], ops[0].w); super::MAX_OPERANDS];
    for (r, orow) in out.chunks_exact_mut(n).enumerate() {
        for (slot, op) in inputs.iter_mut().zip(ops) {
            let k = op.w.k();
            *slot = (&op.x[r * k..(r + 1) * k], op.w);
        }
        row(&inputs[..ops.len()], bias, epi.relu, epi.layer_norm.as_ref(), y);
        for (o, v) in orow.iter_mut().zip(y.iter()) {
            *o = if epi.residual { *o + v } else { *v };
        }
    }
}

pub(crate) fn edge_mlp(
    mlp: &EdgeMlp<'_>,
    edges: &EdgeInputs<'_>,
    latent: &mut [f32],
    aggregate: &mut [f32],
    scratch: &mut [f32],
) {
    let k_e = mlp.w1_edge.k();
    let h = mlp.w1_edge.n();
    let (h1, rest) = scratch.split_at_mut(h);
    let (h2, rest) = rest.split_at_mut(h);
    let m = &mut rest[..k_e];
    for (e, lat) in latent.chunks_exact_mut(k_e).enumerate() {
        let (t, s) = (edges.target[e] as usize, edges.source[e] as usize);
        row(&[(lat, mlp.w1_edge)], Some(mlp.b1), false, None, h1);
        for (o, v) in h1.iter_mut().enumerate() {
            *v = (*v + edges.p_target[t * h + o] + edges.p_source[s * h + o]).max(0.0);
        }
        row(&[(h1, mlp.w2)], Some(mlp.b2), true, None, h2);
        row(&[(h2, mlp.w3)], Some(mlp.b3), false, mlp.layer_norm.as_ref(), m);
        for (l, v) in lat.iter_mut().zip(m.iter()) {
            *l += v;
        }
        for (a, v) in aggregate[t * k_e..(t + 1) * k_e].iter_mut().zip(m.iter()) {
            *a += v;
        }
    }
}
