//! The trainer's fast f32 path: the same forward and backward as [`Network::forward`] /
//! [`Network::backward`] (same data path, same tape contents), on SIMD products
//! ([`super::gemm`]), split between threads by an [`Executor`], with every buffer kept in a
//! reusable [`FastWorkspace`] (grow-only: a steady-state step allocates nothing).
//!
//! Determinism: every parallel loop is cut into [`PARTS`] fixed row (or column) ranges whatever
//! the thread count; row-local results do not depend on the cut, and sums over rows (weight and
//! bias gradients) go to one partial gradient per range, added in range order at the end. One
//! thread and two threads give bitwise the same gradients.

use super::gemm::{Gemm, Mat, Out};
use super::inputs::StepData;
use super::layout::MlpAt;
use super::network::{Network, Stats};
use crate::error::{Error, Result};
use crate::exec::Executor;
use crate::features::{BODY_EDGE_WIDTH, EDGE_NORMALISED, EDGE_WIDTH, NODE_NORMALISED, NODE_WIDTH};
use crate::kernels::{lane_dot, lane_sum, layer_norm_stats};
use crate::model::EdgeKey;
use crate::sim::Graph;
use alloc::vec::Vec;
use core::marker::PhantomData;
use core::ops::Range;

/// Fixed ranges every parallel loop is cut into (independent of the thread count).
pub const PARTS: usize = 4;

/// Most column parts of an MLP's first layer (node latents, up to four slots... and the body).
const MAX_INPUTS: usize = 8;

/// Mutable access to disjoint ranges of one slice from parallel tasks.
struct Shared<'a, T> {
    ptr: *mut T,
    len: usize,
    _m: PhantomData<&'a mut [T]>,
}

// SAFETY: sub-slices are handed out only by the unsafe `range`, whose callers guarantee that
// ranges used at the same time never overlap; sending them is then as safe as sending `&mut [T]`.
unsafe impl<T: Send> Sync for Shared<'_, T> {}
// SAFETY: as above.
unsafe impl<T: Send> Send for Shared<'_, T> {}

impl<'a, T> Shared<'a, T> {
    fn new(s: &'a mut [T]) -> Self {
        Shared { ptr: s.as_mut_ptr(), len: s.len(), _m: PhantomData }
    }

    /// # Safety
    /// No two ranges in use at the same time may overlap.
    #[allow(clippy::mut_from_ref)]
    unsafe fn range(&self, r: Range<usize>) -> &'a mut [T] {
        assert!(r.start <= r.end && r.end <= self.len, "shared range out of bounds");
        // SAFETY: in bounds of a slice borrowed mutably for 'a; no overlapping range is alive.
        unsafe { core::slice::from_raw_parts_mut(self.ptr.add(r.start), r.end - r.start) }
    }
}

fn split(total: usize, p: usize) -> Range<usize> {
    (p * total / PARTS)..((p + 1) * total / PARTS)
}

/// Resizes to `n` zeros, keeping the capacity.
fn fit(v: &mut Vec<f32>, n: usize) {
    v.clear();
    v.resize(n, 0.0);
}

/// Resizes to `n` elements without clearing the kept ones (for buffers the caller overwrites).
fn size(v: &mut Vec<f32>, n: usize) {
    v.resize(n, 0.0);
}

/// What an MLP's backward needs from its forward (the fast twin of `ops::MlpCache`).
#[derive(Clone, Debug, Default)]
struct MlpTape {
    rows: usize,
    /// Post-ReLU outputs of the hidden layers, layer after layer, each `rows × width`.
    hidden: Vec<f32>,
    /// LayerNorm's normalised values, `rows × out`.
    xhat: Vec<f32>,
    /// LayerNorm's `1 / sqrt(var + eps)` per row.
    inv_std: Vec<f32>,
}

impl MlpTape {
    fn shape(&mut self, m: &MlpAt, rows: usize) {
        self.rows = rows;
        let hid: usize = m.layers[..m.layers.len() - 1].iter().map(|l| rows * l.out).sum();
        size(&mut self.hidden, hid);
        let (x, i) = if m.norm.is_some() { (rows * m.output(), rows) } else { (0, 0) };
        size(&mut self.xhat, x);
        size(&mut self.inv_std, i);
    }
}

/// Offset of hidden layer `l` in [`MlpTape::hidden`].
fn hidden_at(m: &MlpAt, rows: usize, l: usize) -> usize {
    m.layers[..l].iter().map(|x| rows * x.out).sum()
}

#[derive(Clone, Debug, Default)]
struct EdgeTape {
    lat_in: Vec<f32>,
    mlp: MlpTape,
}

#[derive(Clone, Debug, Default)]
struct BlockTape {
    x_in: Vec<f32>,
    edges: Vec<EdgeTape>,
    /// body->garment, garment->body.
    body: [EdgeTape; 2],
    has_body: bool,
    slots: Vec<Vec<f32>>,
    node: MlpTape,
}

/// Scratch owned by one of the [`PARTS`] ranges.
#[derive(Clone, Debug, Default)]
struct PartBufs {
    y: Vec<f32>,
    d: Vec<f32>,
    dn: Vec<f32>,
    /// This range's share of the parameter gradient (flat layout).
    grad: Vec<f32>,
}

/// Forward and backward temporaries.
#[derive(Clone, Debug, Default)]
struct Temps {
    x: Vec<f32>,
    lat: [Vec<f32>; 4],
    g2b: Vec<f32>,
    b2g: Vec<f32>,
    pt: Vec<f32>,
    ps: Vec<f32>,
    gath: Vec<f32>,
    local: Vec<f32>,
    msg: Vec<f32>,
    iota: Vec<u32>,
    dx: Vec<f32>,
    dx_in: Vec<f32>,
    dslots: Vec<Vec<f32>>,
    dlat: [Vec<f32>; 4],
    dg2b: Vec<f32>,
    db2g: Vec<f32>,
    d0: Vec<f32>,
    dm: Vec<f32>,
    dxg: Vec<f32>,
    dxl: Vec<f32>,
    gath2: Vec<f32>,
    ddec: Vec<f32>,
    dnf: Vec<f32>,
}

/// The activations of the last [`Network::forward_fast`].
#[derive(Clone, Debug, Default)]
struct FastTape {
    node_in: Vec<f32>,
    node_enc: MlpTape,
    edge_in: [Vec<f32>; 4],
    edge_enc: [MlpTape; 4],
    edge_on: [bool; 4],
    g2b_in: Vec<f32>,
    b2g_in: Vec<f32>,
    body_enc: [MlpTape; 2],
    blocks: Vec<BlockTape>,
    x_final: Vec<f32>,
    dec: MlpTape,
}

/// Everything the fast path keeps between calls: the transposed weights of the current
/// parameters, the tape of the last forward, temporaries and per-range partial gradients.
/// Buffers only grow, so after the first steps of a run a step allocates nothing.
#[derive(Clone, Debug)]
pub struct FastWorkspace {
    gemm: Gemm,
    /// Every Linear layer of the network last run (read from the layout once).
    linears: Vec<super::layout::LinearAt>,
    /// The layout `linears` belongs to.
    layout: Option<super::layout::Layout>,
    /// Per Linear layer, its weight transposed (`[in, out]`), at the layer's offset.
    wt: Vec<f32>,
    tape: FastTape,
    tmp: Temps,
    parts: Vec<PartBufs>,
    /// Decoder output of the last forward (normalised accelerations), `n_garment × 3`.
    pub decoded: Vec<f32>,
    /// Predicted positions of the last forward at the next frame, m (pinned vertices at their
    /// targets).
    pub new_pos: Vec<[f32; 3]>,
}

impl Default for FastWorkspace {
    fn default() -> Self {
        FastWorkspace::new(Gemm::best())
    }
}

impl FastWorkspace {
    /// An empty workspace running products on `gemm` ([`Gemm::best`] for training,
    /// [`Gemm::scalar`] for reference runs).
    pub fn new(gemm: Gemm) -> FastWorkspace {
        FastWorkspace {
            gemm,
            linears: Vec::new(),
            layout: None,
            wt: Vec::new(),
            tape: FastTape::default(),
            tmp: Temps::default(),
            parts: (0..PARTS).map(|_| PartBufs::default()).collect(),
            decoded: Vec::new(),
            new_pos: Vec::new(),
        }
    }
}

/// The parameters and how to run products over them.
#[derive(Clone, Copy)]
struct Ctx<'a> {
    g: Gemm,
    exec: &'a dyn Executor,
    theta: &'a [f32],
    wt: &'a [f32],
    /// The backward's parameter gradient (each product's parts' shares are added into it right
    /// after the product, while they are still in cache).
    grad: Option<&'a Shared<'a, f32>>,
}

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
enum First<'a> {
    Parts(&'a [&'a [f32]]),
    Edge { lat: &'a [f32], pt: &'a [f32], ps: &'a [f32], target: &'a [u32], source: &'a [u32] },
}

impl Ctx<'_> {
    /// Adds the partial gradients over `span` of the parts that ran on `rows` rows into the
    /// gradient, in part order (the same sum whatever the thread count).
    fn reduce(&self, parts: &[PartBufs], rows: usize, span: Range<usize>) {
        let Some(gs) = self.grad else { return };
        self.parts(span.len(), &|_, r| {
            // SAFETY: disjoint ranges of the gradient.
            let g = unsafe { gs.range(span.start + r.start..span.start + r.end) };
            // Parts with no rows did not run: their scratch holds an earlier product's share.
            for (_, pb) in parts.iter().enumerate().filter(|&(p, _)| !split(rows, p).is_empty()) {
                g.iter_mut().zip(&pb.grad[r.clone()]).for_each(|(a, b)| *a += *b);
            }
        });
    }

    /// Calls `f(p, range)` for every non-empty range `p` of `0..rows`.
    fn parts(&self, rows: usize, f: &(dyn Fn(usize, Range<usize>) + Sync)) {
        if rows == 0 {
            return;
        }
        self.exec.run(PARTS, &|p| {
            let r = split(rows, p);
            if !r.is_empty() {
                f(p, r);
            }
        });
    }

    /// `y = x · W_partᵀ` for the column part `col..col+k` of layer `l` (no bias), row-split.
    fn project(&self, l: &super::layout::LinearAt, col: usize, k: usize, x: &[f32], y: &mut [f32]) {
        let rows = x.len() / k;
        let n = l.out;
        let ys = Shared::new(y);
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
    fn mlp_fwd(
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
        let hid = Shared::new(&mut tape.hidden);
        let xhat = Shared::new(&mut tape.xhat);
        let inv = Shared::new(&mut tape.inv_std);
        let outs = Shared::new(out);
        let pbs = Shared::new(parts);
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
    fn mlp_bwd(
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
        let mut din: [Option<Shared<'_, f32>>; MAX_INPUTS] = Default::default();
        for (d, s) in dinputs.iter_mut().zip(din.iter_mut()) {
            *s = d.as_deref_mut().map(Shared::new);
        }
        let d0s = d0_out.map(Shared::new);
        let span = span_of(m);
        let base = span.start;
        let pbs = Shared::new(parts);
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
        l: &super::layout::LinearAt,
        col: usize,
        k: usize,
        x: &[f32],
        dy: &[f32],
        dx: Option<&mut [f32]>,
        parts: &mut [PartBufs],
    ) {
        let rows = x.len() / k;
        let n = l.out;
        let dxs = dx.map(Shared::new);
        let span = l.w..l.w + l.inp * l.out;
        let pbs = Shared::new(parts);
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

    /// `dst[idx[e]] += src[e]` (rows `w` wide). Each part owns a range of destination rows and
    /// scans every index, so repeated indices sum in edge order whatever the split (rows of
    /// whole vectors: splitting by columns left a few floats per row and part at small widths).
    fn scatter_add(&self, src: &[f32], idx: &[u32], w: usize, dst: &mut [f32]) {
        if w == 0 {
            return;
        }
        let rows = dst.len() / w;
        let ds = Shared::new(dst);
        self.exec.run(PARTS, &|p| {
            let own = split(rows, p);
            if own.is_empty() {
                return;
            }
            // SAFETY: destination row ranges of different parts are disjoint.
            let d = unsafe { ds.range(own.start * w..own.end * w) };
            for (row, &i) in src.chunks_exact(w).zip(idx) {
                let i = i as usize;
                if own.contains(&i) {
                    let o = (i - own.start) * w;
                    d[o..o + w].iter_mut().zip(row).for_each(|(a, b)| *a += *b);
                }
            }
        });
    }

    /// `dst[e] = src[idx[e]]` (+ `add[e]` when given), row-split.
    fn gather(&self, src: &[f32], idx: &[u32], w: usize, add: Option<&[f32]>, dst: &mut [f32]) {
        let ds = Shared::new(dst);
        self.parts(idx.len(), &|_, r| {
            // SAFETY: row ranges of different parts are disjoint.
            let d = unsafe { ds.range(r.start * w..r.end * w) };
            for (e, row) in r.zip(d.chunks_exact_mut(w)) {
                let i = idx[e] as usize;
                row.copy_from_slice(&src[i * w..(i + 1) * w]);
                if let Some(add) = add {
                    row.iter_mut().zip(&add[e * w..(e + 1) * w]).for_each(|(a, b)| *a += *b);
                }
            }
        });
    }

    /// `dst = a + b`, row-split.
    fn sum(&self, a: &[f32], b: &[f32], dst: &mut [f32]) {
        let ds = Shared::new(dst);
        self.parts(a.len(), &|_, r| {
            // SAFETY: disjoint ranges.
            let d = unsafe { ds.range(r.clone()) };
            d.iter_mut().zip(&a[r.clone()]).zip(&b[r]).for_each(|((o, x), y)| *o = *x + *y);
        });
    }
}

fn colsum(d: &[f32], w: usize, out: &mut [f32]) {
    for row in d.chunks_exact(w) {
        out.iter_mut().zip(row).for_each(|(a, b)| *a += *b);
    }
}

/// One edge set of an edge MLP pass (as in the generic path).
#[derive(Clone, Copy)]
struct EdgeSet<'a> {
    xt: &'a [f32],
    xs: &'a [f32],
    target: &'a [u32],
    source: &'a [u32],
}

/// Edge MLP forward: messages into `msg`, added to `lat` and summed into `agg` at the targets.
#[allow(clippy::too_many_arguments)]
fn edge_fwd(
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
fn edge_bwd(
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

fn normalise(rows: &mut [f32], stride: usize, (mean, std): &(Vec<f32>, Vec<f32>), width: usize) {
    for r in rows.chunks_exact_mut(stride) {
        for c in 0..width {
            r[c] = (r[c] - mean[c]) / std[c];
        }
    }
}

impl Network {
    /// Checks the spec fits the fast path's fixed-size tables.
    fn check_fast(&self) -> Result<()> {
        let too_deep = self.layout.mlps().iter().any(|m| m.layers.len() > 8);
        let too_wide = self.spec.blocks.iter().any(|b| self.spec.node_inputs(b) > MAX_INPUTS);
        // The LayerNorm backward reads gamma and beta as one block.
        let split_norm = self.layout.mlps().iter().any(|m| m.norm.is_some_and(|(g, b)| b != g + m.output()));
        if too_deep || too_wide || split_norm {
            return Err(Error::IncompatibleModel {
                reason: "the fast trainer path supports at most 8 layers and 8 node inputs",
            });
        }
        Ok(())
    }

    /// The fast f32 forward pass: the same result as [`Network::forward`] (up to summation
    /// order), its outputs in `ws.new_pos` / `ws.decoded` and its tape kept in `ws` for
    /// [`Network::backward_fast`]. Products run on `ws`'s [`Gemm`] path, loops split over `exec`.
    ///
    /// # Errors
    /// As [`Network::forward`].
    pub fn forward_fast(
        &self,
        ws: &mut FastWorkspace,
        exec: &dyn Executor,
        theta: &[f32],
        stats: &Stats<f32>,
        graph: &Graph,
        step: &StepData,
    ) -> Result<()> {
        let lay = &self.layout;
        if theta.len() != lay.len {
            return Err(Error::SizeMismatch { what: "parameter vector", expected: lay.len, got: theta.len() });
        }
        if ws.layout.as_ref() != Some(lay) {
            self.check_fast()?;
            ws.linears = lay.mlps().iter().flat_map(|m| m.layers.iter().copied()).collect();
            ws.layout = Some(lay.clone());
        }
        // Transposed weights of the current parameters, one layer per task.
        size(&mut ws.wt, lay.len);
        {
            let wts = Shared::new(&mut ws.wt);
            let linears = &ws.linears;
            exec.run(linears.len(), &|j| {
                let l = &linears[j];
                // SAFETY: every layer's weights occupy their own range of the layout.
                let wt = unsafe { wts.range(l.w..l.w + l.inp * l.out) };
                for o in 0..l.out {
                    for i in 0..l.inp {
                        wt[i * l.out + o] = theta[l.w + o * l.inp + i];
                    }
                }
            });
        }
        let FastWorkspace { gemm, wt, tape: t, tmp, parts, decoded, new_pos, .. } = ws;
        let c = Ctx { g: *gemm, exec, theta, wt, grad: None };
        let h = self.spec.latent;
        let (v, na) = (step.n_garment, step.n_active);
        let rows = v + na;
        let nb = step.prefix[0];
        // Node features: the embedding columns from the current tables, then normalise, encode.
        let nf = &mut t.node_in;
        nf.clear();
        nf.extend_from_slice(&step.node_features);
        lay.fill_embeddings(theta, &step.node_type, &step.node_level, nf);
        normalise(nf, NODE_WIDTH, &stats.node, NODE_NORMALISED);
        let x = &mut tmp.x;
        fit(x, rows * h);
        c.mlp_fwd(&lay.node_encoder, First::Parts(&[&t.node_in]), rows, &mut t.node_enc, x, false, parts);
        // Mesh and coarse edges.
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            let k = key as usize;
            t.edge_on[k] = !step.edge_features[k].is_empty();
            if !t.edge_on[k] {
                continue;
            }
            let enc = self
                .spec
                .encoder_index(key)
                .and_then(|i| lay.edge_encoders.get(i))
                .ok_or(Error::IncompatibleModel { reason: "the model has no encoder for an edge set it uses" })?;
            let ef = &mut t.edge_in[k];
            ef.clear();
            ef.extend_from_slice(&step.edge_features[k]);
            normalise(ef, EDGE_WIDTH, &stats.edge, EDGE_NORMALISED);
            let ne = ef.len() / EDGE_WIDTH;
            fit(&mut tmp.lat[k], ne * h);
            c.mlp_fwd(enc, First::Parts(&[&t.edge_in[k]]), ne, &mut t.edge_enc[k], &mut tmp.lat[k], false, parts);
        }
        // Body edges: both directions, one normaliser, one encoder.
        fit(&mut tmp.g2b, nb * h);
        fit(&mut tmp.b2g, nb * h);
        if nb > 0 {
            let enc = lay.body_encoder.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
            for (src, dst) in [(&step.g2b_features, &mut t.g2b_in), (&step.b2g_features, &mut t.b2g_in)] {
                dst.clear();
                dst.extend_from_slice(&src[..nb * BODY_EDGE_WIDTH]);
                normalise(dst, BODY_EDGE_WIDTH, &stats.body_edge, BODY_EDGE_WIDTH);
            }
            let [eg, eb] = &mut t.body_enc;
            c.mlp_fwd(enc, First::Parts(&[&t.g2b_in]), nb, eg, &mut tmp.g2b, false, parts);
            c.mlp_fwd(enc, First::Parts(&[&t.b2g_in]), nb, eb, &mut tmp.b2g, false, parts);
        }
        tmp.iota.clear();
        tmp.iota.extend(0..nb as u32);
        let has_body_slot = self.spec.effects.body;
        t.blocks.resize_with(self.spec.blocks.len(), BlockTape::default);
        for (bi, (bs, ba)) in self.spec.blocks.iter().zip(&lay.blocks).enumerate() {
            let n_slots = bs.keys.len() + usize::from(has_body_slot);
            let bt = &mut t.blocks[bi];
            bt.x_in.clear();
            bt.x_in.extend_from_slice(&tmp.x);
            bt.slots.resize_with(n_slots, Vec::new);
            bt.slots.iter_mut().for_each(|s| fit(s, rows * h));
            bt.edges.resize_with(bs.keys.len(), EdgeTape::default);
            for (ki, (&key, m)) in bs.keys.iter().zip(&ba.edges).enumerate() {
                let list = graph.edges(key)?;
                let k = key as usize;
                let et = &mut bt.edges[ki];
                match key.coarse_level() {
                    None => {
                        let xg = &bt.x_in[..v * h];
                        let es = EdgeSet { xt: xg, xs: xg, target: &list.target, source: &list.source };
                        let agg = &mut bt.slots[ki][..v * h];
                        edge_fwd(&c, m, h, es, &mut tmp.lat[k], agg, et, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
                    }
                    Some(l) => {
                        let nodes = &graph.coarse[l].nodes;
                        size(&mut tmp.gath, nodes.len() * h);
                        c.gather(&bt.x_in, nodes, h, None, &mut tmp.gath);
                        fit(&mut tmp.local, nodes.len() * h);
                        let es = EdgeSet { xt: &tmp.gath, xs: &tmp.gath, target: &list.target, source: &list.source };
                        let lat = &mut tmp.lat[k];
                        edge_fwd(&c, m, h, es, lat, &mut tmp.local, et, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
                        c.scatter_add(&tmp.local, nodes, h, &mut bt.slots[ki]);
                    }
                }
            }
            let n = self.body_rows(bi, step);
            bt.has_body = n > 0;
            if n > 0 {
                let m = ba.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                size(&mut tmp.gath, n * h);
                c.gather(&bt.x_in, &step.body_garment[..n], h, None, &mut tmp.gath);
                let xg = &tmp.gath;
                let xb = &bt.x_in[v * h..rows * h];
                let slot = &mut bt.slots[bs.keys.len()];
                let [tb, tg] = &mut bt.body;
                // body -> garment: per edge, then into the garment rows.
                fit(&mut tmp.local, n * h);
                let es = EdgeSet { xt: xg, xs: xb, target: &tmp.iota[..n], source: &step.body_active[..n] };
                let lat = &mut tmp.b2g;
                edge_fwd(&c, m, h, es, lat, &mut tmp.local, tb, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
                c.scatter_add(&tmp.local, &step.body_garment[..n], h, slot);
                // garment -> body: summed per active body node.
                let es = EdgeSet { xt: xb, xs: xg, target: &step.body_active[..n], source: &tmp.iota[..n] };
                let (lat, agg) = (&mut tmp.g2b, &mut slot[v * h..rows * h]);
                edge_fwd(&c, m, h, es, lat, agg, tg, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
            }
            let mut inputs: [&[f32]; MAX_INPUTS] = [&[]; MAX_INPUTS];
            inputs[0] = &bt.x_in;
            for (s, i) in bt.slots.iter().zip(&mut inputs[1..]) {
                *i = s;
            }
            let first = First::Parts(&inputs[..1 + n_slots]);
            c.mlp_fwd(&ba.node, first, rows, &mut bt.node, &mut tmp.x, true, parts);
        }
        fit(decoded, v * 3);
        t.x_final.clear();
        t.x_final.extend_from_slice(&tmp.x);
        c.mlp_fwd(&lay.decoder, First::Parts(&[&t.x_final[..v * h]]), v, &mut t.dec, decoded, false, parts);
        let (mean, std) = &stats.output;
        new_pos.clear();
        new_pos.extend((0..v).map(|i| {
            let p = step.pos[i];
            if step.pinned[i] {
                return p;
            }
            let vel = step.velocity[i];
            core::array::from_fn(|k| p[k] + vel[k] + (decoded[3 * i + k] * std[k] + mean[k]))
        }));
        Ok(())
    }

    /// The fast backward pass of the last [`Network::forward_fast`] on `ws` (same `theta`,
    /// `stats`, `graph` and `step`) from `dpos = dL/d(new positions)`: adds `dL/dθ` into `grad`.
    /// One thread and several threads give bitwise the same gradient.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for buffers of the wrong length or a workspace whose last forward
    /// ran on another step.
    #[allow(clippy::too_many_arguments)] // the forward's inputs, its tape, the seed and the output
    pub fn backward_fast(
        &self,
        ws: &mut FastWorkspace,
        exec: &dyn Executor,
        theta: &[f32],
        stats: &Stats<f32>,
        graph: &Graph,
        step: &StepData,
        dpos: &[[f32; 3]],
        grad: &mut [f32],
    ) -> Result<()> {
        let lay = &self.layout;
        if grad.len() != lay.len || theta.len() != lay.len || ws.wt.len() != lay.len {
            return Err(Error::SizeMismatch { what: "gradient vector", expected: lay.len, got: grad.len() });
        }
        let (v, na) = (step.n_garment, step.n_active);
        if dpos.len() != v || ws.new_pos.len() != v || ws.tape.blocks.len() != self.spec.blocks.len() {
            return Err(Error::SizeMismatch { what: "position gradient", expected: ws.new_pos.len(), got: dpos.len() });
        }
        let FastWorkspace { gemm, wt, tape, tmp, parts, .. } = ws;
        let gs = Shared::new(grad);
        let c = Ctx { g: *gemm, exec, theta, wt, grad: Some(&gs) };
        let h = self.spec.latent;
        let rows = v + na;
        let nb = step.prefix[0];
        // Integration: new_pos = pos + vel + decoded * std + mean (pinned vertices are fixed).
        let std = &stats.output.1;
        fit(&mut tmp.ddec, v * 3);
        for i in 0..v {
            if !step.pinned[i] {
                for k in 0..3 {
                    tmp.ddec[3 * i + k] = dpos[i][k] * std[k];
                }
            }
        }
        fit(&mut tmp.dx, rows * h);
        let xf = &tape.x_final[..v * h];
        c.mlp_bwd(&lay.decoder, &[xf], &tape.dec, &tmp.ddec, &mut [Some(&mut tmp.dx[..v * h])], None, parts);
        for k in 0..4 {
            fit(&mut tmp.dlat[k], tape.edge_in[k].len() / EDGE_WIDTH * h);
        }
        fit(&mut tmp.dg2b, nb * h);
        fit(&mut tmp.db2g, nb * h);
        let iota = &tmp.iota;
        for (bi, (bs, ba)) in self.spec.blocks.iter().zip(&lay.blocks).enumerate().rev() {
            let bt = &tape.blocks[bi];
            // Node update x_out = x_in + MLP([x_in, slots]).
            tmp.dx_in.clear();
            tmp.dx_in.extend_from_slice(&tmp.dx);
            let ns = bt.slots.len();
            tmp.dslots.resize_with(ns, Vec::new);
            tmp.dslots.iter_mut().for_each(|s| fit(s, rows * h));
            {
                let mut inputs: [&[f32]; MAX_INPUTS] = [&[]; MAX_INPUTS];
                inputs[0] = &bt.x_in;
                for (s, i) in bt.slots.iter().zip(&mut inputs[1..]) {
                    *i = s;
                }
                let mut dins: [Option<&mut [f32]>; MAX_INPUTS] = Default::default();
                dins[0] = Some(&mut tmp.dx_in);
                for (s, d) in tmp.dslots.iter_mut().zip(&mut dins[1..]) {
                    *d = Some(s);
                }
                c.mlp_bwd(&ba.node, &inputs[..1 + ns], &bt.node, &tmp.dx, &mut dins[..1 + ns], None, parts);
            }
            core::mem::swap(&mut tmp.dx, &mut tmp.dx_in);
            let x = &bt.x_in;
            if bt.has_body {
                let m = ba.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let n = self.body_rows(bi, step);
                let (garm, act) = (&step.body_garment[..n], &step.body_active[..n]);
                let dslot = &tmp.dslots[bs.keys.len()];
                size(&mut tmp.gath, n * h);
                c.gather(x, garm, h, None, &mut tmp.gath);
                let xg = &tmp.gath;
                let xb = &x[v * h..rows * h];
                fit(&mut tmp.dxg, n * h);
                let (_, dxb) = tmp.dx.split_at_mut(v * h);
                // dm = dlat + dagg[target]
                size(&mut tmp.dm, n * h);
                c.gather(&dslot[v * h..], act, h, Some(&tmp.dg2b[..n * h]), &mut tmp.dm);
                let es = EdgeSet { xt: xb, xs: xg, target: act, source: &iota[..n] };
                let scratch = (&mut tmp.d0, &mut tmp.local, &mut tmp.msg);
                let dl = &mut tmp.dg2b[..n * h];
                edge_bwd(&c, m, h, &bt.body[1], es, &tmp.dm, dl, dxb, Some(&mut tmp.dxg), scratch, parts);
                c.gather(dslot, garm, h, Some(&tmp.db2g[..n * h]), &mut tmp.dm);
                let es = EdgeSet { xt: xg, xs: xb, target: &iota[..n], source: act };
                let scratch = (&mut tmp.d0, &mut tmp.local, &mut tmp.msg);
                let dl = &mut tmp.db2g[..n * h];
                edge_bwd(&c, m, h, &bt.body[0], es, &tmp.dm, dl, &mut tmp.dxg, Some(dxb), scratch, parts);
                c.scatter_add(&tmp.dxg, garm, h, &mut tmp.dx);
            }
            for (ki, (&key, m)) in bs.keys.iter().zip(&ba.edges).enumerate() {
                let list = graph.edges(key)?;
                let k = key as usize;
                let et = &bt.edges[ki];
                let scratch = (&mut tmp.d0, &mut tmp.local, &mut tmp.msg);
                match key.coarse_level() {
                    None => {
                        let xg = &x[..v * h];
                        size(&mut tmp.dm, list.target.len() * h);
                        c.gather(&tmp.dslots[ki], &list.target, h, Some(&tmp.dlat[k]), &mut tmp.dm);
                        let es = EdgeSet { xt: xg, xs: xg, target: &list.target, source: &list.source };
                        let dxv = &mut tmp.dx[..v * h];
                        edge_bwd(&c, m, h, et, es, &tmp.dm, &mut tmp.dlat[k], dxv, None, scratch, parts);
                    }
                    Some(l) => {
                        let nodes = &graph.coarse[l].nodes;
                        size(&mut tmp.gath, nodes.len() * h);
                        c.gather(x, nodes, h, None, &mut tmp.gath);
                        size(&mut tmp.gath2, nodes.len() * h);
                        c.gather(&tmp.dslots[ki], nodes, h, None, &mut tmp.gath2);
                        size(&mut tmp.dm, list.target.len() * h);
                        c.gather(&tmp.gath2, &list.target, h, Some(&tmp.dlat[k]), &mut tmp.dm);
                        fit(&mut tmp.dxl, nodes.len() * h);
                        let es = EdgeSet { xt: &tmp.gath, xs: &tmp.gath, target: &list.target, source: &list.source };
                        edge_bwd(&c, m, h, et, es, &tmp.dm, &mut tmp.dlat[k], &mut tmp.dxl, None, scratch, parts);
                        c.scatter_add(&tmp.dxl, nodes, h, &mut tmp.dx);
                    }
                }
            }
        }
        // Encoders (their inputs are constants, except the embedding columns of the nodes).
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            let k = key as usize;
            if let (true, Some(enc)) =
                (tape.edge_on[k], self.spec.encoder_index(key).and_then(|i| lay.edge_encoders.get(i)))
            {
                c.mlp_bwd(enc, &[&tape.edge_in[k]], &tape.edge_enc[k], &tmp.dlat[k], &mut [None], None, parts);
            }
        }
        if let (true, Some(enc)) = (nb > 0, &lay.body_encoder) {
            c.mlp_bwd(enc, &[&tape.g2b_in], &tape.body_enc[0], &tmp.dg2b, &mut [None], None, parts);
            c.mlp_bwd(enc, &[&tape.b2g_in], &tape.body_enc[1], &tmp.db2g, &mut [None], None, parts);
        }
        fit(&mut tmp.dnf, tape.node_in.len());
        c.mlp_bwd(&lay.node_encoder, &[&tape.node_in], &tape.node_enc, &tmp.dx, &mut [Some(&mut tmp.dnf)], None, parts);
        // The embeddings last (their columns of the node features).
        let nstd = &stats.node.1;
        lay.embedding_backward(&tmp.dnf, nstd, &step.node_type, &step.node_level, grad);
        Ok(())
    }
}
