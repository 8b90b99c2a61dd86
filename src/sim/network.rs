//! The network's forward pass over a step's buffers: encode, process (blocks), decode. Every
//! buffer is sized once by [`Workspace::new`]; [`Workspace::forward`] allocates nothing.

use super::graph::{EdgeList, Graph};
use crate::error::{Error, Result};
use crate::exec::par::target_bounds;
use crate::features::{BODY_EDGE_WIDTH, EDGE_WIDTH, NODE_WIDTH};
use crate::kernels::{self, Kernels, MAX_OPERANDS};
use crate::model::file::{LinearView, Model};
use crate::model::spec::EdgeKey;
use alloc::vec;
use alloc::vec::Vec;

/// Rows per chunk when an MLP runs over many rows (bounds the hidden-layer temporaries).
const CHUNK: usize = 256;

mod forward;
mod tasks;
mod widened;

pub use widened::WidenedBf16;

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
    /// The garment -> body direction's node projections (target: body rows, source: garment
    /// rows), beside `proj_t` and `proj_s`, which hold the body -> garment direction's: all four
    /// are computed in one job.
    g2b_proj_t: Vec<f32>,
    g2b_proj_s: Vec<f32>,
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
            g2b_proj_t: vec![0.0; max_active * h],
            g2b_proj_s: vec![0.0; b * h],
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
    /// The bf16 weights widened to f32 once (on kernel paths without bf16 products): used
    /// instead of the model's when present.
    pub widened: Option<&'m WidenedBf16>,
}

impl<'m> Net<'m> {
    /// This net as the encoders run it: f32 weights and arithmetic at every precision.
    ///
    /// The encoders' outputs start the residual streams of the node and edge latents, which
    /// carry them through every block, so their rounding would reach every later layer; they
    /// hold about a twentieth of a step's products. On the stability suite's looped turn, bf16
    /// blocks with f32 encoders stay about half as far from the f32 rollout (RMS over the
    /// vertices) as a net wholly in bf16.
    pub fn encoders(&self) -> Net<'m> {
        Net { bf16: false, widened: None, ..*self }
    }

    /// The weight parts of `layer` this net runs: the widened bf16 ones, else the model's in
    /// the requested precision.
    ///
    /// # Errors
    /// As [`WidenedBf16::parts`]; [`Error::IncompatibleModel`] for a layer of more parts than
    /// a kernel call sums.
    pub fn parts<'a>(&self, layer: &LinearView<'a>) -> Result<LayerParts<'a>>
    where
        'm: 'a,
    {
        match self.widened {
            Some(w) => w.parts(layer.index),
            None => LayerParts::collect(layer.parts(self.bf16).iter().map(|p| Ok(*p))),
        }
    }
}

/// The weight parts of one layer (at most [`MAX_OPERANDS`]), by value; a slice through `Deref`.
#[derive(Clone, Copy, Debug)]
pub struct LayerParts<'a> {
    /// Unused slots repeat the first part.
    parts: [kernels::Weights<'a>; MAX_OPERANDS],
    len: usize,
}

impl<'a> LayerParts<'a> {
    fn collect(mut parts: impl Iterator<Item = Result<kernels::Weights<'a>>>) -> Result<Self> {
        let first = parts.next().ok_or(Error::IncompatibleModel { reason: "a layer without weights" })??;
        let mut out = LayerParts { parts: [first; MAX_OPERANDS], len: 1 };
        for w in parts {
            let slot = out
                .parts
                .get_mut(out.len)
                .ok_or(Error::IncompatibleModel { reason: "a layer has more parts than a kernel call sums" })?;
            *slot = w?;
            out.len += 1;
        }
        Ok(out)
    }
}

impl<'a> core::ops::Deref for LayerParts<'a> {
    type Target = [kernels::Weights<'a>];
    fn deref(&self) -> &Self::Target {
        &self.parts[..self.len]
    }
}
