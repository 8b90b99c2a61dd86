//! The network's forward pass over a step's buffers: encode, process (blocks), decode. Every
//! buffer is sized once by [`Workspace::new`]; [`Workspace::forward`] allocates nothing.

use super::graph::{EdgeList, Graph};
use crate::error::{Error, Result};
use crate::exec::par::{first_error, split, target_bounds, Disjoint};
use crate::exec::Executor;
use crate::features::{BODY_EDGE_WIDTH, EDGE_WIDTH, NODE_NORMALISED, NODE_WIDTH};
use crate::kernels::{self, EdgeInputs, EdgeMlp, Epilogue, Kernels, Operand, MAX_OPERANDS};
use crate::model::file::{MlpView, Model};
use crate::model::spec::EdgeKey;
use crate::normaliser::normalise_rows;
use alloc::vec;
use alloc::vec::Vec;
use core::ops::Range;

/// Rows per chunk when an MLP runs over many rows (bounds the hidden-layer temporaries).
const CHUNK: usize = 256;
/// Floats below which a fill or copy is not worth splitting between tasks.
const PAR_FLOATS: usize = 1 << 15;

/// What the forward pass needs to know about the step's body edges.
#[derive(Clone, Copy, Debug)]
pub struct BodyEdges<'a> {
    /// Garment vertex of each body edge, listed in [`Graph::body_order`].
    pub garment: &'a [u32],
    /// Active-body row (0-based among active body nodes) of each body edge.
    pub body: &'a [u32],
    /// Active body nodes.
    pub n_active: usize,
    /// How many leading edges stay at each level of descending depth: `[all, c0, c1, c2]`.
    pub prefix: [usize; 4],
}

/// An observation point of the forward pass (for parity tests and debugging).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// After the encoders.
    Encoded,
    /// After processor block `i` (0-based).
    Block(usize),
    /// The decoder's output (normalised accelerations, 3 wide, garment rows only).
    Decoded,
}

/// Node latents at a [`Stage`]: garment rows then active body rows, `h` wide.
#[derive(Clone, Copy, Debug)]
pub struct Probe<'a> {
    /// The stage.
    pub stage: Stage,
    /// Garment node latents, `n_garment × h`.
    pub garment: &'a [f32],
    /// Active body node latents, `n_active × h`.
    pub body: &'a [f32],
}

/// Scratch owned by one task.
#[derive(Clone, Debug)]
pub struct TaskBufs {
    t1: Vec<f32>,
    t2: Vec<f32>,
    lin: Vec<f32>,
    edge: Vec<f32>,
}

/// How a static edge list is split between tasks: edge boundaries at target changes, and the
/// targets rebased to each task's first target.
#[derive(Clone, Debug, Default)]
struct EdgeSplit {
    bounds: Vec<usize>,
    rebased: Vec<u32>,
}

impl EdgeSplit {
    fn new(e: &EdgeList, tasks: usize) -> EdgeSplit {
        let mut bounds = vec![0; tasks + 1];
        target_bounds(&e.target, tasks, &mut bounds);
        let mut rebased = vec![0; e.target.len()];
        for t in 0..tasks {
            let (a, b) = (bounds[t], bounds[t + 1]);
            if a < b {
                let lo = e.target[a];
                for k in a..b {
                    rebased[k] = e.target[k] - lo;
                }
            }
        }
        EdgeSplit { bounds, rebased }
    }
}

/// Every buffer of the forward pass.
#[derive(Clone, Debug)]
pub struct Workspace {
    h: usize,
    v: usize,
    max_active: usize,
    lin_len: usize,
    /// Node features, garment rows then active body rows (24 wide).
    pub node_features: Vec<f32>,
    latents: Vec<f32>,
    next_latents: Vec<f32>,
    edge_features: Vec<f32>,
    /// Body edge features, garment->body (9 wide).
    pub g2b_features: Vec<f32>,
    /// Body edge features, body->garment (9 wide).
    pub b2g_features: Vec<f32>,
    mesh_latents: Vec<f32>,
    coarse_latents: Vec<Vec<f32>>,
    g2b_latents: Vec<f32>,
    b2g_latents: Vec<f32>,
    slots: Vec<Vec<f32>>,
    proj_t: Vec<f32>,
    proj_s: Vec<f32>,
    proj_edge: Vec<f32>,
    gathered: Vec<f32>,
    local_agg: Vec<f32>,
    g2b_offsets: Vec<u32>,
    g2b_perm: Vec<u32>,
    tasks: Vec<TaskBufs>,
    errors: Vec<Option<Error>>,
    mesh_split: EdgeSplit,
    coarse_split: Vec<EdgeSplit>,
    /// Decoder output (normalised accelerations), `v × 3`.
    pub decoded: Vec<f32>,
    uses_key: [bool; 4],
    /// Useful floating-point operations of the matrix products since the last reset (a
    /// multiply-add counts 2; skipped zero operands count nothing).
    pub flops: u64,
}

fn key_index(k: EdgeKey) -> usize {
    k as usize
}

impl Workspace {
    /// Sizes every buffer for `model` on `graph` with at most `max_active` active body nodes
    /// (0 without a body), for one task; see [`Workspace::set_tasks`].
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] for a model the runtime cannot run on this graph;
    /// [`Error::CapacityExceeded`] when the buffers would need more than
    /// [`crate::limits::MAX_WORKSPACE_BYTES`] (nothing is allocated then).
    pub fn new(model: &Model<'_>, graph: &Graph, max_active: usize) -> Result<Workspace> {
        let spec = model.spec();
        let h = spec.latent;
        if spec.hidden_layers != 2 {
            return Err(Error::IncompatibleModel {
                reason: "the runtime's fused edge kernel needs MLPs with 2 hidden layers",
            });
        }
        let v = graph.n_vertices();
        let rows = v + max_active;
        let mut uses_key = [false; 4];
        for b in &spec.blocks {
            for &k in &b.keys {
                uses_key[key_index(k)] = true;
            }
        }
        for (l, used) in uses_key.iter().take(3).enumerate() {
            if *used && graph.coarse.len() <= l {
                return Err(Error::IncompatibleModel {
                    reason: "the model uses a coarse level the garment graph lacks",
                });
            }
        }
        let has_body = max_active > 0;
        let max_slots = spec.blocks.iter().map(|b| b.keys.len() + usize::from(has_body)).max().unwrap_or(0);
        let e_mesh = if uses_key[key_index(EdgeKey::Mesh)] { graph.mesh.target.len() } else { 0 };
        let coarse_e: Vec<usize> = (0..3)
            .map(|l| if uses_key[l] && l < graph.coarse.len() { graph.coarse[l].edges.target.len() } else { 0 })
            .collect();
        let max_e = coarse_e.iter().copied().max().unwrap_or(0).max(e_mesh);
        let b = if has_body { v } else { 0 };
        let max_in = spec.blocks.iter().map(|b| spec.node_inputs(b) * h).max().unwrap_or(0).max(3 * h).max(NODE_WIDTH);
        // The kernels' own bound for the widest layer (the node MLP's first layer), including room to
        // widen bf16 weights on tiers without bf16 dot products.
        let lin_len = kernels::LINEAR_BLOCK_ROWS * (max_in + 2 * MAX_OPERANDS + kernels::padded_cols(h.max(3)))
            + kernels::padded_cols(h.max(3)) * (max_in + MAX_OPERANDS);
        // The buffers below, in floats, counted before any is allocated (u64, saturating).
        let w = |x: usize| x as u64;
        let per_row = w(NODE_WIDTH).saturating_add(w(2 + max_slots).saturating_mul(w(h)));
        let edges = w(e_mesh).saturating_add(coarse_e.iter().map(|&e| w(e)).sum::<u64>());
        let floats = [
            w(rows).saturating_mul(per_row),
            w(max_e).saturating_mul(w(EDGE_WIDTH)),
            edges.saturating_mul(w(h)),
            w(b).saturating_mul(w(2 * BODY_EDGE_WIDTH + 3 * h)),
            w(v.max(max_active)).saturating_mul(w(2 * h)),
            w(v).saturating_mul(w(2 * h + 3)),
        ]
        .iter()
        .fold(0u64, |a, &x| a.saturating_add(x));
        let bytes = floats.saturating_mul(4);
        if bytes > crate::limits::MAX_WORKSPACE_BYTES {
            return Err(Error::CapacityExceeded {
                what: "sim workspace (bytes, for this model and garment)",
                capacity: usize::try_from(crate::limits::MAX_WORKSPACE_BYTES).unwrap_or(usize::MAX),
                needed: usize::try_from(bytes).unwrap_or(usize::MAX),
            });
        }
        let mut ws = Workspace {
            h,
            v,
            max_active,
            lin_len,
            node_features: vec![0.0; rows * NODE_WIDTH],
            latents: vec![0.0; rows * h],
            next_latents: vec![0.0; rows * h],
            edge_features: vec![0.0; max_e * EDGE_WIDTH],
            g2b_features: vec![0.0; b * BODY_EDGE_WIDTH],
            b2g_features: vec![0.0; b * BODY_EDGE_WIDTH],
            mesh_latents: vec![0.0; e_mesh * h],
            coarse_latents: coarse_e.iter().map(|&e| vec![0.0; e * h]).collect(),
            g2b_latents: vec![0.0; b * h],
            b2g_latents: vec![0.0; b * h],
            slots: (0..max_slots).map(|_| vec![0.0; rows * h]).collect(),
            proj_t: vec![0.0; v.max(max_active) * h],
            proj_s: vec![0.0; v.max(max_active) * h],
            proj_edge: vec![0.0; b * h],
            gathered: vec![0.0; v * h],
            local_agg: vec![0.0; v * h],
            g2b_offsets: vec![0; max_active + 1],
            g2b_perm: vec![0; b],
            tasks: Vec::new(),
            errors: Vec::new(),
            mesh_split: EdgeSplit::default(),
            coarse_split: Vec::new(),
            decoded: vec![0.0; v * 3],
            uses_key,
            flops: 0,
        };
        ws.set_tasks(1, graph);
        Ok(ws)
    }

    /// Sizes per-task scratch and edge splits for `tasks` parallel tasks (allocates).
    pub fn set_tasks(&mut self, tasks: usize, graph: &Graph) {
        let tasks = tasks.clamp(1, 256);
        let h = self.h;
        self.tasks = (0..tasks)
            .map(|_| TaskBufs {
                t1: vec![0.0; CHUNK * h],
                t2: vec![0.0; CHUNK * h],
                lin: vec![0.0; self.lin_len],
                edge: vec![0.0; kernels::edge_mlp_scratch_len(h, h)],
            })
            .collect();
        self.errors = vec![None; tasks];
        self.mesh_split = EdgeSplit::new(&graph.mesh, tasks);
        self.coarse_split = graph.coarse.iter().map(|c| EdgeSplit::new(&c.edges, tasks)).collect();
    }

    /// The mesh/coarse edge feature buffer for `n` edges (features are written by the caller,
    /// then [`Workspace::encode_edges`] normalises and encodes them).
    pub fn edge_feature_rows(&mut self, n: usize) -> &mut [f32] {
        &mut self.edge_features[..n * EDGE_WIDTH]
    }

    /// True when some block passes messages over `key`.
    pub fn uses(&self, key: EdgeKey) -> bool {
        self.uses_key[key_index(key)]
    }

    /// Normalises the first `n` edge feature rows and encodes them into the latents of `key`.
    pub fn encode_edges(&mut self, net: &Net<'_>, exec: &dyn Executor, key: EdgeKey, n: usize) -> Result<()> {
        let (mean, std) = net.model.edge_stats();
        let rows = &mut self.edge_features[..n * EDGE_WIDTH];
        normalise_rows(rows, EDGE_WIDTH, mean, std);
        let enc_i = net
            .model
            .spec()
            .encoder_index(key)
            .ok_or(Error::IncompatibleModel { reason: "the model has no encoder for an edge set it uses" })?;
        let out = match key.coarse_level() {
            Some(l) => &mut self.coarse_latents[l][..n * self.h],
            None => &mut self.mesh_latents[..n * self.h],
        };
        let mut p = Par { exec, tasks: &mut self.tasks, errors: &mut self.errors, flops: &mut self.flops };
        p.mlp(net, &net.model.edge_encoders[enc_i], &[Some(&self.edge_features[..n * EDGE_WIDTH])], n, out, false)
    }

    /// The forward pass after the edge latents are encoded: nodes (features already in
    /// `node_features`, garment then active body rows), body edges (features in
    /// `g2b_features`/`b2g_features`), blocks, decoder into `decoded`.
    pub fn forward(
        &mut self,
        net: &Net<'_>,
        exec: &dyn Executor,
        graph: &Graph,
        body: &BodyEdges<'_>,
        observer: &mut dyn FnMut(Probe<'_>),
    ) -> Result<()> {
        let (h, v) = (self.h, self.v);
        let a = body.n_active;
        if a > self.max_active {
            return Err(Error::CapacityExceeded { what: "active body nodes", capacity: self.max_active, needed: a });
        }
        let rows = v + a;
        let nb = body.prefix[0];
        let model = net.model;
        let mut par = Par { exec, tasks: &mut self.tasks, errors: &mut self.errors, flops: &mut self.flops };
        // Nodes: normalise the first 21 columns, encode.
        let (mean, std) = model.node_stats();
        let feats = &mut self.node_features[..rows * NODE_WIDTH];
        normalise_rows(feats, NODE_WIDTH, &mean[..NODE_NORMALISED], &std[..NODE_NORMALISED]);
        par.mlp(
            net,
            &model.node_encoder,
            &[Some(&self.node_features[..rows * NODE_WIDTH])],
            rows,
            &mut self.latents[..rows * h],
            false,
        )?;
        // Body edges: both directions, one normaliser, one encoder.
        if nb > 0 {
            let enc = model.body_encoder.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
            let (mean, std) = model.body_edge_stats();
            for (f, lat) in
                [(&mut self.g2b_features, &mut self.g2b_latents), (&mut self.b2g_features, &mut self.b2g_latents)]
            {
                normalise_rows(&mut f[..nb * BODY_EDGE_WIDTH], BODY_EDGE_WIDTH, mean, std);
                par.mlp(net, enc, &[Some(&f[..nb * BODY_EDGE_WIDTH])], nb, &mut lat[..nb * h], false)?;
            }
        }
        observer(Probe {
            stage: Stage::Encoded,
            garment: &self.latents[..v * h],
            body: &self.latents[v * h..rows * h],
        });

        for (bi, (bspec, bview)) in model.spec().blocks.iter().zip(&model.blocks).enumerate() {
            let n_slots = bspec.keys.len() + usize::from(nb > 0);
            for s in &mut self.slots[..n_slots] {
                par.fill(&mut s[..rows * h]);
            }
            for (ki, (&key, mlp)) in bspec.keys.iter().zip(&bview.edges).enumerate() {
                let slot = &mut self.slots[ki][..rows * h];
                match key.coarse_level() {
                    None => {
                        let e = &graph.mesh;
                        let x = &self.latents[..v * h];
                        par.edge_mlp(
                            net,
                            mlp,
                            (x, x),
                            Edges::Split { list: e, split: &self.mesh_split },
                            &mut self.mesh_latents[..e.target.len() * h],
                            &mut slot[..v * h],
                            (&mut self.proj_t, &mut self.proj_s, &mut self.proj_edge),
                        )?;
                    }
                    Some(l) => {
                        let level = &graph.coarse[l];
                        let nl = level.nodes.len();
                        gather(&self.latents, &level.nodes, h, &mut self.gathered[..nl * h]);
                        let local = &mut self.local_agg[..nl * h];
                        local.fill(0.0);
                        let x = &self.gathered[..nl * h];
                        par.edge_mlp(
                            net,
                            mlp,
                            (x, x),
                            Edges::Split { list: &level.edges, split: &self.coarse_split[l] },
                            &mut self.coarse_latents[l][..level.edges.target.len() * h],
                            local,
                            (&mut self.proj_t, &mut self.proj_s, &mut self.proj_edge),
                        )?;
                        scatter(&self.local_agg[..nl * h], &level.nodes, h, slot);
                    }
                }
            }
            if nb > 0 {
                let mlp = bview.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let depth = bspec.finest().coarse_level().map_or(0, |l| l + 1);
                let n = body.prefix[depth];
                let slot = &mut self.slots[bspec.keys.len()][..rows * h];
                if n > 0 {
                    gather(&self.latents, &body.garment[..n], h, &mut self.gathered[..n * h]);
                    let xg = &self.gathered[..n * h];
                    let xb = &self.latents[v * h..rows * h];
                    // body -> garment: each garment end has one body edge, so the per-edge
                    // messages are its aggregate: compute them in edge order, then scatter.
                    let msgs = &mut self.local_agg[..n * h];
                    msgs.fill(0.0);
                    par.edge_mlp(
                        net,
                        mlp,
                        (xg, xb),
                        Edges::PerEdge { source: &body.body[..n], iota: graph.iota(), target_rows: None },
                        &mut self.b2g_latents[..n * h],
                        msgs,
                        (&mut self.proj_t, &mut self.proj_s, &mut self.proj_edge),
                    )?;
                    scatter(&self.local_agg[..n * h], &body.garment[..n], h, slot);
                    // garment -> body: per-edge messages, then a sum per active body node in
                    // edge order (independent of the task split).
                    let msgs = &mut self.local_agg[..n * h];
                    msgs.fill(0.0);
                    par.edge_mlp(
                        net,
                        mlp,
                        (xb, xg),
                        Edges::PerEdge {
                            source: &graph.iota()[..n],
                            iota: graph.iota(),
                            target_rows: Some(&body.body[..n]),
                        },
                        &mut self.g2b_latents[..n * h],
                        msgs,
                        (&mut self.proj_t, &mut self.proj_s, &mut self.proj_edge),
                    )?;
                    let offsets = &mut self.g2b_offsets[..a + 1];
                    let perm = &mut self.g2b_perm[..n];
                    counting_sort(&body.body[..n], offsets, perm);
                    par.reduce_rows(&self.local_agg[..n * h], offsets, perm, h, &mut slot[v * h..rows * h]);
                }
            }
            // Node update from the latents at the start of the block.
            par.copy(&mut self.next_latents[..rows * h], &self.latents[..rows * h]);
            let mut inputs: [Option<&[f32]>; MAX_OPERANDS] = [None; MAX_OPERANDS];
            inputs[0] = Some(&self.latents[..rows * h]);
            for s in 0..n_slots {
                inputs[1 + s] = Some(&self.slots[s][..rows * h]);
            }
            // A model trained with a body but run without one: the body slot is zero and skipped.
            let n_inputs = model.spec().node_inputs(bspec);
            par.mlp(net, &bview.node, &inputs[..n_inputs], rows, &mut self.next_latents[..rows * h], true)?;
            core::mem::swap(&mut self.latents, &mut self.next_latents);
            observer(Probe {
                stage: Stage::Block(bi),
                garment: &self.latents[..v * h],
                body: &self.latents[v * h..rows * h],
            });
        }
        par.mlp(net, &model.decoder, &[Some(&self.latents[..v * h])], v, &mut self.decoded, false)?;
        observer(Probe { stage: Stage::Decoded, garment: &self.decoded, body: &[] });
        Ok(())
    }
}

/// Copies rows `idx` of `src` (`h` wide) into consecutive rows of `dst`.
fn gather(src: &[f32], idx: &[u32], h: usize, dst: &mut [f32]) {
    for (d, &g) in dst.chunks_exact_mut(h).zip(idx) {
        let g = g as usize;
        d.copy_from_slice(&src[g * h..(g + 1) * h]);
    }
}

/// Copies consecutive rows of `src` into rows `idx` of `dst`.
fn scatter(src: &[f32], idx: &[u32], h: usize, dst: &mut [f32]) {
    for (s, &g) in src.chunks_exact(h).zip(idx) {
        let g = g as usize;
        dst[g * h..(g + 1) * h].copy_from_slice(s);
    }
}

/// CSR of `keys` (values below `offsets.len() - 1`): `perm[offsets[k]..offsets[k+1]]` are the
/// positions holding `k`, ascending.
fn counting_sort(keys: &[u32], offsets: &mut [u32], perm: &mut [u32]) {
    offsets.fill(0);
    for &k in keys {
        offsets[k as usize + 1] += 1;
    }
    for i in 1..offsets.len() {
        offsets[i] += offsets[i - 1];
    }
    // Fill using the starts, then shift back.
    for (e, &k) in keys.iter().enumerate() {
        let slot = &mut offsets[k as usize];
        perm[*slot as usize] = e as u32;
        *slot += 1;
    }
    for i in (1..offsets.len()).rev() {
        offsets[i] = offsets[i - 1];
    }
    offsets[0] = 0;
}

/// The edges of one edge-MLP call.
#[derive(Clone, Copy)]
enum Edges<'a> {
    /// A static list sorted by target, split at target changes.
    Split { list: &'a EdgeList, split: &'a EdgeSplit },
    /// One message row per edge (target `e` is edge `e`), any split; `iota` is `0, 1, 2, ...`.
    /// With `target_rows`, the target-side rows `x.0` are per node and edge `e` reads row
    /// `target_rows[e]` (its projection is gathered per edge first).
    PerEdge { source: &'a [u32], iota: &'a [u32], target_rows: Option<&'a [u32]> },
}

/// The executor with per-task scratch.
struct Par<'w> {
    exec: &'w dyn Executor,
    tasks: &'w mut [TaskBufs],
    errors: &'w mut [Option<Error>],
    flops: &'w mut u64,
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

    /// Zeroes `buf`, split between tasks (megabytes per block at h = 128: serially it would
    /// hold back the second thread).
    fn fill(&mut self, buf: &mut [f32]) {
        let len = buf.len();
        let n = self.tasks.len().min(len.div_ceil(PAR_FLOATS)).max(1);
        let buf = Disjoint::new(buf);
        let _ = self.run(n, &|t, _| {
            // SAFETY: ranges of different tasks are disjoint.
            unsafe { buf.range(split(len, n, t)) }.fill(0.0);
            Ok(())
        });
    }

    /// `dst.copy_from_slice(src)` (same lengths), split between tasks.
    fn copy(&mut self, dst: &mut [f32], src: &[f32]) {
        let len = dst.len().min(src.len());
        let n = self.tasks.len().min(len.div_ceil(PAR_FLOATS)).max(1);
        let dst = Disjoint::new(dst);
        let _ = self.run(n, &|t, _| {
            let r = split(len, n, t);
            // SAFETY: ranges of different tasks are disjoint.
            unsafe { dst.range(r.clone()) }.copy_from_slice(&src[r]);
            Ok(())
        });
    }

    /// `mlp` over `rows` rows, split into row ranges per task (see [`Net::mlp_rows`]).
    fn mlp(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        inputs: &[Option<&[f32]>],
        rows: usize,
        out: &mut [f32],
        residual: bool,
    ) -> Result<()> {
        if rows == 0 {
            return Ok(());
        }
        let w = out.len() / rows;
        let first: usize = mlp.layers[0]
            .parts(net.bf16)
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
            net.mlp_rows(mlp, inputs, r, o, residual, tb)
        })
    }

    /// One edge set through an edge MLP: both node projections (row-split), then the fused
    /// kernel (edge-split so that no target's sum spans two tasks).
    #[allow(clippy::too_many_arguments)]
    fn edge_mlp(
        &mut self,
        net: &Net<'_>,
        mlp: &MlpView<'_>,
        x: (&[f32], &[f32]),
        edges: Edges<'_>,
        latent: &mut [f32],
        aggregate: &mut [f32],
        proj: (&mut [f32], &mut [f32], &mut [f32]),
    ) -> Result<()> {
        let l = &mlp.layers;
        let p1 = l[0].parts(net.bf16);
        let h = l[0].out;
        let (nt, ns) = (x.0.len() / h, x.1.len() / h);
        let (pt, ps) = (&mut proj.0[..nt * h], &mut proj.1[..ns * h]);
        self.linear(net, x.0, p1[0], pt)?;
        self.linear(net, x.1, p1[1], ps)?;
        let pt: &[f32] = match edges {
            Edges::PerEdge { target_rows: Some(rows), .. } => {
                let per_edge = &mut proj.2[..rows.len() * h];
                gather(pt, rows, h, per_edge);
                per_edge
            }
            _ => pt,
        };
        let ps = &*ps;
        let em = EdgeMlp {
            w1_edge: p1[2],
            b1: l[0].bias,
            w2: l[1].parts(net.bf16)[0],
            b2: l[1].bias,
            w3: l[2].parts(net.bf16)[0],
            b3: l[2].bias,
            layer_norm: mlp.layer_norm,
        };
        let k_e = em.w3.n();
        let n_edges = latent.len() / k_e;
        *self.flops += 2 * (n_edges * (em.w1_edge.k() * h + em.w2.k() * em.w2.n() + em.w3.k() * k_e)) as u64;
        let latent = Disjoint::new(latent);
        let aggregate = Disjoint::new(aggregate);
        let tasks = self.tasks.len().min(n_edges.div_ceil(64)).max(1);
        match edges {
            Edges::Split { list, split } => {
                let n = split.bounds.len() - 1;
                self.run(n, &|t, tb| {
                    let (a, b) = (split.bounds[t], split.bounds[t + 1]);
                    if a == b {
                        return Ok(());
                    }
                    let (lo, hi) = (list.target[a] as usize, list.target[b - 1] as usize + 1);
                    let inputs = EdgeInputs {
                        p_target: &pt[lo * h..hi * h],
                        p_source: ps,
                        target: &split.rebased[a..b],
                        source: &list.source[a..b],
                    };
                    // SAFETY: edge ranges are disjoint, and so are their target ranges (the split
                    // never cuts a target's edges).
                    let (lat, agg) = unsafe { (latent.range(a * k_e..b * k_e), aggregate.range(lo * k_e..hi * k_e)) };
                    net.kernels.edge_mlp(&em, &inputs, lat, agg, &mut tb.edge)
                })
            }
            Edges::PerEdge { source, iota, .. } => self.run(tasks, &|t, tb| {
                let r = split(n_edges, tasks, t);
                if r.is_empty() {
                    return Ok(());
                }
                let inputs = EdgeInputs {
                    p_target: &pt[r.start * h..r.end * h],
                    p_source: ps,
                    target: &iota[..r.len()],
                    source: &source[r.clone()],
                };
                // SAFETY: edge ranges (and so their message rows) are disjoint between tasks.
                let (lat, agg) =
                    unsafe { (latent.range(r.start * k_e..r.end * k_e), aggregate.range(r.start * k_e..r.end * k_e)) };
                net.kernels.edge_mlp(&em, &inputs, lat, agg, &mut tb.edge)
            }),
        }
    }

    /// `out = x · Wᵀ` (no bias), row-split.
    fn linear(&mut self, net: &Net<'_>, x: &[f32], w: kernels::Weights<'_>, out: &mut [f32]) -> Result<()> {
        let (k, n_out) = (w.k(), w.n());
        let rows = x.len() / k.max(1);
        *self.flops += 2 * (rows * k * n_out) as u64;
        let n = self.tasks.len().min(rows.div_ceil(64)).max(1);
        let out = Disjoint::new(out);
        self.run(n, &|t, tb| {
            let r = split(rows, n, t);
            // SAFETY: row ranges of different tasks are disjoint.
            let o = unsafe { out.range(r.start * n_out..r.end * n_out) };
            let op = [Operand { x: &x[r.start * k..r.end * k], w }];
            net.kernels.linear(&op, None, &Epilogue::default(), o, &mut tb.lin)
        })
    }

    /// `out[r] = Σ src[perm[k]]` for `k` in `offsets[r]..offsets[r+1]`, row-split.
    fn reduce_rows(&mut self, src: &[f32], offsets: &[u32], perm: &[u32], h: usize, out: &mut [f32]) {
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

/// A model bound to a kernel path and a precision.
#[derive(Clone, Copy, Debug)]
pub struct Net<'m> {
    /// The model.
    pub model: &'m Model<'m>,
    /// The kernel path.
    pub kernels: Kernels,
    /// Run the bf16 weights.
    pub bf16: bool,
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
        let parts = layers[0].parts(self.bf16);
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
            for (x, w) in inputs.iter().zip(parts) {
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
                    let op = [Operand { x: &a[..r * l.inp], w: l.parts(self.bf16)[0] }];
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
