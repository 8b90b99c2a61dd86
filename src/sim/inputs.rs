//! The body edges of a step (MODEL.md section 1): which garment vertices link to which body
//! vertices, in the order the network reads them, and which body vertices become its active body
//! nodes. One place for the runtime's prediction and the trainer's inputs.

use super::graph::Graph;
use crate::body::{BodyMesh, Nearest};

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

/// Where [`link_body_edges`] writes a step's body edges; every slice is indexed by edge but
/// `active` (by active row) and `active_of` (by body vertex).
pub(crate) struct BodyEdgeLists<'a> {
    /// Garment vertex of each edge: at least one entry per garment vertex.
    pub garment: &'a mut [u32],
    /// Active row of each edge's body vertex: as long as `garment`.
    pub active_row: &'a mut [u32],
    /// `[garment vertex, body vertex]` of each edge: as long as `garment`.
    pub pairs: &'a mut [[u32; 2]],
    /// The active body vertices, ascending: at least `min(garment vertices, body vertices)`.
    pub active: &'a mut [u32],
    /// Scratch, one entry per body vertex, `u32::MAX` on entry and on return.
    pub active_of: &'a mut [u32],
}

/// Links each garment vertex to its nearest body vertex within [`BODY_EDGE_RADIUS`]
/// (`nearest`, one per garment vertex, found by the caller) unless that body vertex is omitted
/// (`nearest` keeps only the links made): the edges are listed in the graph's body order (by
/// descending level, so each coarse level's edges are a prefix), the body vertices they reach
/// become the active body nodes, ascending, and each edge's body end its row among them.
pub(crate) fn link_body_edges(
    graph: &Graph,
    mesh: &BodyMesh,
    nearest: &mut [Option<Nearest>],
    out: BodyEdgeLists<'_>,
) -> BodyEdgeCounts {
    mesh.keep_not_omitted(nearest);
    let mut prefix = [0usize; 4];
    let mut ne = 0;
    for &g in &graph.body_order {
        if let Some(near) = nearest[g as usize] {
            out.pairs[ne] = [g, near.index];
            out.garment[ne] = g;
            ne += 1;
            let lvl = graph.vertex_level[g as usize] as usize;
            for p in prefix.iter_mut().take(lvl + 1) {
                *p += 1;
            }
        }
    }
    // Active body nodes, ascending: mark the body vertices reached, then number them in order.
    for p in &out.pairs[..ne] {
        out.active_of[p[1] as usize] = 0;
    }
    let mut n_active = 0;
    for (o, a) in out.active_of.iter_mut().enumerate() {
        if *a == 0 {
            *a = n_active as u32;
            out.active[n_active] = o as u32;
            n_active += 1;
        }
    }
    for (row, p) in out.active_row[..ne].iter_mut().zip(&out.pairs[..ne]) {
        *row = out.active_of[p[1] as usize];
    }
    for &o in &out.active[..n_active] {
        out.active_of[o as usize] = u32::MAX;
    }
    BodyEdgeCounts { prefix, n_active }
}
