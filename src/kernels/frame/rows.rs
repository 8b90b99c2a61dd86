//! Row passes written once for every tier: bf16 rounding and packing of activations, lane-wise
//! sums and dot products, LayerNorm statistics and rows, and bf16 weights widened to f32 panels.

use crate::kernels::{PackedBf16, LN_EPS, PANEL};

/// Rounds to the nearest bf16 (ties to even) and widens back: the value a bf16 activation has.
/// Finite inputs only (NaN payloads are not preserved).
#[inline(always)]
pub(crate) fn round_bf16(x: f32) -> f32 {
    let b = x.to_bits();
    f32::from_bits(b.wrapping_add(0x7FFF + ((b >> 16) & 1)) & 0xFFFF_0000)
}

/// `Σ f(y_i)` in 8 interleaved partial sums, so the compiler can keep them in one vector (a
/// single serial sum would be a latency chain as long as the row). The tail (`len % 8`) is summed
/// apart: folding it into the partial sums made the compiler keep them on the stack with masked
/// stores, which cannot forward to the next load and stalled every LayerNorm row.
#[inline(always)]
pub(crate) fn lane_sum(y: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut acc = [0.0f32; 8];
    let chunks = y.chunks_exact(8);
    let tail = chunks.remainder();
    for c in chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            *a += f(*v);
        }
    }
    let rest = tail.iter().fold(0.0f32, |t, v| t + f(*v));
    (((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]))) + rest
}

/// `Σ a_i·b_i` over the shorter of the two, in the partial sums of [`lane_sum`] (the trainer's
/// LayerNorm backward).
#[cfg(feature = "train")]
#[inline(always)]
pub(crate) fn lane_dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f32; 8];
    for (ca, cb) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        for ((s, x), y) in acc.iter_mut().zip(ca).zip(cb) {
            *s += x * y;
        }
    }
    let t = n - n % 8;
    let rest = a[t..].iter().zip(&b[t..]).fold(0.0f32, |s, (x, y)| s + x * y);
    (((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]))) + rest
}

/// Mean and inverse standard deviation of one row (two-pass, eps [`LN_EPS`]).
#[inline(always)]
pub(crate) fn layer_norm_stats(y: &[f32]) -> (f32, f32) {
    let n = y.len() as f32;
    let mean = lane_sum(y, |v| v) / n;
    let var = lane_sum(y, |v| (v - mean) * (v - mean)) / n;
    (mean, 1.0 / crate::math::sqrt_f32(var + LN_EPS))
}

/// [`layer_norm_stats`] of consecutive rows of `width` values (`stats` gets one entry per row).
/// The portable form, row by row; the x86 tiers batch rows with the same arithmetic
/// ([`Simd::layer_norm_stats_rows`](super::Simd::layer_norm_stats_rows)).
#[inline(always)]
pub(crate) fn layer_norm_stats_rows(y: &[f32], width: usize, stats: &mut [(f32, f32)]) {
    if width == 0 {
        return;
    }
    for (row, out) in y.chunks_exact(width).zip(stats) {
        *out = layer_norm_stats(row);
    }
}

/// In-place affine LayerNorm of one row (two-pass mean and variance, eps [`LN_EPS`]).
#[inline(always)]
pub(crate) fn layer_norm_row(y: &mut [f32], gamma: &[f32], beta: &[f32]) {
    layer_norm_apply(y, layer_norm_stats(y), gamma, beta);
}

/// In-place affine LayerNorm of one row with its statistics `(mean, inverse deviation)` from
/// [`layer_norm_stats`] (or a tier's batched form of it).
#[inline(always)]
pub(crate) fn layer_norm_apply(y: &mut [f32], stats: (f32, f32), gamma: &[f32], beta: &[f32]) {
    for ((v, g), b) in y.iter_mut().zip(gamma).zip(beta) {
        *v = layer_norm_value(*v, stats, *g, *b);
    }
}

/// One LayerNorm output: `(v - mean) · inv · gamma + beta`, with the row's `(mean, inv)`. Every
/// tier and layer normalises through this, so that they all round alike.
#[inline(always)]
pub(crate) fn layer_norm_value(v: f32, (mean, inv): (f32, f32), gamma: f32, beta: f32) -> f32 {
    (v - mean) * inv * gamma + beta
}

/// Widens packed bf16 weights into the f32 panel layout (same `k` and `n`), for tiers without
/// bf16 dot products: they then run the f32 micro-kernel on bf16-exact weights.
#[inline(always)]
pub(crate) fn widen_bf16(w: &PackedBf16<'_>, dst: &mut [f32]) {
    let k = w.k();
    let kp = k.next_multiple_of(2);
    if k == 0 {
        return;
    }
    for (sp, dp) in w.data().chunks_exact(PANEL * kp).zip(dst.chunks_exact_mut(PANEL * k)) {
        for kk in 0..k {
            let src = &sp[(kk / 2) * 2 * PANEL + kk % 2..];
            for j in 0..PANEL {
                dp[kk * PANEL + j] = f32::from_bits((src[2 * j].to_bits() as u32) << 16);
            }
        }
    }
}

/// Writes `src` as packed bf16 pairs, one per `f32` slot (the even input in the low half, as
/// `vdpbf16ps` reads them); an odd last input is paired with zero. The portable form of the
/// prepared activations of tiers with bf16 dot products.
#[inline(always)]
pub(crate) fn pack_bf16_pairs(src: &[f32], dst: &mut [f32]) {
    let pairs = src.len() / 2;
    for (d, s) in dst[..pairs].iter_mut().zip(src.chunks_exact(2)) {
        let lo = round_bf16(s[0]).to_bits() >> 16;
        let hi = round_bf16(s[1]).to_bits() & 0xFFFF_0000;
        *d = f32::from_bits(hi | lo);
    }
    if src.len() % 2 == 1 {
        dst[pairs] = f32::from_bits(round_bf16(src[src.len() - 1]).to_bits() >> 16);
    }
}
