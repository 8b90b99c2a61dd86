//! The garment hierarchy: coarse levels c0, c1, c2 of the mesh graph (MODEL.md sections 1 and 2,
//! HOOD supplement Algorithm 1), their centres, and the per-vertex level.
//!
//! Every connected component is coarsened around its own centre, a node of minimal eccentricity
//! (the reference handles one component only). Level `i + 1` is built from level `i` (level 0 from
//! the mesh edges) by keeping the nodes at an even hop distance from the centre and joining them
//! through the odd nodes between them. Neighbours are visited in ascending index order, so the
//! result is a deterministic function of the edge set and the centres (the reference's result
//! depends on its graph library's insertion order instead).
//!
//! The graph has no geometry: distances here are hop counts, not metres.

use crate::error::{Error, Result};
use crate::mesh::topology::components;
use crate::mesh::Garment;
use alloc::vec;
use alloc::vec::Vec;
use centres::candidates_of;
use coarsen::{coarsen, Scratch};
use graph::{normalise_edges, Csr};
use search::{Bfs, UNREACHED};

mod centres;
mod coarsen;
mod graph;
mod search;
pub use centres::{centre_candidates, pick_centres};

/// The number of coarse levels the reference builds (c0, c1, c2).
pub const DEFAULT_LEVELS: usize = 3;

/// The largest number of coarse levels: [`Hierarchy::vertex_level`] is a `u8`.
pub const MAX_LEVELS: usize = u8::MAX as usize;

/// Which centre each connected component is coarsened around, among its candidates (all nodes
/// of minimal eccentricity, see [`centre_candidates`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum CentreChoice {
    /// The candidate of lowest index (inference: a fixed, reproducible choice).
    #[default]
    First,
    /// A candidate drawn per component from this seed (training: the reference draws a random
    /// centre for every sample). The same seed always gives the same centres.
    Seeded(u64),
}

/// How to build a [`Hierarchy`].
///
/// Built from [`Default`] and the `with_` methods (new fields may come, so it has no struct
/// literal outside this crate).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub struct HierarchyConfig {
    /// Number of coarse levels (the reference builds 3 and the network reads c0 and c1).
    pub levels: usize,
    /// How the centre of each component is chosen.
    pub centre: CentreChoice,
}

impl Default for HierarchyConfig {
    fn default() -> Self {
        HierarchyConfig { levels: DEFAULT_LEVELS, centre: CentreChoice::First }
    }
}

impl HierarchyConfig {
    with_fields! {
        /// Sets [`levels`](Self::levels): the number of coarse levels.
        with_levels => levels: usize;
        /// Sets [`centre`](Self::centre): how each component's centre is chosen.
        with_centre => centre: CentreChoice;
    }
}

/// One coarse level: its nodes and edges, over the garment's vertex indices.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Level {
    /// Unique undirected edges `(a, b)`, `a < b`, sorted.
    pub edges: Vec<[u32; 2]>,
    /// The nodes kept at this level (even hop distance from their component's centre in the
    /// finer level), ascending. A component reduced to its centre keeps it as a node without
    /// edges; otherwise every node here has at least one edge.
    pub nodes: Vec<u32>,
    /// Both directions of every edge as `(source, target)`, sorted by `(target, source)`.
    pub directed: Vec<[u32; 2]>,
    /// CSR offsets into `directed` (length: vertex count + 1): the edges into vertex `v` are
    /// `directed[in_offsets[v]..in_offsets[v + 1]]`.
    pub in_offsets: Vec<u32>,
}

/// The coarse levels of a garment graph, the centre of each component and each vertex's level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Hierarchy {
    levels: Vec<Level>,
    centres: Vec<u32>,
    vertex_level: Vec<u8>,
}

impl Hierarchy {
    /// Builds the coarse levels of a garment's mesh graph.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] when `cfg.levels` exceeds [`MAX_LEVELS`].
    pub fn build(garment: &Garment, cfg: &HierarchyConfig) -> Result<Hierarchy> {
        let n = garment.n_vertices();
        let adj = Csr::from_sorted_edges(n, garment.edges());
        let candidates = candidates_of(&adj, garment.component_of(), garment.n_components())?;
        let centres = pick_centres(&candidates, cfg.centre)?;
        Self::from_adjacency(adj, &centres, cfg.levels)
    }

    /// Builds the coarse levels of an arbitrary graph over `n_vertices` nodes. `edges` may come
    /// in either orientation and repeat; self-loops are ignored. An isolated node is a component
    /// of its own.
    ///
    /// # Errors
    /// [`Error::IndexOutOfRange`] for an edge naming a node past `n_vertices`;
    /// [`Error::OutOfRange`] when `cfg.levels` exceeds [`MAX_LEVELS`];
    /// [`Error::CapacityExceeded`] for more nodes than [`crate::limits::MAX_VERTICES`].
    pub fn from_graph(n_vertices: usize, edges: &[[u32; 2]], cfg: &HierarchyConfig) -> Result<Hierarchy> {
        let edges = normalise_edges(n_vertices, edges)?;
        let (component, n_components) = components(n_vertices, &edges);
        let adj = Csr::from_sorted_edges(n_vertices, &edges);
        let candidates = candidates_of(&adj, &component, n_components as usize)?;
        let centres = pick_centres(&candidates, cfg.centre)?;
        Self::from_adjacency(adj, &centres, cfg.levels)
    }

    /// Builds the coarse levels around given centres, exactly one per connected component (for
    /// example one drawn by the caller from [`centre_candidates`], or the reference's centre in a
    /// parity test). `edges` as in [`Hierarchy::from_graph`].
    ///
    /// # Errors
    /// [`Error::IndexOutOfRange`] for an edge or centre past `n_vertices`; [`Error::OutOfRange`]
    /// for a centre in the same component as an earlier one (`what: "centre"`), for a node whose
    /// component has no centre (`what: "node without a centre"`), or for too many levels.
    pub fn with_centres(n_vertices: usize, edges: &[[u32; 2]], centres: &[u32], levels: usize) -> Result<Hierarchy> {
        let edges = normalise_edges(n_vertices, edges)?;
        for (i, &c) in centres.iter().enumerate() {
            if c as usize >= n_vertices {
                return Err(Error::IndexOutOfRange { what: "centre", at: i, index: c as usize, len: n_vertices });
            }
        }
        Self::from_adjacency(Csr::from_sorted_edges(n_vertices, &edges), centres, levels)
    }

    fn from_adjacency(adj: Csr, centres: &[u32], levels: usize) -> Result<Hierarchy> {
        let levels = levels_checked(levels)?;
        let n = adj.n();
        let mut bfs = Bfs::new(n);
        // One BFS per centre on a shared distance array: a centre already reached lies in the
        // component of an earlier one.
        for (i, &c) in centres.iter().enumerate() {
            if bfs.dist[c as usize] != UNREACHED {
                return Err(Error::OutOfRange { what: "centre", index: i });
            }
            bfs.run(&adj, &[c]);
        }
        if let Some(v) = bfs.dist.iter().position(|&d| d == UNREACHED) {
            return Err(Error::OutOfRange { what: "node without a centre", index: v });
        }
        let mut scratch = Scratch::new(n);
        let mut out = Vec::with_capacity(levels);
        let mut adj = adj;
        for i in 0..levels {
            if i > 0 {
                bfs.clear();
                bfs.run(&adj, centres);
            }
            adj = coarsen(&adj, &bfs.dist, &mut scratch);
            let nodes =
                (0..n as u32).filter(|&v| bfs.dist[v as usize] != UNREACHED && bfs.dist[v as usize] & 1 == 0).collect();
            let (directed, in_offsets) = adj.directed();
            out.push(Level { edges: adj.edges(), nodes, directed, in_offsets });
        }
        let mut vertex_level = vec![0u8; n];
        for (i, level) in out.iter().enumerate() {
            for &[a, b] in &level.edges {
                vertex_level[a as usize] = i as u8 + 1;
                vertex_level[b as usize] = i as u8 + 1;
            }
        }
        Ok(Hierarchy { levels: out, centres: centres.to_vec(), vertex_level })
    }

    /// The coarse levels, finest (c0) first.
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// Number of coarse levels.
    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    /// The centre of each connected component, in the order of the components (numbered by
    /// their lowest vertex).
    pub fn centres(&self) -> &[u32] {
        &self.centres
    }

    /// Number of vertices of the graph.
    pub fn n_vertices(&self) -> usize {
        self.vertex_level.len()
    }

    /// Per vertex, its deepest coarse level (MODEL.md section 1): 0, then `i + 1` for every vertex
    /// touched by an edge of level `c_i`.
    pub fn vertex_level(&self) -> &[u8] {
        &self.vertex_level
    }
}

fn levels_checked(levels: usize) -> Result<usize> {
    if levels > MAX_LEVELS {
        return Err(Error::OutOfRange { what: "number of coarse levels", index: levels });
    }
    Ok(levels)
}

#[cfg(test)]
mod tests;
