//! The undirected graph the levels are built on: edge keys, checked edge lists and the adjacency
//! with ascending neighbour lists ([`Csr`]).

use crate::error::{Error, Result};
use alloc::vec;
use alloc::vec::Vec;

pub(super) fn edge_key(a: u32, b: u32) -> u64 {
    let (a, b) = if a < b { (a, b) } else { (b, a) };
    ((a as u64) << 32) | b as u64
}

fn key_edge(k: u64) -> [u32; 2] {
    [(k >> 32) as u32, k as u32]
}

/// Edges checked, oriented `a < b`, without self-loops, sorted and unique.
pub(super) fn normalise_edges(n_vertices: usize, edges: &[[u32; 2]]) -> Result<Vec<[u32; 2]>> {
    // Every public entry point comes here first: an absurd count is refused before anything is
    // sized by it (and before it is narrowed to the u32 of the node indices).
    crate::limits::within("graph vertices", n_vertices, crate::limits::MAX_VERTICES)?;
    crate::limits::within("graph edges", edges.len(), crate::limits::MAX_FACES * 3)?;
    let mut keys = Vec::with_capacity(edges.len());
    for (i, &[a, b]) in edges.iter().enumerate() {
        for v in [a, b] {
            if v as usize >= n_vertices {
                return Err(Error::IndexOutOfRange { what: "edge", at: i, index: v as usize, len: n_vertices });
            }
        }
        if a != b {
            keys.push(edge_key(a, b));
        }
    }
    keys.sort_unstable();
    keys.dedup();
    Ok(keys.into_iter().map(key_edge).collect())
}

/// Undirected adjacency with ascending neighbour lists.
pub(super) struct Csr {
    pub(super) offsets: Vec<u32>,
    pub(super) nbrs: Vec<u32>,
}

impl Csr {
    /// From unique, sorted edges `a < b`. Visiting them in order appends every node's lower
    /// neighbours (ascending `a`) before its higher ones (ascending `b`), so lists come out sorted.
    pub(super) fn from_sorted_edges(n: usize, edges: &[[u32; 2]]) -> Csr {
        let mut offsets = vec![0u32; n + 1];
        for &[a, b] in edges {
            offsets[a as usize + 1] += 1;
            offsets[b as usize + 1] += 1;
        }
        for v in 0..n {
            offsets[v + 1] += offsets[v];
        }
        let mut fill: Vec<u32> = offsets[..n].to_vec();
        let mut nbrs = vec![0u32; edges.len() * 2];
        for &[a, b] in edges {
            nbrs[fill[a as usize] as usize] = b;
            fill[a as usize] += 1;
            nbrs[fill[b as usize] as usize] = a;
            fill[b as usize] += 1;
        }
        Csr { offsets, nbrs }
    }

    pub(super) fn n(&self) -> usize {
        self.offsets.len() - 1
    }

    /// This graph plus the edges `keys` (see [`edge_key`]; sorted and deduplicated here),
    /// merging neighbour lists node by node.
    pub(super) fn union_keys(self, keys: &mut Vec<u64>) -> Csr {
        if keys.is_empty() {
            return self;
        }
        keys.sort_unstable();
        keys.dedup();
        let edges: Vec<[u32; 2]> = keys.iter().map(|&k| key_edge(k)).collect();
        let extra = Csr::from_sorted_edges(self.n(), &edges);
        let mut offsets = Vec::with_capacity(self.offsets.len());
        offsets.push(0u32);
        let mut nbrs = Vec::with_capacity(self.nbrs.len() + extra.nbrs.len());
        for v in 0..self.n() as u32 {
            let (mut a, mut b) = (self.of(v), extra.of(v));
            while let (Some(&x), Some(&y)) = (a.first(), b.first()) {
                if x <= y {
                    nbrs.push(x);
                    a = &a[1..];
                    if x == y {
                        b = &b[1..];
                    }
                } else {
                    nbrs.push(y);
                    b = &b[1..];
                }
            }
            nbrs.extend_from_slice(a);
            nbrs.extend_from_slice(b);
            offsets.push(nbrs.len() as u32);
        }
        Csr { offsets, nbrs }
    }

    /// Unique undirected edges `(a, b)`, `a < b`, sorted.
    pub(super) fn edges(&self) -> Vec<[u32; 2]> {
        let mut out = Vec::with_capacity(self.nbrs.len() / 2);
        for v in 0..self.n() as u32 {
            out.extend(self.of(v).iter().filter(|&&w| w > v).map(|&w| [v, w]));
        }
        out
    }

    /// Both directions of every edge as `(source, target)` sorted by `(target, source)`, with
    /// CSR offsets per target: the same as `mesh::topology::directed_csr` of [`Csr::edges`], without a sort.
    pub(super) fn directed(&self) -> (Vec<[u32; 2]>, Vec<u32>) {
        let mut out = Vec::with_capacity(self.nbrs.len());
        for t in 0..self.n() as u32 {
            out.extend(self.of(t).iter().map(|&s| [s, t]));
        }
        (out, self.offsets.clone())
    }

    pub(super) fn of(&self, v: u32) -> &[u32] {
        &self.nbrs[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }
}
