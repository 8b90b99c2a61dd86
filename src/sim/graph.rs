//! The static part of a simulation's graph, derived once in `Sim::new`: mesh edges and coarse
//! levels in the index forms the kernels read, and the order in which body edges are listed.

use crate::error::{Error, Result};
use crate::hierarchy::Hierarchy;
use crate::mesh::topology::directed_csr;
use crate::mesh::Garment;
use alloc::vec;
use alloc::vec::Vec;

/// Directed edges as the kernels read them: parallel source/target arrays sorted by target.
#[derive(Clone, Debug, Default)]
pub struct EdgeList {
    /// `(source, target)` in garment vertex indices (for features).
    pub global: Vec<[u32; 2]>,
    /// Source per edge, in the index space of the node rows the kernel gathers from.
    pub source: Vec<u32>,
    /// Target per edge, same index space, ascending.
    pub target: Vec<u32>,
}

/// One coarse level: its nodes and its edges in level-local indices.
#[derive(Clone, Debug, Default)]
pub struct CoarseLevel {
    /// Garment vertices of the level, ascending; local index = position here.
    pub nodes: Vec<u32>,
    /// Directed edges (local indices for the kernels, global for features).
    pub edges: EdgeList,
}

/// The garment graph as the step uses it. Read-only outside the crate: the kernels rely on its
/// invariants (indices in range, targets sorted), which its constructors establish.
#[derive(Clone, Debug)]
pub struct Graph {
    /// Mesh edges (both directions), sorted by target; local = global indices.
    pub(crate) mesh: EdgeList,
    /// Coarse levels c0, c1, ...
    pub(crate) coarse: Vec<CoarseLevel>,
    /// Vertex level 0..=3 of every garment vertex.
    pub(crate) vertex_level: Vec<u8>,
    /// Garment vertices ordered by descending level, then ascending index: body edges are listed
    /// in this order, so the edges of a coarse level's nodes form a prefix.
    pub(crate) body_order: Vec<u32>,
    iota: Vec<u32>,
}

impl Graph {
    /// From a garment and its hierarchy.
    pub fn new(garment: &Garment, hierarchy: &Hierarchy) -> Result<Graph> {
        let coarse: Vec<Vec<[u32; 2]>> = hierarchy.levels().iter().map(|l| l.edges.clone()).collect();
        Graph::from_parts(garment, &coarse, hierarchy.vertex_level())
    }

    /// From a garment, with its hierarchy of `levels` coarse levels built by the default
    /// [`HierarchyConfig`](crate::hierarchy::HierarchyConfig) (as [`Sim::new`](super::Sim::new)
    /// builds it).
    ///
    /// # Errors
    /// Errors of the hierarchy.
    pub fn build(garment: &Garment, levels: usize) -> Result<Graph> {
        use crate::hierarchy::HierarchyConfig;
        let hierarchy = Hierarchy::build(garment, &HierarchyConfig { levels, ..HierarchyConfig::default() })?;
        Graph::new(garment, &hierarchy)
    }

    /// From a garment, undirected coarse edges per level and vertex levels (e.g. a reference
    /// fixture's graph).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] / [`Error::IndexOutOfRange`] for inconsistent input.
    pub fn from_parts(garment: &Garment, coarse_edges: &[Vec<[u32; 2]>], vertex_level: &[u8]) -> Result<Graph> {
        let n = garment.n_vertices();
        if vertex_level.len() != n {
            return Err(Error::SizeMismatch { what: "vertex levels", expected: n, got: vertex_level.len() });
        }
        if let Some(i) = vertex_level.iter().position(|&l| l as usize >= crate::features::LEVELS) {
            return Err(Error::OutOfRange { what: "vertex level (0 to 3)", index: i });
        }
        let d = garment.directed_edges();
        let mesh = EdgeList {
            global: d.to_vec(),
            source: d.iter().map(|e| e[0]).collect(),
            target: d.iter().map(|e| e[1]).collect(),
        };
        let mut coarse = Vec::with_capacity(coarse_edges.len());
        for edges in coarse_edges {
            let mut local = vec![u32::MAX; n];
            let mut nodes: Vec<u32> = Vec::new();
            for (at, e) in edges.iter().enumerate() {
                for &v in e {
                    if v as usize >= n {
                        return Err(Error::IndexOutOfRange { what: "coarse edge", at, index: v as usize, len: n });
                    }
                    local[v as usize] = 0;
                }
            }
            for v in 0..n {
                if local[v] == 0 {
                    local[v] = nodes.len() as u32;
                    nodes.push(v as u32);
                }
            }
            let local_pairs: Vec<[u32; 2]> =
                edges.iter().map(|e| [local[e[0] as usize], local[e[1] as usize]]).collect();
            let (directed, _) = directed_csr(nodes.len(), &local_pairs);
            let global = directed.iter().map(|e| [nodes[e[0] as usize], nodes[e[1] as usize]]).collect();
            let edges = EdgeList {
                global,
                source: directed.iter().map(|e| e[0]).collect(),
                target: directed.iter().map(|e| e[1]).collect(),
            };
            coarse.push(CoarseLevel { nodes, edges });
        }
        let mut body_order: Vec<u32> = (0..n as u32).collect();
        body_order.sort_by_key(|&v| (core::cmp::Reverse(vertex_level[v as usize]), v));
        Ok(Graph { mesh, coarse, vertex_level: vertex_level.to_vec(), body_order, iota: (0..n as u32).collect() })
    }

    /// Mesh edges (both directions), sorted by target; local = global indices.
    pub fn mesh(&self) -> &EdgeList {
        &self.mesh
    }

    /// Coarse levels c0, c1, ...
    pub fn coarse(&self) -> &[CoarseLevel] {
        &self.coarse
    }

    /// Vertex level 0..=3 of every garment vertex.
    pub fn vertex_level(&self) -> &[u8] {
        &self.vertex_level
    }

    /// Garment vertices ordered by descending level, then ascending index (the order body edges
    /// are listed in).
    pub fn body_order(&self) -> &[u32] {
        &self.body_order
    }

    /// `0, 1, 2, ...` (one per garment vertex): row indices for gathered rows.
    pub fn iota(&self) -> &[u32] {
        &self.iota
    }

    /// Garment vertex count.
    pub fn n_vertices(&self) -> usize {
        self.vertex_level.len()
    }

    /// The edge sets a model's edge encoders can read, in the order they are encoded: the mesh
    /// edges, then each coarse level the graph has, up to c2.
    pub fn edge_sets(&self) -> impl Iterator<Item = (crate::model::EdgeKey, &EdgeList)> + '_ {
        let coarse = self.coarse.iter().enumerate();
        let coarse = coarse.filter_map(|(l, c)| crate::model::EdgeKey::coarse(l).map(|k| (k, &c.edges)));
        core::iter::once((crate::model::EdgeKey::Mesh, &self.mesh)).chain(coarse)
    }

    /// The edge list an edge key reads: the mesh edges or one coarse level's.
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] for a coarse level this graph does not have.
    pub fn edges(&self, key: crate::model::EdgeKey) -> Result<&EdgeList> {
        match key.coarse_level() {
            None => Ok(&self.mesh),
            Some(l) => self
                .coarse
                .get(l)
                .map(|c| &c.edges)
                .ok_or(Error::IncompatibleModel { reason: "the model uses a coarse level the garment graph lacks" }),
        }
    }
}
