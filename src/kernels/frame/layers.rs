//! The layers a tier runs through the frame: a linear layer ([`linear`]) and the fused split
//! edge MLP ([`edge_mlp`]), in row blocks, with their bf16 activations prepared per block.

use super::{gemm, layer_norm_apply, layer_norm_value, widen_bf16, Ahead, SegBf16, SegF32, Segs, Simd, TileEpi};
use crate::kernels::{
    packed_len_f32, padded_cols, EdgeInputs, EdgeMlp, Epilogue, Operand, Weights, EDGE_BLOCK, LINEAR_BLOCK_ROWS,
    MAX_OPERANDS, PANEL,
};

fn bias_ptr(bias: Option<&[f32]>) -> *const f32 {
    bias.map_or(core::ptr::null(), |b| b.as_ptr())
}

/// [`crate::kernels::Kernels::linear`] on tier `S`.
///
/// # Safety
/// The arguments passed the checks of [`crate::kernels::Kernels::linear`] (the tiles' pointer
/// arithmetic relies on those shapes).
#[inline(always)]
pub(crate) unsafe fn linear<S: Simd>(
    s: S,
    ops: &[Operand<'_>],
    bias: Option<&[f32]>,
    epi: &Epilogue<'_>,
    out: &mut [f32],
    scratch: &mut [f32],
) {
    let n = ops[0].w.n();
    let rows = out.len() / n;
    let kps: usize = ops.iter().map(|o| o.w.k().next_multiple_of(2)).sum();
    let (prep, rest) = scratch.split_at_mut(LINEAR_BLOCK_ROWS * kps);
    let (pre_ln, mut wide) = rest.split_at_mut(LINEAR_BLOCK_ROWS * padded_cols(n));
    // Without bf16 dot products, bf16 weights are widened once per call.
    let emulate = S::SLOTS_PER_PAIR == 2;
    let mut wide_ptr = [core::ptr::null::<f32>(); MAX_OPERANDS];
    if emulate {
        for (i, op) in ops.iter().enumerate() {
            if let Weights::Bf16(w) = op.w {
                let (this, next) = core::mem::take(&mut wide).split_at_mut(packed_len_f32(w.k(), n));
                widen_bf16(&w, this);
                wide_ptr[i] = this.as_ptr();
                wide = next;
            }
        }
    }
    let native_bf16 = ops[0].w.is_bf16() && !emulate;
    if native_bf16 {
        s.bf16_begin();
    }
    // LayerNorm statistics of a block's rows, computed for all of them before any is normalised
    // (as in the edge MLP: independent chains the core can overlap).
    let mut stats = [(0.0f32, 0.0f32); LINEAR_BLOCK_ROWS];
    let mut b0 = 0;
    while b0 < rows {
        let br = (rows - b0).min(LINEAR_BLOCK_ROWS);
        let mut f32_segs = [SegF32 { x: core::ptr::null(), ldx: 0, w: core::ptr::null(), k: 0 }; MAX_OPERANDS];
        let mut bf_segs = [SegBf16 { x: core::ptr::null(), ldx: 0, w: core::ptr::null(), pairs: 0, ahead: Ahead::NONE };
            MAX_OPERANDS];
        // Each bf16 operand's prepared rows are split off the rest of `prep`, so that preparing
        // the next operand does not reborrow (and so invalidate the pointers into) this one's.
        let mut free: &mut [f32] = &mut *prep;
        for (i, op) in ops.iter().enumerate() {
            let k = op.w.k();
            let x = &op.x[b0 * k..(b0 + br) * k];
            match op.w {
                Weights::F32(w) => f32_segs[i] = SegF32 { x: x.as_ptr(), ldx: k, w: w.data().as_ptr(), k },
                Weights::Bf16(w) => {
                    let kp = k.next_multiple_of(2);
                    let (area, next) = core::mem::take(&mut free).split_at_mut(br * kp);
                    free = next;
                    for (src, dst) in x.chunks_exact(k.max(1)).zip(area.chunks_exact_mut(kp.max(1))) {
                        s.prep_bf16(src, dst);
                    }
                    let next = &op.x[(b0 + br) * k..(b0 + br + (rows - b0 - br).min(LINEAR_BLOCK_ROWS)) * k];
                    bf_segs[i] = SegBf16 {
                        x: area.as_ptr(),
                        ldx: kp,
                        w: w.data().as_ptr() as *const u16,
                        pairs: kp / 2,
                        ahead: Ahead::new(next, br),
                    };
                    f32_segs[i] = SegF32 { x: area.as_ptr(), ldx: kp, w: wide_ptr[i], k };
                }
            }
        }
        let segs = if ops[0].w.is_bf16() && !emulate {
            Segs::Bf16(&bf_segs[..ops.len()])
        } else {
            Segs::F32(&f32_segs[..ops.len()])
        };
        let out_blk = &mut out[b0 * n..(b0 + br) * n];
        let tepi = TileEpi {
            bias: bias_ptr(bias),
            addend: core::ptr::null(),
            relu: epi.relu,
            accumulate: false,
            prefetch_out: true,
            prepared_out: false,
        };
        match (&epi.layer_norm, epi.residual) {
            (None, residual) => {
                let tepi = TileEpi { accumulate: residual, ..tepi };
                // SAFETY: shapes validated by `Kernels::linear`.
                unsafe { gemm(s, segs, br, n, out_blk.as_mut_ptr(), n, &tepi) };
            }
            (Some(ln), false) => {
                // SAFETY: as above.
                unsafe { gemm(s, segs, br, n, out_blk.as_mut_ptr(), n, &tepi) };
                s.layer_norm_stats_rows(out_blk, n, &mut stats[..br]);
                for (y, &st) in out_blk.chunks_exact_mut(n).zip(&stats[..br]) {
                    layer_norm_apply(y, st, ln.gamma, ln.beta);
                }
            }
            (Some(ln), true) => {
                let tmp = &mut pre_ln[..br * n];
                let tepi = TileEpi { prefetch_out: false, ..tepi };
                // SAFETY: as above, into the scratch rows.
                unsafe { gemm(s, segs, br, n, tmp.as_mut_ptr(), n, &tepi) };
                s.layer_norm_stats_rows(tmp, n, &mut stats[..br]);
                for ((y, o), &st) in tmp.chunks_exact(n).zip(out_blk.chunks_exact_mut(n)).zip(&stats[..br]) {
                    // Normalised and added to the residual in one pass.
                    for ((o, v), (g, b)) in o.iter_mut().zip(y).zip(ln.gamma.iter().zip(ln.beta)) {
                        *o += layer_norm_value(*v, st, *g, *b);
                    }
                }
            }
        }
        b0 += br;
    }
    if native_bf16 {
        s.bf16_end();
    }
}

/// The rows a layer of the edge chain reads.
#[derive(Clone, Copy)]
enum ChainInput<'a> {
    /// f32 rows, `k` wide, which bf16 weights prepare into the scratch rows first.
    F32(&'a [f32]),
    /// Rows the previous layer's epilogue wrote prepared (`TileEpi::prepared_out`), `kp` slots
    /// apart.
    Prepared(&'a [f32]),
}

/// Runs one layer of the edge chain on `br` rows of `x`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn chain_layer<S: Simd>(
    s: S,
    w: &Weights<'_>,
    x: ChainInput<'_>,
    br: usize,
    prep: &mut [f32],
    wide: &[f32],
    out: &mut [f32],
    epi: &TileEpi,
    ahead: Ahead,
) {
    let (k, n) = (w.k(), w.n());
    let (x, prepared) = match x {
        ChainInput::F32(x) => (x, false),
        ChainInput::Prepared(x) => (x, true),
    };
    match w {
        Weights::F32(wf) => {
            debug_assert!(!prepared, "prepared rows for f32 weights");
            let seg = [SegF32 { x: x.as_ptr(), ldx: k, w: wf.data().as_ptr(), k }];
            // SAFETY: `x` has `br` rows of `k`, `out` `br` rows of `n`.
            unsafe { gemm(s, Segs::F32(&seg), br, n, out.as_mut_ptr(), n, epi) };
        }
        Weights::Bf16(wb) => {
            let kp = k.next_multiple_of(2);
            let prep = if prepared {
                x
            } else {
                for (src, dst) in x[..br * k].chunks_exact(k).zip(prep.chunks_exact_mut(kp)) {
                    s.prep_bf16(src, dst);
                }
                &*prep
            };
            if S::SLOTS_PER_PAIR == 2 {
                // Widened weights (see `widen_bf16`) and bf16-rounded activations.
                let seg = [SegF32 { x: prep.as_ptr(), ldx: kp, w: wide.as_ptr(), k }];
                // SAFETY: as above with the prepared rows and the widened weights.
                unsafe { gemm(s, Segs::F32(&seg), br, n, out.as_mut_ptr(), n, epi) };
            } else {
                let seg =
                    [SegBf16 { x: prep.as_ptr(), ldx: kp, w: wb.data().as_ptr() as *const u16, pairs: kp / 2, ahead }];
                // SAFETY: as above with the prepared rows.
                unsafe { gemm(s, Segs::Bf16(&seg), br, n, out.as_mut_ptr(), n, epi) };
            }
        }
    }
}

/// [`crate::kernels::Kernels::edge_mlp`] on tier `S`.
///
/// # Safety
/// The arguments passed the checks of [`crate::kernels::Kernels::edge_mlp`] (shapes, and node
/// indices inside their projections).
#[inline(always)]
pub(crate) unsafe fn edge_mlp<S: Simd>(
    s: S,
    mlp: &EdgeMlp<'_>,
    edges: &EdgeInputs<'_>,
    latent: &mut [f32],
    aggregate: &mut [f32],
    scratch: &mut [f32],
) {
    let k_e = mlp.w1_edge.k();
    let h = mlp.w1_edge.n();
    let n_edges = edges.target.len();
    let prep_w = k_e.next_multiple_of(2).max(h.next_multiple_of(2));
    let (prep, rest) = scratch.split_at_mut(EDGE_BLOCK * prep_w);
    let (buf_a, rest) = rest.split_at_mut(EDGE_BLOCK * h.max(k_e));
    let (buf_b, rest) = rest.split_at_mut(EDGE_BLOCK * h);
    let (wide1, rest) = rest.split_at_mut(packed_len_f32(k_e, h));
    let (wide2, rest) = rest.split_at_mut(packed_len_f32(h, h));
    let wide3 = &mut rest[..packed_len_f32(h, k_e)];
    if S::SLOTS_PER_PAIR == 2 {
        for (w, dst) in [(&mlp.w1_edge, &mut *wide1), (&mlp.w2, &mut *wide2), (&mlp.w3, &mut *wide3)] {
            if let Weights::Bf16(wb) = w {
                widen_bf16(wb, dst);
            }
        }
    }
    let native_bf16 = mlp.w1_edge.is_bf16() && S::SLOTS_PER_PAIR != 2;
    if native_bf16 {
        s.bf16_begin();
    }
    // With native bf16 products, the hidden layers' epilogues write the next layer's bf16 rows
    // directly (rounded as its preparation would round them, so no bit changes), which saves
    // two of the chain's three preparation passes and half of the hidden rows' stores.
    let hidden_prepared = native_bf16 && h.is_multiple_of(PANEL);
    let mut e0 = 0;
    while e0 < n_edges {
        let br = (n_edges - e0).min(EDGE_BLOCK);
        // The split first layer's node projections, gathered and summed once per edge: the
        // loads of random node rows overlap here, instead of stalling each column pass's
        // epilogue. (`pt + ps` is the same sum the epilogue formed before, so results are
        // unchanged.)
        for (i, g) in buf_b[..br * h].chunks_exact_mut(h).enumerate() {
            let (t, src) = (edges.target[e0 + i] as usize * h, edges.source[e0 + i] as usize * h);
            for ((g, a), b) in g.iter_mut().zip(&edges.p_target[t..t + h]).zip(&edges.p_source[src..src + h]) {
                *g = a + b;
            }
        }
        // The source projection rows are random rows of node arrays that outgrow L2: request
        // those of the block after next now (one block ahead left part of their latency
        // exposed). Target rows are sequential (edges are sorted by target): the hardware
        // prefetcher has them, and prefetching them too cost 2.5 % of the bf16 edge MLP.
        // (The next block's latent rows: in bf16 the first layer's tiles request them, spread
        // over its pair steps, see `Ahead`; requested here at once they lost 2 % in bf16.)
        for e in (e0 + 2 * br).min(n_edges)..(e0 + 3 * br).min(n_edges) {
            let src = edges.source[e] as usize * h;
            for c in (0..h).step_by(16) {
                // SAFETY: `src + c` is inside the projection array (indices validated); a
                // prefetch never faults anyway.
                unsafe { s.prefetch(edges.p_source.as_ptr().add(src + c) as *const u8) };
            }
        }
        // The next block's latent rows, requested while this block's first layer runs.
        let next = &latent[(e0 + br) * k_e..(e0 + br + (n_edges - e0 - br).min(EDGE_BLOCK)) * k_e];
        let ahead = Ahead::new(next, br);
        let lat = &mut latent[e0 * k_e..(e0 + br) * k_e];
        let none = core::ptr::null();
        let epi1 = TileEpi {
            bias: mlp.b1.as_ptr(),
            addend: buf_b.as_ptr(),
            relu: true,
            accumulate: false,
            prefetch_out: false,
            prepared_out: hidden_prepared,
        };
        let epi2 = TileEpi { bias: mlp.b2.as_ptr(), addend: none, relu: true, prepared_out: hidden_prepared, ..epi1 };
        let epi3 = TileEpi { bias: mlp.b3.as_ptr(), addend: none, relu: false, prepared_out: false, ..epi1 };
        // SAFETY: shapes validated by `Kernels::edge_mlp` (indices checked against the projection
        // rows); scratch buffers hold `EDGE_BLOCK` rows of their widths (a prepared row takes
        // no more slots than its f32 values).
        unsafe {
            chain_layer(s, &mlp.w1_edge, ChainInput::F32(lat), br, prep, wide1, buf_a, &epi1, ahead);
            if hidden_prepared {
                // buf_a (prepared) -> prep (prepared) -> buf_a (f32).
                chain_layer(s, &mlp.w2, ChainInput::Prepared(buf_a), br, &mut [], wide2, prep, &epi2, Ahead::NONE);
                chain_layer(s, &mlp.w3, ChainInput::Prepared(prep), br, &mut [], wide3, buf_a, &epi3, Ahead::NONE);
            } else {
                chain_layer(s, &mlp.w2, ChainInput::F32(buf_a), br, prep, wide2, buf_b, &epi2, Ahead::NONE);
                chain_layer(s, &mlp.w3, ChainInput::F32(buf_b), br, prep, wide3, buf_a, &epi3, Ahead::NONE);
            }
        }
        // LayerNorm statistics for all rows first: independent chains the core can overlap
        // (one row at a time would serialise on each row's sum -> sqrt -> divide latency).
        let mut stats = [(0.0f32, 0.0f32); EDGE_BLOCK];
        if mlp.layer_norm.is_some() {
            s.layer_norm_stats_rows(&buf_a[..br * k_e], k_e, &mut stats[..br]);
        }
        // Normalise, aggregate and add the residual in one pass over each message row.
        for (i, (m, l)) in buf_a[..br * k_e].chunks_exact(k_e).zip(lat.chunks_exact_mut(k_e)).enumerate() {
            let t = edges.target[e0 + i] as usize;
            let agg = aggregate[t * k_e..(t + 1) * k_e].iter_mut().zip(l.iter_mut());
            match &mlp.layer_norm {
                Some(ln) => {
                    for (((a, l), v), (g, b)) in agg.zip(m).zip(ln.gamma.iter().zip(ln.beta)) {
                        let y = layer_norm_value(*v, stats[i], *g, *b);
                        *a += y;
                        *l += y;
                    }
                }
                None => {
                    for ((a, l), v) in agg.zip(m) {
                        *a += v;
                        *l += v;
                    }
                }
            }
        }
        e0 += br;
    }
    if native_bf16 {
        s.bf16_end();
    }
}
