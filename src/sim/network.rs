//! The network's forward pass over a step's buffers: encode, process (blocks), decode. Every
//! buffer is sized once by [`Workspace::new`]; [`Workspace::forward`] allocates nothing.

use super::graph::Graph;
use crate::error::{Error, Result};
use crate::features::{BODY_EDGE_WIDTH, EDGE_WIDTH, NODE_NORMALISED, NODE_WIDTH};
use crate::kernels::{self, EdgeInputs, EdgeMlp, Epilogue, Kernels, Operand, MAX_OPERANDS};
use crate::model::file::{MlpView, Model};
use crate::model::spec::EdgeKey;
use crate::normaliser::normalise_rows;
use alloc::vec;
use alloc::vec::Vec;

/// Rows per chunk when an MLP runs over many rows (bounds the hidden-layer temporaries).
const CHUNK: usize = 256;

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

/// Every buffer of the forward pass.
#[derive(Clone, Debug)]
pub struct Workspace {
    h: usize,
    v: usize,
    max_active: usize,
    /// Node features, garment rows then active body rows (24 wide).
    pub node_features: Vec<f32>,
    latents: Vec<f32>,
    next_latents: Vec<f32>,
    edge_features: Vec<f32>,
    /// Body edge features, garment->body then body->garment (9 wide each).
    pub g2b_features: Vec<f32>,
    /// See `g2b_features`.
    pub b2g_features: Vec<f32>,
    mesh_latents: Vec<f32>,
    coarse_latents: Vec<Vec<f32>>,
    g2b_latents: Vec<f32>,
    b2g_latents: Vec<f32>,
    slots: Vec<Vec<f32>>,
    proj_t: Vec<f32>,
    proj_s: Vec<f32>,
    gathered: Vec<f32>,
    local_agg: Vec<f32>,
    t1: Vec<f32>,
    t2: Vec<f32>,
    lin_scratch: Vec<f32>,
    edge_scratch: Vec<f32>,
    /// Decoder output (normalised accelerations), `v × 3`.
    pub decoded: Vec<f32>,
    uses_key: [bool; 4],
}

fn key_index(k: EdgeKey) -> usize {
    k as usize
}

impl Workspace {
    /// Sizes every buffer for `model` on `graph` with at most `max_active` active body nodes
    /// (0 without a body).
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
        let lin_scratch = kernels::LINEAR_BLOCK_ROWS * (max_in + 2 * MAX_OPERANDS + kernels::padded_cols(h.max(3)));
        Ok(Workspace {
            h,
            v,
            max_active,
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
            gathered: vec![0.0; v * h],
            local_agg: vec![0.0; v * h],
            t1: vec![0.0; CHUNK * h],
            t2: vec![0.0; CHUNK * h],
            lin_scratch: vec![0.0; lin_scratch],
            edge_scratch: vec![0.0; kernels::edge_mlp_scratch_len(h, h)],
            decoded: vec![0.0; v * 3],
            uses_key,
        })
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
    pub fn encode_edges(&mut self, net: &Net<'_>, key: EdgeKey, n: usize) -> Result<()> {
        let (mean, std) = net.model.edge_stats();
        let rows = &mut self.edge_features[..n * EDGE_WIDTH];
        normalise_rows(rows, EDGE_WIDTH, mean, std);
        let enc_i = net
            .model
            .spec()
            .encoded_keys()
            .iter()
            .position(|&k| k == key)
            .ok_or(Error::IncompatibleModel { reason: "the model has no encoder for an edge set it uses" })?;
        let out = match key.coarse_level() {
            Some(l) => &mut self.coarse_latents[l][..n * self.h],
            None => &mut self.mesh_latents[..n * self.h],
        };
        net.mlp(
            &net.model.edge_encoders[enc_i],
            &[Some(&self.edge_features[..n * EDGE_WIDTH])],
            n,
            out,
            false,
            (&mut self.t1, &mut self.t2),
            &mut self.lin_scratch,
        )
    }

    /// The forward pass after the edge latents are encoded: nodes (features already in
    /// `node_features`, garment then active body rows), body edges (features in
    /// `g2b_features`/`b2g_features`), blocks, decoder into `decoded`.
    pub fn forward(
        &mut self,
        net: &Net<'_>,
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
        // Nodes: normalise the first 21 columns, encode.
        let (mean, std) = model.node_stats();
        let feats = &mut self.node_features[..rows * NODE_WIDTH];
        normalise_rows(feats, NODE_WIDTH, &mean[..NODE_NORMALISED], &std[..NODE_NORMALISED]);
        net.mlp(
            &model.node_encoder,
            &[Some(&self.node_features[..rows * NODE_WIDTH])],
            rows,
            &mut self.latents[..rows * h],
            false,
            (&mut self.t1, &mut self.t2),
            &mut self.lin_scratch,
        )?;
        // Body edges: both directions, one normaliser, one encoder.
        if nb > 0 {
            let enc = model.body_encoder.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
            let (mean, std) = model.body_edge_stats();
            for (f, lat) in
                [(&mut self.g2b_features, &mut self.g2b_latents), (&mut self.b2g_features, &mut self.b2g_latents)]
            {
                normalise_rows(&mut f[..nb * BODY_EDGE_WIDTH], BODY_EDGE_WIDTH, mean, std);
                net.mlp(
                    enc,
                    &[Some(&f[..nb * BODY_EDGE_WIDTH])],
                    nb,
                    &mut lat[..nb * h],
                    false,
                    (&mut self.t1, &mut self.t2),
                    &mut self.lin_scratch,
                )?;
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
                s[..rows * h].fill(0.0);
            }
            for (ki, (&key, mlp)) in bspec.keys.iter().zip(&bview.edges).enumerate() {
                let slot = &mut self.slots[ki][..rows * h];
                match key.coarse_level() {
                    None => {
                        let e = &graph.mesh;
                        let x = &self.latents[..v * h];
                        net.edge_mlp(
                            mlp,
                            (x, x),
                            (&e.target, &e.source),
                            &mut self.mesh_latents[..e.target.len() * h],
                            &mut slot[..v * h],
                            (&mut self.proj_t, &mut self.proj_s),
                            (&mut self.lin_scratch, &mut self.edge_scratch),
                        )?;
                    }
                    Some(l) => {
                        let level = &graph.coarse[l];
                        let nl = level.nodes.len();
                        for (r, &g) in level.nodes.iter().enumerate() {
                            let g = g as usize;
                            self.gathered[r * h..(r + 1) * h].copy_from_slice(&self.latents[g * h..(g + 1) * h]);
                        }
                        let local = &mut self.local_agg[..nl * h];
                        local.fill(0.0);
                        let x = &self.gathered[..nl * h];
                        net.edge_mlp(
                            mlp,
                            (x, x),
                            (&level.edges.target, &level.edges.source),
                            &mut self.coarse_latents[l][..level.edges.target.len() * h],
                            local,
                            (&mut self.proj_t, &mut self.proj_s),
                            (&mut self.lin_scratch, &mut self.edge_scratch),
                        )?;
                        for (r, &g) in level.nodes.iter().enumerate() {
                            let g = g as usize;
                            slot[g * h..(g + 1) * h].copy_from_slice(&self.local_agg[r * h..(r + 1) * h]);
                        }
                    }
                }
            }
            if nb > 0 {
                let mlp = bview.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let depth = bspec.finest().coarse_level().map_or(0, |l| l + 1);
                let n = body.prefix[depth];
                let slot = &mut self.slots[bspec.keys.len()][..rows * h];
                if n > 0 {
                    for (r, &g) in body.garment[..n].iter().enumerate() {
                        let g = g as usize;
                        self.gathered[r * h..(r + 1) * h].copy_from_slice(&self.latents[g * h..(g + 1) * h]);
                    }
                    let xg = &self.gathered[..n * h];
                    let xb = &self.latents[v * h..rows * h];
                    // body -> garment: targets are the gathered garment rows 0..n.
                    let local = &mut self.local_agg[..n * h];
                    local.fill(0.0);
                    net.edge_mlp(
                        mlp,
                        (xg, xb),
                        (&graph.iota()[..n], &body.body[..n]),
                        &mut self.b2g_latents[..n * h],
                        local,
                        (&mut self.proj_t, &mut self.proj_s),
                        (&mut self.lin_scratch, &mut self.edge_scratch),
                    )?;
                    for (r, &g) in body.garment[..n].iter().enumerate() {
                        let g = g as usize;
                        slot[g * h..(g + 1) * h].copy_from_slice(&self.local_agg[r * h..(r + 1) * h]);
                    }
                    // garment -> body: targets are the active body rows.
                    net.edge_mlp(
                        mlp,
                        (xb, xg),
                        (&body.body[..n], &graph.iota()[..n]),
                        &mut self.g2b_latents[..n * h],
                        &mut slot[v * h..rows * h],
                        (&mut self.proj_t, &mut self.proj_s),
                        (&mut self.lin_scratch, &mut self.edge_scratch),
                    )?;
                }
            }
            // Node update from the latents at the start of the block.
            self.next_latents[..rows * h].copy_from_slice(&self.latents[..rows * h]);
            let mut inputs: [Option<&[f32]>; MAX_OPERANDS] = [None; MAX_OPERANDS];
            inputs[0] = Some(&self.latents[..rows * h]);
            for s in 0..n_slots {
                inputs[1 + s] = Some(&self.slots[s][..rows * h]);
            }
            // A model trained with a body but run without one: the body slot is zero and skipped.
            let n_inputs = model.spec().node_inputs(bspec);
            net.mlp(
                &bview.node,
                &inputs[..n_inputs],
                rows,
                &mut self.next_latents[..rows * h],
                true,
                (&mut self.t1, &mut self.t2),
                &mut self.lin_scratch,
            )?;
            core::mem::swap(&mut self.latents, &mut self.next_latents);
            observer(Probe {
                stage: Stage::Block(bi),
                garment: &self.latents[..v * h],
                body: &self.latents[v * h..rows * h],
            });
        }
        net.mlp(
            &model.decoder,
            &[Some(&self.latents[..v * h])],
            v,
            &mut self.decoded,
            false,
            (&mut self.t1, &mut self.t2),
            &mut self.lin_scratch,
        )?;
        observer(Probe { stage: Stage::Decoded, garment: &self.decoded, body: &[] });
        Ok(())
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
    /// Runs `mlp` over `rows` rows. `inputs` are the column parts of its input (the parts of the
    /// first layer, in order; `None` is a part known to be zero and skipped); `out` is
    /// `rows × out` and is added to when `residual`.
    #[allow(clippy::too_many_arguments)]
    fn mlp(
        &self,
        mlp: &MlpView<'_>,
        inputs: &[Option<&[f32]>],
        rows: usize,
        out: &mut [f32],
        residual: bool,
        tmp: (&mut [f32], &mut [f32]),
        scratch: &mut [f32],
    ) -> Result<()> {
        let layers = &mlp.layers;
        let first = &layers[0];
        let parts = first.parts(self.bf16);
        if parts.len() != inputs.len() {
            return Err(Error::IncompatibleModel { reason: "MLP input parts disagree with the model" });
        }
        let n_out = layers[layers.len() - 1].out;
        let (mut a, mut b) = tmp;
        for start in (0..rows).step_by(CHUNK) {
            let end = (start + CHUNK).min(rows);
            let r = end - start;
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
                    let dst: &mut [f32] = if last { &mut out[start * n_out..end * n_out] } else { &mut a[..r * l.out] };
                    self.kernels.linear(&ops[..n_ops], Some(l.bias), &ep, dst, scratch)?;
                } else {
                    let x = &a[..r * l.inp];
                    let op = [Operand { x, w: l.parts(self.bf16)[0] }];
                    let dst: &mut [f32] = if last { &mut out[start * n_out..end * n_out] } else { &mut b[..r * l.out] };
                    self.kernels.linear(&op, Some(l.bias), &ep, dst, scratch)?;
                    core::mem::swap(&mut a, &mut b);
                }
            }
        }
        Ok(())
    }

    /// One edge set through a block's edge MLP: node projections of the targets' rows `x.0` and
    /// the sources' rows `x.1`, then the fused kernel (`latent += m`, `aggregate[t] += m`).
    #[allow(clippy::too_many_arguments)]
    fn edge_mlp(
        &self,
        mlp: &MlpView<'_>,
        x: (&[f32], &[f32]),
        idx: (&[u32], &[u32]),
        latent: &mut [f32],
        aggregate: &mut [f32],
        proj: (&mut [f32], &mut [f32]),
        scratch: (&mut [f32], &mut [f32]),
    ) -> Result<()> {
        let l = &mlp.layers;
        let p1 = l[0].parts(self.bf16);
        let h = l[0].out;
        let (pt, ps) = proj;
        let no = Epilogue::default();
        let (nt, ns) = (x.0.len() / h, x.1.len() / h);
        self.kernels.linear(&[Operand { x: x.0, w: p1[0] }], None, &no, &mut pt[..nt * h], scratch.0)?;
        self.kernels.linear(&[Operand { x: x.1, w: p1[1] }], None, &no, &mut ps[..ns * h], scratch.0)?;
        let em = EdgeMlp {
            w1_edge: p1[2],
            b1: l[0].bias,
            w2: l[1].parts(self.bf16)[0],
            b2: l[1].bias,
            w3: l[2].parts(self.bf16)[0],
            b3: l[2].bias,
            layer_norm: mlp.layer_norm,
        };
        let inputs = EdgeInputs { p_target: &pt[..nt * h], p_source: &ps[..ns * h], target: idx.0, source: idx.1 };
        self.kernels.edge_mlp(&em, &inputs, latent, aggregate, scratch.1)
    }
}
