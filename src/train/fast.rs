//! The trainer's fast f32 path: the same forward and backward as [`Network::forward`] /
//! [`Network::backward`] (same data path, same tape contents), on SIMD products
//! ([`super::gemm`]), split between threads by an [`Executor`], with every buffer kept in a
//! reusable [`FastWorkspace`] (grow-only: a steady-state step allocates nothing).
//!
//! Determinism: every parallel loop is cut into [`PARTS`] fixed row (or column) ranges whatever
//! the thread count; row-local results do not depend on the cut, and sums over rows (weight and
//! bias gradients) go to one partial gradient per range, added in range order at the end. One
//! thread and two threads give bitwise the same gradients.
//!
//! [`Network::forward`]: super::network::Network::forward
//! [`Network::backward`]: super::network::Network::backward

use super::gemm::Gemm;
use super::layout::MlpAt;
use crate::exec::par::Disjoint;
use crate::exec::Executor;
use alloc::vec::Vec;

mod backward;
mod forward;
mod layers;
mod parallel;

/// Fixed ranges every parallel loop is cut into (independent of the thread count).
pub const PARTS: usize = 4;

/// Most column parts of an MLP's first layer (node latents, up to four slots... and the body).
const MAX_INPUTS: usize = 8;

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
///
/// [`Network::forward_fast`]: super::network::Network::forward_fast
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
    grad: Option<&'a Disjoint<'a, f32>>,
}
