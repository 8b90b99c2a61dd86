//! The network's inputs of one pass (MODEL.md sections 1-3), assembled in one place for the
//! runtime's prediction (`sim/predict.rs`) and the trainer (`train/inputs.rs`): which garment
//! vertices link to which body vertices and in what order ([`BodyLinks`]), which body vertices
//! become active body nodes, and the feature rows of the nodes and edges ([`node_features`],
//! [`Graph::edge_sets`]). The runtime works in the speed limit's frame of reference and writes
//! embedded, un-normalised rows; the trainer passes zero embedding tables and the world frame.

use super::graph::Graph;
use super::network::BodyEdges;
use crate::body::{BodyMesh, Nearest, PointGrid};
use crate::error::{Error, Result};
use crate::exec::Executor;
use crate::features::{self, BodyNodes, Embeddings, GarmentNodes, BODY_EDGE_WIDTH, NODE_WIDTH};
use alloc::vec;
use alloc::vec::Vec;

/// Body-edge radius (MODEL.md section 1), metres.
pub const BODY_EDGE_RADIUS: f32 = 0.03;

/// How many body edges and active body nodes a step has.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct BodyEdgeCounts {
    /// How many leading edges stay at each level of descending depth: `[all, c0, c1, c2]`
    /// (`prefix[0]` is the number of edges).
    pub prefix: [usize; 4],
    /// Active body nodes.
    pub n_active: usize,
}

/// A step's body edges and active body nodes, with the buffers that find them, sized once for a
/// garment of `n` vertices on a body of `nb` vertices (no allocation per step). Each garment
/// vertex within [`BODY_EDGE_RADIUS`] of a body vertex that is not omitted links to the nearest
/// one; the edges are listed in the graph's body order (by descending level, so each coarse
/// level's edges are a prefix), the body vertices they reach become the active body nodes,
/// ascending, and each edge's body end is its row among them.
#[derive(Clone, Debug)]
pub(crate) struct BodyLinks {
    nearest: Vec<Option<Nearest>>,
    /// Last step's nearest body vertex of every garment vertex (`u32::MAX`: none yet): the
    /// search starts from it, which only changes its speed.
    hints: Vec<u32>,
    /// Each body vertex's row among the active body nodes (`u32::MAX` between steps).
    active_of: Vec<u32>,
    /// The active body nodes, ascending (the first `counts.n_active`).
    active: Vec<u32>,
    /// Garment vertex of each edge (the first `counts.prefix[0]`).
    garment: Vec<u32>,
    /// Active row of each edge's body vertex.
    active_row: Vec<u32>,
    /// `[garment vertex, body vertex]` of each edge.
    pairs: Vec<[u32; 2]>,
    counts: BodyEdgeCounts,
}

impl BodyLinks {
    /// Buffers for `n` garment vertices on a body of `nb` vertices.
    pub(crate) fn new(n: usize, nb: usize) -> BodyLinks {
        BodyLinks {
            nearest: vec![None; n],
            hints: vec![u32::MAX; n],
            active_of: vec![u32::MAX; nb],
            active: vec![0; nb.min(n)],
            garment: vec![0; n],
            active_row: vec![0; n],
            pairs: vec![[0; 2]; n],
            counts: BodyEdgeCounts::default(),
        }
    }

    /// Whether these buffers are sized for `n` garment vertices on `nb` body vertices (a
    /// trainer's builder meets garments and bodies of several sizes).
    #[cfg(feature = "train")]
    pub(crate) fn fits(&self, n: usize, nb: usize) -> bool {
        self.nearest.len() == n && self.active_of.len() == nb
    }

    /// Most active body nodes of a step.
    pub(crate) fn max_active(&self) -> usize {
        self.active.len()
    }

    /// Links the garment at `pos` (m, one per garment vertex) to the body `mesh` whose current
    /// vertices `grid` holds (searched on `exec`).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `pos` or `grid` do not match the sizes of [`new`](Self::new);
    /// errors of the search (non-finite positions).
    pub(crate) fn link(
        &mut self,
        grid: &PointGrid,
        exec: &dyn Executor,
        graph: &Graph,
        mesh: &BodyMesh,
        pos: &[[f32; 3]],
    ) -> Result<BodyEdgeCounts> {
        let (n, nb) = (self.nearest.len(), self.active_of.len());
        if pos.len() != n || graph.n_vertices() != n {
            return Err(Error::SizeMismatch { what: "garment vertices to link", expected: n, got: pos.len() });
        }
        if grid.len() != nb || mesh.n_vertices() != nb {
            return Err(Error::SizeMismatch { what: "body vertices to link", expected: nb, got: grid.len() });
        }
        grid.nearest_within_on(exec, pos, BODY_EDGE_RADIUS, &self.hints, &mut self.nearest)?;
        for (h, near) in self.hints.iter_mut().zip(&self.nearest) {
            if let Some(near) = near {
                *h = near.index;
            }
        }
        mesh.keep_not_omitted(&mut self.nearest);
        let mut prefix = [0usize; 4];
        let mut ne = 0;
        for &g in &graph.body_order {
            if let Some(near) = self.nearest[g as usize] {
                self.pairs[ne] = [g, near.index];
                self.garment[ne] = g;
                ne += 1;
                let lvl = graph.vertex_level[g as usize] as usize;
                for p in prefix.iter_mut().take(lvl + 1) {
                    *p += 1;
                }
            }
        }
        // Active body nodes, ascending: mark the body vertices reached, then number them in order.
        for p in &self.pairs[..ne] {
            self.active_of[p[1] as usize] = 0;
        }
        let mut n_active = 0;
        for (o, a) in self.active_of.iter_mut().enumerate() {
            if *a == 0 {
                *a = n_active as u32;
                self.active[n_active] = o as u32;
                n_active += 1;
            }
        }
        for (row, p) in self.active_row[..ne].iter_mut().zip(&self.pairs[..ne]) {
            *row = self.active_of[p[1] as usize];
        }
        for &o in &self.active[..n_active] {
            self.active_of[o as usize] = u32::MAX;
        }
        self.counts = BodyEdgeCounts { prefix, n_active };
        Ok(self.counts)
    }

    /// The active body nodes of the last [`link`](Self::link), ascending.
    pub(crate) fn active(&self) -> &[u32] {
        &self.active[..self.counts.n_active]
    }

    /// `[garment vertex, body vertex]` of each body edge of the last [`link`](Self::link).
    pub(crate) fn pairs(&self) -> &[[u32; 2]] {
        &self.pairs[..self.counts.prefix[0]]
    }

    /// The body edges of the last [`link`](Self::link) as the forward pass reads them.
    pub(crate) fn edges(&self) -> BodyEdges<'_> {
        let ne = self.counts.prefix[0];
        BodyEdges {
            garment: &self.garment[..ne],
            body: &self.active_row[..ne],
            n_active: self.counts.n_active,
            prefix: self.counts.prefix,
        }
    }
}

/// The body as one step of the network sees it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BodyInputs<'a> {
    /// The body nodes' inputs: current and previous frames, normals, omitted flags, step.
    pub nodes: BodyNodes<'a>,
    /// The next frame, m (the current one for a static body).
    pub next: &'a [[f32; 3]],
    /// The active body nodes, ascending ([`BodyLinks::active`]).
    pub active: &'a [u32],
    /// Each body edge's garment and body vertex ([`BodyLinks::pairs`]).
    pub pairs: &'a [[u32; 2]],
}

/// Where [`node_features`] writes: node rows (garment, then active body nodes), and the
/// garment->body and body->garment edge rows; each slice exactly as long as its rows.
pub(crate) struct FeatureRows<'a> {
    /// `(garment vertices + active body nodes) x NODE_WIDTH`.
    pub nodes: &'a mut [f32],
    /// `body edges x BODY_EDGE_WIDTH`.
    pub g2b: &'a mut [f32],
    /// `body edges x BODY_EDGE_WIDTH`.
    pub b2g: &'a mut [f32],
}

/// The node features (a row per garment vertex, then per active body node) and, with a body,
/// both directions of the body edges between the garment at `pos` (m) and the body.
///
/// # Errors
/// [`Error::SizeMismatch`] for rows of the wrong length; errors of the feature functions.
pub(crate) fn node_features(
    garment: &GarmentNodes<'_>,
    body: Option<&BodyInputs<'_>>,
    pos: &[[f32; 3]],
    emb: &Embeddings<'_>,
    out: FeatureRows<'_>,
) -> Result<()> {
    let n_active = body.map_or(0, |b| b.active.len());
    let n_edges = body.map_or(0, |b| b.pairs.len());
    let rows = [
        ("node feature rows", out.nodes.len(), (pos.len() + n_active) * NODE_WIDTH),
        ("garment-to-body feature rows", out.g2b.len(), n_edges * BODY_EDGE_WIDTH),
        ("body-to-garment feature rows", out.b2g.len(), n_edges * BODY_EDGE_WIDTH),
    ];
    for (what, got, expected) in rows {
        if got != expected {
            return Err(Error::SizeMismatch { what, expected, got });
        }
    }
    let (gpart, bpart) = out.nodes.split_at_mut(pos.len() * NODE_WIDTH);
    features::garment_node_features(garment, emb, gpart)?;
    if let Some(b) = body {
        features::body_node_features(&b.nodes, b.active, emb, bpart)?;
        features::body_edge_features(b.pairs, pos, b.nodes.pos, b.next, garment.dt, out.g2b, out.b2g)?;
    }
    Ok(())
}
