//! Centres of the components: every node of minimal eccentricity by exact eccentricity bounding
//! ([`centre_candidates`]), and one centre per component picked from them ([`pick_centres`]).

use super::graph::{normalise_edges, Csr};
use super::search::{Bfs, Marks, MultiBfs, UNREACHED};
use super::CentreChoice;
use crate::error::{Error, Result};
use alloc::vec;
use alloc::vec::Vec;

/// In the centre search, a bounding BFS from a peripheral node is repeated while the previous one
/// closed at least this many open nodes; otherwise a batch certification comes next.
const PRUNE_GAIN: usize = 16;

/// For each connected component, all its nodes of minimal eccentricity (hop count), ascending.
/// `component[v]` is the component of node `v`, in `0..n_components`; `edges` as in
/// [`Hierarchy::from_graph`].
///
/// Exact, by eccentricity bounding (Takes and Kosters, *Computing the eccentricity distribution
/// of large graphs*, 2013): BFS from nodes of extreme bounds until every node's eccentricity is
/// either known or provably above the radius. Meshes need a few BFS plus one per candidate.
///
/// # Errors
/// [`Error::SizeMismatch`] when `component` is not one label per node;
/// [`Error::IndexOutOfRange`] for an edge or label out of range; [`Error::OutOfRange`] for an
/// edge joining two components (`what: "edge across components"`) or a component that is not
/// connected (`what: "disconnected component"`); [`Error::Empty`] for a component without nodes.
///
/// [`Hierarchy::from_graph`]: super::Hierarchy::from_graph
pub fn centre_candidates(
    n_vertices: usize,
    edges: &[[u32; 2]],
    component: &[u32],
    n_components: usize,
) -> Result<Vec<Vec<u32>>> {
    let edges = normalise_edges(n_vertices, edges)?;
    if component.len() != n_vertices {
        return Err(Error::SizeMismatch { what: "component labels", expected: n_vertices, got: component.len() });
    }
    for (v, &c) in component.iter().enumerate() {
        if c as usize >= n_components {
            return Err(Error::IndexOutOfRange {
                what: "component label",
                at: v,
                index: c as usize,
                len: n_components,
            });
        }
    }
    for (i, &[a, b]) in edges.iter().enumerate() {
        if component[a as usize] != component[b as usize] {
            return Err(Error::OutOfRange { what: "edge across components", index: i });
        }
    }
    candidates_of(&Csr::from_sorted_edges(n_vertices, &edges), component, n_components)
}

/// One centre per component from its candidates (see [`CentreChoice`]).
///
/// # Errors
/// [`Error::Empty`] when a component has no candidate.
pub fn pick_centres(candidates: &[Vec<u32>], choice: CentreChoice) -> Result<Vec<u32>> {
    candidates
        .iter()
        .enumerate()
        .map(|(k, c)| {
            if c.is_empty() {
                return Err(Error::Empty { what: "centre candidates of a component" });
            }
            Ok(match choice {
                CentreChoice::First => c[0],
                CentreChoice::Seeded(seed) => {
                    let r = splitmix64(seed ^ splitmix64(k as u64));
                    c[(r % c.len() as u64) as usize]
                }
            })
        })
        .collect()
}

fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// [`centre_candidates`] on a built adjacency; labels must be valid.
///
/// Per component, every node is open with bounds `lower <= ecc <= upper`, and `radius` is the
/// smallest upper bound. Two kinds of rounds close open nodes until none is left:
/// * a bounding BFS (Takes and Kosters) from one node tightens every node's bounds; a node whose
///   lower bound exceeds `radius` can no longer be a candidate. The first four alternate between
///   the open node of smallest lower bound and the one of largest upper bound; later ones take
///   the latter (peripheral nodes prune best) while they keep paying off (see [`PRUNE_GAIN`]);
/// * a batch certification settles up to 64 open nodes around the one of smallest lower bound
///   with one bit-parallel BFS truncated at `radius`: a node that reaches everything gets its
///   exact eccentricity, the others exceed the radius. Meshes have many candidates (a plateau of
///   equal eccentricity, hundreds of nodes on a 20k-vertex garment), each of which would need
///   its own BFS to be certified; nearby sources share most of their search.
///
/// At the end every node has a known eccentricity or one above `radius`, which is then the radius.
pub(super) fn candidates_of(adj: &Csr, component: &[u32], n_components: usize) -> Result<Vec<Vec<u32>>> {
    let n = adj.n();
    // Nodes grouped by component, ascending within each.
    let mut start = vec![0u32; n_components + 1];
    for &c in component {
        start[c as usize + 1] += 1;
    }
    for c in 0..n_components {
        start[c + 1] += start[c];
    }
    let mut fill = start[..n_components].to_vec();
    let mut members = vec![0u32; n];
    for (v, &c) in component.iter().enumerate() {
        members[fill[c as usize] as usize] = v as u32;
        fill[c as usize] += 1;
    }

    let mut lower = vec![0u32; n];
    let mut upper = vec![u32::MAX; n];
    let mut bfs = Bfs::new(n);
    let mut open: Vec<u32> = Vec::new();
    let mut multi: Option<MultiBfs> = None;
    let mut marks = Marks::new(n);
    let mut batch: Vec<u32> = Vec::with_capacity(64);
    let mut ecc = [0u32; 64];
    let mut out = Vec::with_capacity(n_components);
    for c in 0..n_components {
        let nodes = &members[start[c] as usize..start[c + 1] as usize];
        if nodes.is_empty() {
            return Err(Error::Empty { what: "connected component" });
        }
        open.clear();
        open.extend_from_slice(nodes);
        let mut radius = u32::MAX;
        let mut round = 0usize;
        let mut gain = usize::MAX;
        let mut peripheral = false;
        while !open.is_empty() {
            round += 1;
            let only_certify = open.iter().all(|&w| lower[w as usize] == radius);
            let before = open.len();
            peripheral = round <= 4 || (!only_certify && (gain >= PRUNE_GAIN || !peripheral));
            if peripheral {
                // Single BFS: first alternating between the node of smallest lower bound (likely
                // central) and the one of largest upper bound (likely peripheral), then only the
                // latter, whose lower bounds prune. Ties to the higher degree, then lower index.
                let pick = if round.is_multiple_of(2) && round <= 4 {
                    open.iter().copied().min_by_key(|&v| (lower[v as usize], usize::MAX - adj.of(v).len(), v))
                } else {
                    open.iter().copied().max_by_key(|&v| (upper[v as usize], adj.of(v).len(), u32::MAX - v))
                };
                let v = pick.unwrap_or(open[0]);
                bfs.clear();
                let e = bfs.run(adj, &[v]);
                if bfs.queue.len() != nodes.len() {
                    return Err(Error::OutOfRange { what: "disconnected component", index: c });
                }
                for &w in nodes {
                    let d = bfs.dist[w as usize];
                    let (lo, hi) = (&mut lower[w as usize], &mut upper[w as usize]);
                    *lo = (*lo).max(d).max(e - d);
                    *hi = (*hi).min(e + d);
                    radius = radius.min(*hi);
                }
            } else {
                // Certify a batch: the open node of smallest lower bound and the open nodes
                // nearest to it, 64 at most, by one bit-parallel BFS truncated at the radius
                // bound. A node reaching everything has its exact eccentricity; the others
                // exceed the radius.
                let seed = open.iter().copied().min_by_key(|&v| (lower[v as usize], v)).unwrap_or(open[0]);
                marks.next();
                for &w in &open {
                    marks.set(w);
                }
                batch.clear();
                bfs.clear();
                bfs.dist[seed as usize] = 0;
                bfs.queue.push(seed);
                let mut head = 0;
                while head < bfs.queue.len() && batch.len() < 64 {
                    let u = bfs.queue[head];
                    head += 1;
                    if marks.has(u) {
                        batch.push(u);
                    }
                    for &w in adj.of(u) {
                        if bfs.dist[w as usize] == UNREACHED {
                            bfs.dist[w as usize] = 0;
                            bfs.queue.push(w);
                        }
                    }
                }
                let multi = multi.get_or_insert_with(|| MultiBfs::new(n));
                let reach = multi.within(adj, nodes, &batch, radius, &mut ecc);
                for (k, &w) in batch.iter().enumerate() {
                    if reach >> k & 1 == 1 {
                        lower[w as usize] = ecc[k];
                        upper[w as usize] = ecc[k];
                        radius = radius.min(ecc[k]);
                    } else {
                        lower[w as usize] = radius.saturating_add(1);
                    }
                }
            }
            open.retain(|&w| lower[w as usize] != upper[w as usize] && lower[w as usize] <= radius);
            if peripheral {
                gain = before - open.len();
            }
        }
        // Every node now has a known eccentricity or one above the radius, so the candidates are
        // the nodes known to reach it.
        out.push(
            nodes.iter().copied().filter(|&w| lower[w as usize] == radius && upper[w as usize] == radius).collect(),
        );
    }
    Ok(out)
}
