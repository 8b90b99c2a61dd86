//! The products of one MLP or edge MLP on the fast path, forward and backward: column-part
//! projections, the MLP with its LayerNorm and residual, and the edge MLP's message pass
//! (projected node parts, gathered per edge, messages scattered to the targets).

use super::{fit, hidden_at, size, Ctx, EdgeTape, MlpTape, PartBufs, MAX_INPUTS};
use crate::exec::par::Disjoint;
use crate::kernels::{lane_dot, lane_sum, layer_norm_stats};
use crate::train::gemm::{Mat, Out};
use crate::train::layout::{LinearAt, MlpAt};
use alloc::vec::Vec;
use core::ops::Range;

/// The parameter range an MLP's gradients fall in.
fn span_of(m: &MlpAt) -> Range<usize> {
    let (mut lo, mut hi) = (usize::MAX, 0);
    let mut cover = |a: usize, len: usize| {
        lo = lo.min(a);
        hi = hi.max(a + len);
    };
    for l in &m.layers {
        cover(l.w, l.inp * l.out);
        cover(l.b, l.out);
    }
    if let Some((g, b)) = m.norm {
        cover(g, m.output());
        cover(b, m.output());
    }
    lo.min(hi)..hi
}

/// The first layer's input: column parts, or an edge MLP's split first layer
/// (`[x_target, x_source, edge latent]`, node parts already projected).
#[derive(Clone, Copy)]
pub(super) enum First<'a> {
    Parts(&'a [&'a [f32]]),
    Edge { lat: &'a [f32], pt: &'a [f32], ps: &'a [f32], target: &'a [u32], source: &'a [u32] },
}

impl Ctx<'_> {
    /// `y = x · W_partᵀ` for the column part `col..col+k` of layer `l` (no bias), row-split.
    fn project(&self, l: &LinearAt, col: usize, k: usize, x: &[f32], y: &mut [f32]) {
        let rows = x.len() / k;
        let n = l.out;
        let ys = Disjoint::new(y);
        let (g, wt) = (self.g, self.wt);
        self.parts(rows, &|_, r| {
            // SAFETY: row ranges of different parts are disjoint.
            let yr = unsafe { ys.range(r.start * n..r.end * n) };
            let (a, b) = (Mat { data: &x[r.start * k..], ld: k }, Mat { data: &wt[l.w + col * n..], ld: n });
            g.nn_out(r.len(), n, k, a, b, Out::Set, yr, n);
        });
    }

    /// An MLP over `rows` rows into `out` (`=` or, with `residual`, `+=`), keeping its tape.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn mlp_fwd(
        &self,
        m: &MlpAt,
        first: First<'_>,
        rows: usize,
        tape: &mut MlpTape,
        out: &mut [f32],
        residual: bool,
        parts: &mut [PartBufs],
    ) {
        tape.shape(m, rows);
        if rows == 0 {
            return;
        }
        let nl = m.layers.len();
        let nout = m.output();
        let offs: [usize; 8] = core::array::from_fn(|l| if l < nl { hidden_at(m, rows, l) } else { 0 });
        let hid = Disjoint::new(&mut tape.hidden);
        let xhat = Disjoint::new(&mut tape.xhat);
        let inv = Disjoint::new(&mut tape.inv_std);
        let outs = Disjoint::new(out);
        let pbs = Disjoint::new(parts);
        let (g, theta, wt) = (self.g, self.theta, self.wt);
        self.parts(rows, &|p, r| {
            let nr = r.len();
            // SAFETY: part p owns scratch p and rows `r` of every per-row buffer.
            let pb = unsafe { &mut pbs.range(p..p + 1)[0] };
            let y = &mut pb.y;
            size(y, nr * nout);
            for (li, l) in m.layers.iter().enumerate() {
                let last = li + 1 == nl;
                // SAFETY: rows `r` of hidden layer li belong to this part.
                let dst: &mut [f32] = if last {
                    &mut y[..]
                } else {
                    unsafe { hid.range(offs[li] + r.start * l.out..offs[li] + r.end * l.out) }
                };
                let bias = &theta[l.b..l.b + l.out];
                // The epilogue of the product that completes the pre-activation.
                let done = if last { Out::Bias(bias) } else { Out::BiasRelu(bias) };
                if li == 0 {
                    match first {
                        First::Parts(inputs) => {
                            let mut col = 0;
                            for (i, x) in inputs.iter().enumerate() {
                                let k = x.len() / rows;
                                let a = Mat { data: &x[r.start * k..], ld: k };
                                let out = match (i, inputs.len()) {
                                    (0, 1) => done,
                                    (0, _) => Out::Bias(bias),
                                    _ => Out::Add,
                                };
                                let b = Mat { data: &wt[l.w + col * l.out..], ld: l.out };
                                g.nn_out(nr, l.out, k, a, b, out, dst, l.out);
                                col += k;
                            }
                            if inputs.len() > 1 && !last {
                                dst.iter_mut().for_each(|v| *v = v.max(0.0));
                            }
                        }
                        First::Edge { lat, pt, ps, target, source } => {
                            let k = lat.len() / rows;
                            let col = l.inp - k;
                            let a = Mat { data: &lat[r.start * k..], ld: k };
                            let b = Mat { data: &wt[l.w + col * l.out..], ld: l.out };
                            g.nn_out(nr, l.out, k, a, b, Out::Bias(bias), dst, l.out);
                            let w = l.out;
                            for (e, row) in r.clone().zip(dst.chunks_exact_mut(w)) {
                                let (t, s) = (target[e] as usize, source[e] as usize);
                                for ((o, a), b) in
                                    row.iter_mut().zip(&pt[t * w..(t + 1) * w]).zip(&ps[s * w..(s + 1) * w])
                                {
                                    let v = *o + (*a + *b);
                                    *o = if last { v } else { v.max(0.0) };
                                }
                            }
                        }
                    }
                } else {
                    let pl = &m.layers[li - 1];
                    // SAFETY: this part's rows of the previous hidden layer (read only here).
                    let x = unsafe { hid.range(offs[li - 1] + r.start * pl.out..offs[li - 1] + r.end * pl.out) };
                    let b = Mat { data: &wt[l.w..], ld: l.out };
                    g.nn_out(nr, l.out, l.inp, Mat { data: x, ld: l.inp }, b, done, dst, l.out);
                }
            }
            // SAFETY: rows `r` of the output belong to this part.
            let o = unsafe { outs.range(r.start * nout..r.end * nout) };
            if let Some((gm, bt)) = m.norm {
                // SAFETY: rows `r` of the LayerNorm tape belong to this part.
                let (xh, iv) = unsafe { (xhat.range(r.start * nout..r.end * nout), inv.range(r.clone())) };
                for ((yr, (xr, or)), iv) in
                    y.chunks_exact(nout).zip(xh.chunks_exact_mut(nout).zip(o.chunks_exact_mut(nout))).zip(iv)
                {
                    // The runtime's statistics (8 partial sums: a serial sum per row was a
                    // latency chain that cost ~10 % of a training step).
                    let (mean, is) = layer_norm_stats(yr);
                    *iv = is;
                    for c in 0..nout {
                        let x = (yr[c] - mean) * is;
                        xr[c] = x;
                        let v = x * theta[gm + c] + theta[bt + c];
                        or[c] = if residual { or[c] + v } else { v };
                    }
                }
            } else if residual {
                o.iter_mut().zip(y.iter()).for_each(|(a, b)| *a += *b);
            } else {
                o.copy_from_slice(y);
            }
        });
    }

    /// Backward of [`Ctx::mlp_fwd`] from `dout` (the MLP's own output): parameter gradients
    /// into the parts' partial gradients, input gradients added into `dinputs` (column parts;
    /// for an edge MLP only the edge-latent part, the node parts' gradient `d0` of the first
    /// pre-activation is written to `d0_out` for the caller to scatter).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn mlp_bwd(
        &self,
        m: &MlpAt,
        inputs: &[&[f32]],
        tape: &MlpTape,
        dout: &[f32],
        dinputs: &mut [Option<&mut [f32]>],
        d0_out: Option<&mut [f32]>,
        parts: &mut [PartBufs],
    ) {
        let rows = tape.rows;
        if rows == 0 {
            return;
        }
        let nl = m.layers.len();
        let nout = m.output();
        let l0 = m.layers[0];
        let ks: [usize; MAX_INPUTS] = core::array::from_fn(|i| inputs.get(i).map_or(0, |x| x.len() / rows));
        // Column of each part: an edge MLP's single input is the last part of its first layer.
        let col0 = l0.inp - ks.iter().sum::<usize>();
        let mut din: [Option<Disjoint<'_, f32>>; MAX_INPUTS] = Default::default();
        for (d, s) in dinputs.iter_mut().zip(din.iter_mut()) {
            *s = d.as_deref_mut().map(Disjoint::new);
        }
        let d0s = d0_out.map(Disjoint::new);
        let span = span_of(m);
        let base = span.start;
        let pbs = Disjoint::new(parts);
        let (g, theta) = (self.g, self.theta);
        self.parts(rows, &|p, r| {
            let nr = r.len();
            // SAFETY: part p owns scratch p.
            let pb = unsafe { &mut pbs.range(p..p + 1)[0] };
            let PartBufs { d, dn, grad: pg, .. } = pb;
            // This part's share of the MLP's parameter gradient, at offsets from `base`.
            fit(pg, span.len());
            let dout = &dout[r.start * nout..r.end * nout];
            if let Some((gm, _)) = m.norm {
                size(d, dout.len());
                let nf = nout as f32;
                // Gamma and beta are adjacent in the layout.
                let (dg, db) = pg[gm - base..gm - base + 2 * nout].split_at_mut(nout);
                let gamma = &theta[gm..gm + nout];
                let xhs = &tape.xhat[r.start * nout..r.end * nout];
                let rows_in = dout.chunks_exact(nout).zip(xhs.chunks_exact(nout)).zip(&tape.inv_std[r.clone()]);
                for (dr, ((di, xh), iv)) in d.chunks_exact_mut(nout).zip(rows_in) {
                    for (((((dv, &dy), &x), g), b), &gv) in
                        dr.iter_mut().zip(di).zip(xh).zip(dg.iter_mut()).zip(db.iter_mut()).zip(gamma)
                    {
                        *g += dy * x;
                        *b += dy;
                        *dv = dy * gv;
                    }
                    // Partial sums, as in the forward (serial sums kept this loop scalar).
                    let (m1, m2) = (lane_sum(dr, |v| v) / nf, lane_dot(dr, xh) / nf);
                    for (dv, &x) in dr.iter_mut().zip(xh) {
                        *dv = iv * (*dv - m1 - x * m2);
                    }
                }
            } else {
                d.clear();
                d.extend_from_slice(dout);
            }
            for li in (1..nl).rev() {
                let l = &m.layers[li];
                let off = hidden_at(m, rows, li - 1);
                let x = &tape.hidden[off + r.start * l.inp..off + r.end * l.inp];
                colsum(d, l.out, &mut pg[l.b - base..l.b - base + l.out]);
                let (dy, xm) = (Mat { data: d, ld: l.out }, Mat { data: x, ld: l.inp });
                g.tn(nr, l.out, l.inp, dy, xm, &mut pg[l.w - base..], l.inp);
                size(dn, nr * l.inp);
                let w = Mat { data: &theta[l.w..], ld: l.inp };
                g.nn_out(nr, l.inp, l.out, Mat { data: d, ld: l.out }, w, Out::Set, dn, l.inp);
                // ReLU: the gradient passes where the activation is positive.
                for (gv, a) in dn.iter_mut().zip(x) {
                    *gv = if *a > 0.0 { *gv } else { 0.0 };
                }
                core::mem::swap(d, dn);
            }
            colsum(d, l0.out, &mut pg[l0.b - base..l0.b - base + l0.out]);
            let mut col = col0;
            for (i, x) in inputs.iter().enumerate() {
                let k = ks[i];
                let xr = &x[r.start * k..r.end * k];
                g.tn(
                    nr,
                    l0.out,
                    k,
                    Mat { data: d, ld: l0.out },
                    Mat { data: xr, ld: k },
                    &mut pg[l0.w - base + col..],
                    l0.inp,
                );
                if let Some(dx) = &din[i] {
                    // SAFETY: rows `r` of the input gradient belong to this part.
                    let dxr = unsafe { dx.range(r.start * k..r.end * k) };
                    g.nn(
                        nr,
                        k,
                        l0.out,
                        Mat { data: d, ld: l0.out },
                        Mat { data: &theta[l0.w + col..], ld: l0.inp },
                        dxr,
                        k,
                    );
                }
                col += k;
            }
            if let Some(d0s) = &d0s {
                // SAFETY: rows `r` belong to this part.
                unsafe { d0s.range(r.start * l0.out..r.end * l0.out) }.copy_from_slice(d);
            }
        });
        self.reduce(parts, rows, span);
    }

    /// Backward of [`Ctx::project`]: `dW_part += dyᵀ · x`, and `dx += dy · W_part` when asked.
    #[allow(clippy::too_many_arguments)]
    fn project_bwd(
        &self,
        l: &LinearAt,
        col: usize,
        k: usize,
        x: &[f32],
        dy: &[f32],
        dx: Option<&mut [f32]>,
        parts: &mut [PartBufs],
    ) {
        let rows = x.len() / k;
        let n = l.out;
        let dxs = dx.map(Disjoint::new);
        let span = l.w..l.w + l.inp * l.out;
        let pbs = Disjoint::new(parts);
        let (g, theta) = (self.g, self.theta);
        self.parts(rows, &|p, r| {
            // SAFETY: part p owns scratch p and rows `r` of `dx`.
            let pg = unsafe { &mut pbs.range(p..p + 1)[0].grad };
            fit(pg, span.len());
            let dyr = &dy[r.start * n..r.end * n];
            let a = Mat { data: dyr, ld: n };
            g.tn(r.len(), n, k, a, Mat { data: &x[r.start * k..], ld: k }, &mut pg[col..], l.inp);
            if let Some(dxs) = &dxs {
                // SAFETY: as above.
                let dxr = unsafe { dxs.range(r.start * k..r.end * k) };
                g.nn(r.len(), k, n, a, Mat { data: &theta[l.w + col..], ld: l.inp }, dxr, k);
            }
        });
        self.reduce(parts, rows, span);
    }
}

fn colsum(d: &[f32], w: usize, out: &mut [f32]) {
    for row in d.chunks_exact(w) {
        out.iter_mut().zip(row).for_each(|(a, b)| *a += *b);
    }
}

/// One edge set of an edge MLP pass (as in the generic path).
#[derive(Clone, Copy)]
pub(super) struct EdgeSet<'a> {
    pub(super) xt: &'a [f32],
    pub(super) xs: &'a [f32],
    pub(super) target: &'a [u32],
    pub(super) source: &'a [u32],
}

/// Edge MLP forward: messages into `msg`, added to `lat` and summed into `agg` at the targets.
#[allow(clippy::too_many_arguments)]
pub(super) fn edge_fwd(
    c: &Ctx<'_>,
    m: &MlpAt,
    h: usize,
    es: EdgeSet<'_>,
    lat: &mut Vec<f32>,
    agg: &mut [f32],
    et: &mut EdgeTape,
    pt: &mut Vec<f32>,
    ps: &mut Vec<f32>,
    msg: &mut Vec<f32>,
    parts: &mut [PartBufs],
) {
    let l0 = m.layers[0];
    let w = l0.out;
    let ne = es.target.len();
    size(pt, es.xt.len() / h * w);
    c.project(&l0, 0, h, es.xt, pt);
    size(ps, es.xs.len() / h * w);
    c.project(&l0, h, h, es.xs, ps);
    // The tape keeps the latents this pass reads by taking their buffer (no copy); the pass
    // writes the updated latents (`+ msg` on the first `ne` rows) into the other.
    core::mem::swap(&mut et.lat_in, lat);
    size(lat, et.lat_in.len());
    size(msg, ne * h);
    let lat_in = &et.lat_in[..ne * h];
    let first = First::Edge { lat: lat_in, pt, ps, target: es.target, source: es.source };
    c.mlp_fwd(m, first, ne, &mut et.mlp, msg, false, parts);
    c.sum(lat_in, msg, &mut lat[..ne * h]);
    lat[ne * h..].copy_from_slice(&et.lat_in[ne * h..]);
    c.scatter_add(msg, es.target, h, agg);
}

/// Edge MLP backward from the message gradient `dm`; adds into `dlat`, `dxt` and `dxs` (`None`:
/// the source rows are the target rows).
#[allow(clippy::too_many_arguments)]
pub(super) fn edge_bwd(
    c: &Ctx<'_>,
    m: &MlpAt,
    h: usize,
    et: &EdgeTape,
    es: EdgeSet<'_>,
    dm: &[f32],
    dlat: &mut [f32],
    dxt: &mut [f32],
    dxs: Option<&mut [f32]>,
    tmp: (&mut Vec<f32>, &mut Vec<f32>, &mut Vec<f32>),
    parts: &mut [PartBufs],
) {
    let (d0, dpt, dps) = tmp;
    let l0 = m.layers[0];
    let w = l0.out;
    let ne = es.target.len();
    size(d0, ne * w);
    c.mlp_bwd(m, &[&et.lat_in[..ne * h]], &et.mlp, dm, &mut [Some(dlat)], Some(d0), parts);
    fit(dpt, es.xt.len() / h * w);
    c.scatter_add(d0, es.target, w, dpt);
    fit(dps, es.xs.len() / h * w);
    c.scatter_add(d0, es.source, w, dps);
    c.project_bwd(&l0, 0, h, es.xt, dpt, Some(&mut *dxt), parts);
    match dxs {
        Some(dxs) => c.project_bwd(&l0, h, h, es.xs, dps, Some(dxs), parts),
        None => c.project_bwd(&l0, h, h, es.xs, dps, Some(dxt), parts),
    }
}
