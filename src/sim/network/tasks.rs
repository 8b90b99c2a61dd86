//! The network's row passes split between tasks ([`Par`]): MLPs by row ranges, edge MLPs by
//! target ranges (body edges by edge ranges, both directions in one job), node projections
//! (each task gathering the rows it projects, where they are gathered), fills and row
//! reductions, each task with its own scratch; and the chunked MLP one task runs over its rows.
//! Copies between the passes (gathers, scatters, zeroing) run inside the jobs that use them,
//! each task on its own rows, rather than on the calling thread between jobs.

use super::{EdgeSplit, Net, TaskBufs, CHUNK};
use crate::error::{Error, Result};
use crate::exec::par::{first_error, split, Disjoint};
use crate::exec::Executor;
use crate::kernels::{self, EdgeInputs, EdgeMlp, Epilogue, Operand, MAX_OPERANDS};
use crate::model::file::MlpView;
use crate::sim::graph::EdgeList;
use alloc::vec::Vec;
use core::ops::Range;

/// Floats below which a fill or copy is not worth splitting between tasks.
const PAR_FLOATS: usize = 1 << 15;

/// Copies rows `idx` of `src` (`h` wide) into consecutive rows of `dst`.
fn gather(src: &[f32], idx: &[u32], h: usize, dst: &mut [f32]) {
    for (d, &g) in dst.chunks_exact_mut(h).zip(idx) {
        let g = g as usize;
        d.copy_from_slice(&src[g * h..(g + 1) * h]);
    }
}

/// Rows `idx` of `src` (`width` wide), gathered into `into` by the tasks of the job that reads
/// them, each task its own rows (split as that job splits `idx.len()` rows), so that the copy
/// runs on both threads and each thread then reads rows it has just written.
pub(super) struct Gather<'a> {
    pub(super) src: &'a [f32],
    pub(super) idx: &'a [u32],
    pub(super) width: usize,
    pub(super) into: &'a mut [f32],
}

/// The rows a product of [`Par::node_projections`] reads.
#[derive(Clone, Copy)]
pub(super) enum Input<'a> {
    /// These rows.
    Rows(&'a [f32]),
    /// The job's [`Gather`]ed rows.
    Gathered,
}

/// An edge MLP's node projections: rows for its edges' target ends and for their source ends.
#[derive(Clone, Copy)]
pub(super) struct Projections<'a> {
    pub(super) target: &'a [f32],
    pub(super) source: &'a [f32],
}

/// Where an edge MLP's messages are summed.
pub(super) enum Agg<'a> {
    /// Into these rows (target node `i` of the edge list is row `i`), which hold zeros or sums
    /// to add to.
    Rows(&'a mut [f32]),
    /// Into `local` (row `i` for target `i`), then copied to row `nodes[i]` of `slot`: each task
    /// zeroes, sums and copies the rows of its own targets. Rows of targets without edges are
    /// neither read nor copied: `slot` keeps whatever those rows held (zeros, in a block's
    /// message slots).
    Scattered { local: &'a mut [f32], nodes: &'a [u32], slot: &'a mut [f32] },
}

/// The body edges of a block as [`Par::body_messages`] reads them: garment vertex and active
/// body row of each edge, and `0, 1, 2, ...` (at least as many as edges).
pub(super) struct BodyLinks<'a> {
    pub(super) garment: &'a [u32],
    pub(super) body: &'a [u32],
    pub(super) iota: &'a [u32],
}

/// The executor with per-task scratch.
pub(super) struct Par<'w> {
    pub(super) exec: &'w dyn Executor,
    pub(super) tasks: &'w mut [TaskBufs],
    pub(super) errors: &'w mut [Option<Error>],
    pub(super) flops: &'w mut u64,
}

impl Par<'_> {
    /// Runs `f(task, scratch)` for `n` tasks and returns the first error.
    fn run(&mut self, n: usize, f: &(dyn Fn(usize, &mut TaskBufs) -> Result<()> + Sync)) -> Result<()> {
        let n = n.clamp(1, self.tasks.len());
        let tasks = Disjoint::new(&mut self.tasks[..n]);
        let errors = Disjoint::new(&mut self.errors[..n]);
        self.exec.run(n, &|t| {
            // SAFETY: the executor calls each task index once; index t owns element t.
            let (tb, err) = unsafe { (tasks.range(t..t + 1), errors.range(t..t + 1)) };
            if let (Some(tb), Some(err)) = (tb.first_mut(), err.first_mut()) {
                if let Err(e) = f(t, tb) {
                    *err = Some(e);
                }
            }
        });
        first_error(&mut self.errors[..n])
    }

    /// Zeroes the first `len` floats of each of `bufs`, split between tasks (megabytes per block
    /// at h = 128: serially it would hold back the second thread), in one job for a block's
    /// message slots (one per [`MAX_OPERANDS`] buffers), each task its share of every buffer.
    pub(super) fn fill_each(&mut self, bufs: &mut [Vec<f32>], len: usize) {
        // Split as one buffer's fill would be (small buffers are zeroed on the calling thread).
        let n = self.tasks.len().min(len.div_ceil(PAR_FLOATS)).max(1);
        for group in bufs.chunks_mut(MAX_OPERANDS) {
            let mut parts: [Option<Disjoint<'_, f32>>; MAX_OPERANDS] = [const { None }; MAX_OPERANDS];
            for (p, b) in parts.iter_mut().zip(group.iter_mut()) {
                let l = len.min(b.len());
                *p = Some(Disjoint::new(&mut b[..l]));
            }
            let _ = self.run(n, &|t, _| {
                for b in parts.iter().flatten() {
                    // SAFETY: ranges of different tasks are disjoint (out-of-bounds ranges are empty).
                    unsafe { b.range(split(len, n, t)) }.fill(0.0);
                }
                Ok(())
            });
        }
    }

    /// `mlp` over `rows` rows, split into row ranges per task (see [`Net::mlp_rows`]); with
    /// `residual`, `out = residual + mlp(inputs)` (each task copies its rows of `residual` first,
    /// in the same job).
    pub(super) fn mlp(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        inputs: &[Option<&[f32]>],
        rows: usize,
        out: &mut [f32],
        residual: Option<&[f32]>,
    ) -> Result<()> {
        if rows == 0 {
            return Ok(());
        }
        let w = out.len() / rows;
        let first: usize = net
            .parts(&mlp.layers[0])?
            .iter()
            .zip(inputs)
            .filter(|(_, x)| x.is_some())
            .map(|(p, _)| p.k() * p.n())
            .sum();
        let rest: usize = mlp.layers[1..].iter().map(|l| l.inp * l.out).sum();
        *self.flops += 2 * (rows * (first + rest)) as u64;
        // Even row ranges (not whole chunks: a few hundred rows in chunks of 256 would leave one
        // task with twice the work of another); rows are independent, so the split changes no bit.
        let n = self.tasks.len().min(rows.div_ceil(64)).max(1);
        let out = Disjoint::new(out);
        self.run(n, &|t, tb| {
            let r = split(rows, n, t);
            // SAFETY: row ranges of different tasks are disjoint.
            let o = unsafe { out.range(r.start * w..r.end * w) };
            if let Some(base) = residual {
                let b = base.get(r.start * w..r.end * w).ok_or(Error::SizeMismatch {
                    what: "residual rows",
                    expected: r.end * w,
                    got: base.len(),
                })?;
                o.copy_from_slice(b);
            }
            net.mlp_rows(mlp, inputs, r, o, residual.is_some(), tb)
        })
    }

    /// One static edge set through an edge MLP: both node projections of `x` (row-split, one
    /// job, gathering `x` first when it is [`Input::Gathered`]), then the fused kernel
    /// ([`Par::edge_kernel`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn edge_mlp(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        (x, gather): (Input<'_>, Option<Gather<'_>>),
        (list, split): (&EdgeList, &EdgeSplit),
        latent: &mut [f32],
        aggregate: Agg<'_>,
        proj: (&mut [f32], &mut [f32]),
    ) -> Result<()> {
        let [pt, ps] = self.node_projections(net, mlp, gather, [(x, 0, proj.0), (x, 1, proj.1)])?;
        self.edge_kernel(net, mlp, Projections { target: pt, source: ps }, (list, split), latent, aggregate)
    }

    /// The first layer's node projections of an edge MLP, in one job: product `i` is
    /// `x_i · W_{part_i}ᵀ` (part 0 the target's weights, 1 the source's), written to the start
    /// of `out_i`, which is returned cut to its rows. Products of [`Input::Gathered`] rows read
    /// `gather`'s rows, which each task copies first (see [`Par::linear_each`]).
    pub(super) fn node_projections<'o, const N: usize>(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        gather: Option<Gather<'_>>,
        products: [(Input<'_>, usize, &'o mut [f32]); N],
    ) -> Result<[&'o [f32]; N]> {
        let l0 = &mlp.layers[0];
        let (parts, h) = (net.parts(l0)?, l0.out);
        let gathered_rows = gather.as_ref().map_or(0, |g| g.idx.len());
        let outs = products.map(|(x, part, out)| {
            let n = match x {
                Input::Rows(x) => x.len() / h,
                Input::Gathered => gathered_rows,
            };
            (x, parts[part], &mut out[..n * h])
        });
        self.linear_each(net, gather, outs)
    }

    /// The edge MLP parts of `mlp` as the fused kernel takes them, and its useful FLOPs per edge.
    fn edge_parts<'m>(net: &Net<'m>, mlp: &MlpView<'m>) -> Result<(EdgeMlp<'m>, usize)> {
        let l = &mlp.layers;
        let p1 = net.parts(&l[0])?;
        let h = l[0].out;
        let em = EdgeMlp {
            w1_edge: p1[2],
            b1: l[0].bias,
            w2: net.parts(&l[1])?[0],
            b2: l[1].bias,
            w3: net.parts(&l[2])?[0],
            b3: l[2].bias,
            layer_norm: mlp.layer_norm,
        };
        let flops = 2 * (em.w1_edge.k() * h + em.w2.k() * em.w2.n() + em.w3.k() * em.w3.n());
        Ok((em, flops))
    }

    /// The fused edge kernel of `mlp` on the node projections `proj` of a static edge list, split by target ranges so that no target's sum spans two
    /// tasks.
    fn edge_kernel(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        proj: Projections<'_>,
        (list, split): (&EdgeList, &EdgeSplit),
        latent: &mut [f32],
        aggregate: Agg<'_>,
    ) -> Result<()> {
        let (em, edge_flops) = Self::edge_parts(net, mlp)?;
        let h = em.w2.k();
        let k_e = em.w3.n();
        let n_edges = latent.len() / k_e;
        *self.flops += (n_edges * edge_flops) as u64;
        let latent = Disjoint::new(latent);
        let (aggregate, scatter) = match aggregate {
            Agg::Rows(rows) => (Disjoint::new(rows), None),
            Agg::Scattered { local, nodes, slot } => (Disjoint::new(local), Some((nodes, Disjoint::new(slot)))),
        };
        let n = split.bounds.len() - 1;
        self.run(n, &|t, tb| {
            let (a, b) = (split.bounds[t], split.bounds[t + 1]);
            if a == b {
                return Ok(());
            }
            let (lo, hi) = (list.target[a] as usize, list.target[b - 1] as usize + 1);
            let inputs = EdgeInputs {
                p_target: &proj.target[lo * h..hi * h],
                p_source: proj.source,
                target: &split.rebased[a..b],
                source: &list.source[a..b],
            };
            // SAFETY: edge ranges are disjoint, and so are their target ranges (the split never
            // cuts a target's edges).
            let (lat, agg) = unsafe { (latent.range(a * k_e..b * k_e), aggregate.range(lo * k_e..hi * k_e)) };
            if scatter.is_some() {
                agg.fill(0.0);
            }
            net.kernels.edge_mlp(&em, &inputs, lat, agg, &mut tb.edge)?;
            if let Some((nodes, slot)) = &scatter {
                for (row, &node) in agg.chunks_exact(k_e).zip(&nodes[lo..hi]) {
                    let node = node as usize;
                    // SAFETY: `nodes` holds distinct rows (a coarse level's fine vertices), and
                    // tasks copy the rows of disjoint target ranges.
                    unsafe { slot.range(node * k_e..(node + 1) * k_e) }.copy_from_slice(row);
                }
            }
            Ok(())
        })
    }

    /// Both directions of a block's body edges through the body edge MLP `mlp` (one set of
    /// weights on swapped ends), in one job split by edge ranges. Each task, for its edges:
    /// body -> garment, whose target ends each have one body edge, so that a message is its
    /// garment vertex's sum, copied into row `garment[e]` of `slot` (the garment rows of the
    /// block's body slot); then garment -> body, one message per edge into `msgs`, for
    /// [`Par::reduce_rows`] to sum per active body node. `b2g` are the node projections of the
    /// body -> garment direction (target: per edge, source: per active body node), `g2b` those
    /// of the garment -> body direction (target: per active body node, gathered per edge into
    /// `per_edge` first; source: per edge), or `None` to leave that direction out (when nothing
    /// reads the body's next latents).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn body_messages(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        links: &BodyLinks<'_>,
        (b2g, g2b): (Projections<'_>, Option<Projections<'_>>),
        (b2g_latent, g2b_latent): (&mut [f32], &mut [f32]),
        msgs: &mut [f32],
        per_edge: &mut [f32],
        slot: &mut [f32],
    ) -> Result<()> {
        let (em, edge_flops) = Self::edge_parts(net, mlp)?;
        let h = em.w2.k();
        let k_e = em.w3.n();
        let n_edges = links.garment.len();
        let directions = if g2b.is_some() { 2 } else { 1 };
        *self.flops += (directions * n_edges * edge_flops) as u64;
        let (b2g_latent, g2b_latent) = (Disjoint::new(b2g_latent), Disjoint::new(g2b_latent));
        let (msgs, per_edge, slot) = (Disjoint::new(msgs), Disjoint::new(per_edge), Disjoint::new(slot));
        let tasks = self.tasks.len().min(n_edges.div_ceil(64)).max(1);
        self.run(tasks, &|t, tb| {
            let r = split(n_edges, tasks, t);
            if r.is_empty() {
                return Ok(());
            }
            let iota = &links.iota[..r.len()];
            // SAFETY: edge ranges (and so their message, latent and gathered rows) are disjoint
            // between tasks.
            let (m, pe) = unsafe { (msgs.range(r.start * k_e..r.end * k_e), per_edge.range(r.start * h..r.end * h)) };
            // body -> garment.
            m.fill(0.0);
            let inputs = EdgeInputs {
                p_target: &b2g.target[r.start * h..r.end * h],
                p_source: b2g.source,
                target: iota,
                source: &links.body[r.clone()],
            };
            // SAFETY: as above.
            let lat = unsafe { b2g_latent.range(r.start * k_e..r.end * k_e) };
            net.kernels.edge_mlp(&em, &inputs, lat, m, &mut tb.edge)?;
            for (row, &g) in m.chunks_exact(k_e).zip(&links.garment[r.clone()]) {
                let g = g as usize;
                // SAFETY: each garment vertex has at most one body edge, and tasks copy the rows
                // of disjoint edge ranges.
                unsafe { slot.range(g * k_e..(g + 1) * k_e) }.copy_from_slice(row);
            }
            // garment -> body.
            let Some(g2b) = &g2b else { return Ok(()) };
            gather(g2b.target, &links.body[r.clone()], h, pe);
            m.fill(0.0);
            let inputs =
                EdgeInputs { p_target: pe, p_source: g2b.source, target: iota, source: &links.iota[r.clone()] };
            // SAFETY: as above.
            let lat = unsafe { g2b_latent.range(r.start * k_e..r.end * k_e) };
            net.kernels.edge_mlp(&em, &inputs, lat, m, &mut tb.edge)
        })
    }

    /// `out_i = x_i · W_iᵀ` for each product (no bias), in one job: task `t` computes its share
    /// of the rows of each, the rows it would have in that product alone, so that each thread
    /// keeps the rows its edge kernel then reads (rather than one thread writing all of one
    /// product, whose rows the other would pull across cores). With `gather_first`, each task
    /// first copies its share of the gathered rows, which its [`Input::Gathered`] products then
    /// read. One hand-off instead of `N` (and the gather's); rows are independent, so the split
    /// changes no bit. Returns the outputs.
    fn linear_each<'o, const N: usize>(
        &mut self,
        net: &Net<'_>,
        gather_first: Option<Gather<'_>>,
        mut products: [(Input<'_>, kernels::Weights<'_>, &'o mut [f32]); N],
    ) -> Result<[&'o [f32]; N]> {
        let gathered_rows = gather_first.as_ref().map_or(0, |g| g.idx.len());
        let rows_of = |x: &Input<'_>, k: usize| match x {
            Input::Rows(x) => x.len() / k.max(1),
            Input::Gathered => gathered_rows,
        };
        let mut max_rows = gathered_rows;
        for (x, w, _) in &products {
            let rows = rows_of(x, w.k());
            max_rows = max_rows.max(rows);
            *self.flops += 2 * (rows * w.k() * w.n()) as u64;
        }
        let n = self.tasks.len().min(max_rows.div_ceil(64)).max(1);
        let gather_first = gather_first.map(|g| (g.src, g.idx, g.width, Disjoint::new(g.into)));
        let outs = products.each_mut().map(|(x, w, out)| (*x, *w, Disjoint::new(out)));
        self.run(n, &|t, tb| {
            let mut gathered: &[f32] = &[];
            if let Some((src, idx, width, into)) = &gather_first {
                let range = split(idx.len(), n, t);
                // SAFETY: row ranges of different tasks are disjoint.
                let rows = unsafe { into.range(range.start * width..range.end * width) };
                gather(src, &idx[range], *width, rows);
                gathered = rows;
            }
            for (x, w, out) in &outs {
                let (k, n_out) = (w.k(), w.n());
                let range = split(rows_of(x, k), n, t);
                if range.is_empty() {
                    continue;
                }
                let x = match x {
                    Input::Rows(x) => &x[range.start * k..range.end * k],
                    // The task's own gathered rows: the same split of the same row count.
                    Input::Gathered => gathered,
                };
                // SAFETY: row ranges of different tasks are disjoint, in each output.
                let o = unsafe { out.range(range.start * n_out..range.end * n_out) };
                let op = [Operand { x, w: *w }];
                net.kernels.linear(&op, None, &Epilogue::default(), o, &mut tb.lin)?;
            }
            Ok(())
        })?;
        Ok(products.map(|(_, _, out)| -> &'o [f32] { out }))
    }

    /// `out[r] = Σ src[perm[k]]` for `k` in `offsets[r]..offsets[r+1]`, row-split.
    pub(super) fn reduce_rows(&mut self, src: &[f32], offsets: &[u32], perm: &[u32], h: usize, out: &mut [f32]) {
        let rows = offsets.len() - 1;
        let n = self.tasks.len().min(rows.div_ceil(64)).max(1);
        let out = Disjoint::new(out);
        let _ = self.run(n, &|t, _| {
            let r = split(rows, n, t);
            // SAFETY: row ranges of different tasks are disjoint.
            let o = unsafe { out.range(r.start * h..r.end * h) };
            for (row, node) in o.chunks_exact_mut(h).zip(r) {
                row.fill(0.0);
                for &e in &perm[offsets[node] as usize..offsets[node + 1] as usize] {
                    let m = &src[e as usize * h..(e as usize + 1) * h];
                    row.iter_mut().zip(m).for_each(|(o, m)| *o += m);
                }
            }
            Ok(())
        });
    }
}

impl Net<'_> {
    /// Runs `mlp` over the rows `rows` (chunk by chunk). `inputs` are the column parts of the
    /// whole input (the parts of the first layer, in order; `None` is a part known to be zero
    /// and skipped); `out` holds just these rows and is added to when `residual`.
    fn mlp_rows(
        &self,
        mlp: &MlpView<'_>,
        inputs: &[Option<&[f32]>],
        rows: Range<usize>,
        out: &mut [f32],
        residual: bool,
        tb: &mut TaskBufs,
    ) -> Result<()> {
        let layers = &mlp.layers;
        let parts = self.parts(&layers[0])?;
        if parts.len() != inputs.len() {
            return Err(Error::IncompatibleModel { reason: "MLP input parts disagree with the model" });
        }
        let n_out = layers[layers.len() - 1].out;
        let (mut a, mut b) = (&mut tb.t1[..], &mut tb.t2[..]);
        let mut start = rows.start;
        while start < rows.end {
            let end = (start + CHUNK).min(rows.end);
            let r = end - start;
            let o = (start - rows.start) * n_out..(end - rows.start) * n_out;
            let mut ops = [Operand { x: &[], w: parts[0] }; MAX_OPERANDS];
            let mut n_ops = 0;
            for (x, w) in inputs.iter().zip(parts.iter()) {
                if let Some(x) = x {
                    ops[n_ops] = Operand { x: &x[start * w.k()..end * w.k()], w: *w };
                    n_ops += 1;
                }
            }
            for (li, l) in layers.iter().enumerate() {
                let last = li + 1 == layers.len();
                let ep = if last {
                    Epilogue { relu: false, layer_norm: mlp.layer_norm, residual }
                } else {
                    Epilogue { relu: true, layer_norm: None, residual: false }
                };
                if li == 0 {
                    let dst: &mut [f32] = if last { &mut out[o.clone()] } else { &mut a[..r * l.out] };
                    self.kernels.linear(&ops[..n_ops], Some(l.bias), &ep, dst, &mut tb.lin)?;
                } else {
                    let op = [Operand { x: &a[..r * l.inp], w: self.parts(l)?[0] }];
                    let dst: &mut [f32] = if last { &mut out[o.clone()] } else { &mut b[..r * l.out] };
                    self.kernels.linear(&op, Some(l.bias), &ep, dst, &mut tb.lin)?;
                    core::mem::swap(&mut a, &mut b);
                }
            }
            start = end;
        }
        Ok(())
    }
}
