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
    /// [`Error::OutOfRange`] when `cfg.levels` exceeds [`MAX_LEVELS`].
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

fn levels_checked(levels: usize) -> Result<usize> {
    if levels > MAX_LEVELS {
        return Err(Error::OutOfRange { what: "number of coarse levels", index: levels });
    }
    Ok(levels)
}

fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn edge_key(a: u32, b: u32) -> u64 {
    let (a, b) = if a < b { (a, b) } else { (b, a) };
    ((a as u64) << 32) | b as u64
}

fn key_edge(k: u64) -> [u32; 2] {
    [(k >> 32) as u32, k as u32]
}

/// Edges checked, oriented `a < b`, without self-loops, sorted and unique.
fn normalise_edges(n_vertices: usize, edges: &[[u32; 2]]) -> Result<Vec<[u32; 2]>> {
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
struct Csr {
    offsets: Vec<u32>,
    nbrs: Vec<u32>,
}

impl Csr {
    /// From unique, sorted edges `a < b`. Visiting them in order appends every node's lower
    /// neighbours (ascending `a`) before its higher ones (ascending `b`), so lists come out sorted.
    fn from_sorted_edges(n: usize, edges: &[[u32; 2]]) -> Csr {
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

    fn n(&self) -> usize {
        self.offsets.len() - 1
    }

    /// This graph plus the edges `keys` (see [`edge_key`]; sorted and deduplicated here),
    /// merging neighbour lists node by node.
    fn union_keys(self, keys: &mut Vec<u64>) -> Csr {
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
    fn edges(&self) -> Vec<[u32; 2]> {
        let mut out = Vec::with_capacity(self.nbrs.len() / 2);
        for v in 0..self.n() as u32 {
            out.extend(self.of(v).iter().filter(|&&w| w > v).map(|&w| [v, w]));
        }
        out
    }

    /// Both directions of every edge as `(source, target)` sorted by `(target, source)`, with
    /// CSR offsets per target: the same as `mesh::topology::directed_csr` of [`Csr::edges`], without a sort.
    fn directed(&self) -> (Vec<[u32; 2]>, Vec<u32>) {
        let mut out = Vec::with_capacity(self.nbrs.len());
        for t in 0..self.n() as u32 {
            out.extend(self.of(t).iter().map(|&s| [s, t]));
        }
        (out, self.offsets.clone())
    }

    fn of(&self, v: u32) -> &[u32] {
        &self.nbrs[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }
}

const UNREACHED: u32 = u32::MAX;

/// In the centre search, a bounding BFS from a peripheral node is repeated while the previous one
/// closed at least this many open nodes; otherwise a batch certification comes next.
const PRUNE_GAIN: usize = 16;

/// Breadth-first search with reusable buffers; `queue` holds the nodes reached, so clearing costs
/// only what was visited.
struct Bfs {
    dist: Vec<u32>,
    queue: Vec<u32>,
}

impl Bfs {
    fn new(n: usize) -> Bfs {
        Bfs { dist: vec![UNREACHED; n], queue: Vec::with_capacity(n) }
    }

    /// Hop distances from `sources` to every node they reach (nodes reached by an earlier run
    /// stay as they are); returns the largest distance found by this run.
    fn run(&mut self, adj: &Csr, sources: &[u32]) -> u32 {
        let start = self.queue.len();
        for &s in sources {
            if self.dist[s as usize] == UNREACHED {
                self.dist[s as usize] = 0;
                self.queue.push(s);
            }
        }
        let mut head = start;
        let mut far = 0;
        while head < self.queue.len() {
            let v = self.queue[head];
            head += 1;
            let d = self.dist[v as usize] + 1;
            for &w in adj.of(v) {
                if self.dist[w as usize] == UNREACHED {
                    self.dist[w as usize] = d;
                    far = d;
                    self.queue.push(w);
                }
            }
        }
        far
    }

    fn clear(&mut self) {
        for &v in &self.queue {
            self.dist[v as usize] = UNREACHED;
        }
        self.queue.clear();
    }
}

/// Up to 64 breadth-first searches at once, one bit per source.
struct MultiBfs {
    visited: Vec<u64>,
    front: Vec<u64>,
    next: Vec<u64>,
    list: Vec<u32>,
    next_list: Vec<u32>,
}

impl MultiBfs {
    fn new(n: usize) -> MultiBfs {
        MultiBfs { visited: vec![0; n], front: vec![0; n], next: vec![0; n], list: Vec::new(), next_list: Vec::new() }
    }

    /// Searches from `sources` (at most 64, distinct, all in the component `nodes`) up to `depth`
    /// hops. Returns a mask with bit `k` set when `sources[k]` reaches every node within
    /// `depth`, and writes that source's eccentricity to `ecc[k]` (meaningless for unset bits).
    fn within(&mut self, adj: &Csr, nodes: &[u32], sources: &[u32], depth: u32, ecc: &mut [u32; 64]) -> u64 {
        debug_assert!(sources.len() <= 64);
        self.list.clear();
        for (k, &s) in sources.iter().enumerate() {
            self.visited[s as usize] |= 1 << k;
            self.front[s as usize] |= 1 << k;
            self.list.push(s);
            ecc[k] = 0;
        }
        let mut level = 0;
        while level < depth && !self.list.is_empty() {
            level += 1;
            for &v in &self.list {
                let f = self.front[v as usize];
                for &w in adj.of(v) {
                    let new = f & !self.visited[w as usize];
                    if new != 0 {
                        if self.next[w as usize] == 0 {
                            self.next_list.push(w);
                        }
                        self.next[w as usize] |= new;
                    }
                }
            }
            for &v in &self.list {
                self.front[v as usize] = 0;
            }
            let mut arrived = 0u64;
            for &w in &self.next_list {
                let bits = self.next[w as usize];
                arrived |= bits;
                self.visited[w as usize] |= bits;
                self.front[w as usize] = bits;
                self.next[w as usize] = 0;
            }
            while arrived != 0 {
                ecc[arrived.trailing_zeros() as usize] = level;
                arrived &= arrived - 1;
            }
            core::mem::swap(&mut self.list, &mut self.next_list);
            self.next_list.clear();
        }
        let mut all = if sources.len() == 64 { u64::MAX } else { (1u64 << sources.len()) - 1 };
        for &w in nodes {
            all &= self.visited[w as usize];
            self.visited[w as usize] = 0;
            self.front[w as usize] = 0;
        }
        all
    }
}

/// Per-node marks stamped with a generation counter, so "is `w` marked" needs no clearing.
struct Marks {
    stamp: Vec<u32>,
    now: u32,
}

impl Marks {
    fn new(n: usize) -> Marks {
        Marks { stamp: vec![0; n], now: 0 }
    }

    fn next(&mut self) {
        self.now = self.now.wrapping_add(1);
        if self.now == 0 {
            self.stamp.fill(0);
            self.now = 1;
        }
    }

    fn set(&mut self, v: u32) {
        self.stamp[v as usize] = self.now;
    }

    fn has(&self, v: u32) -> bool {
        self.stamp[v as usize] == self.now
    }
}

/// Buffers reused across levels.
struct Scratch {
    marks: Marks,
    keys: Vec<u64>,
    closer: Vec<u32>,
    /// Edges added by step 4, as singly linked lists per node (head, then next/to per entry).
    head: Vec<u32>,
    next: Vec<u32>,
    to: Vec<u32>,
}

impl Scratch {
    fn new(n: usize) -> Scratch {
        Scratch {
            marks: Marks::new(n),
            keys: Vec::new(),
            closer: Vec::new(),
            head: vec![UNREACHED; n],
            next: Vec::new(),
            to: Vec::new(),
        }
    }
}

/// One coarsening step (Algorithm 1, steps 2 to 4) of the graph `adj` whose hop distances from
/// the centres are `dist` (`UNREACHED` for nodes not in the graph). Returns the new level's
/// adjacency. Built node by node, so no global sort of the edge list is needed.
fn coarsen(adj: &Csr, dist: &[u32], s: &mut Scratch) -> Csr {
    let n = adj.n();
    let odd = |v: u32| dist[v as usize] != UNREACHED && dist[v as usize] & 1 == 1;
    let even = |v: u32| dist[v as usize] != UNREACHED && dist[v as usize] & 1 == 0;

    // Step 2: across every odd node, join each neighbour one hop closer to each one hop farther
    // (such a pair is always exactly two hops apart). Seen from an even node x, its partners are
    // the nodes two levels up or down behind its odd neighbours.
    let mut offsets = Vec::with_capacity(n + 1);
    offsets.push(0u32);
    let mut nbrs = Vec::with_capacity(adj.nbrs.len());
    for x in 0..n as u32 {
        if even(x) {
            let dx = dist[x as usize];
            let start = nbrs.len();
            s.marks.next();
            for &u in adj.of(x) {
                if !odd(u) {
                    continue;
                }
                let target = if dist[u as usize] > dx { dx + 2 } else { dx - 2 };
                for &w in adj.of(u) {
                    if dist[w as usize] == target && !s.marks.has(w) {
                        s.marks.set(w);
                        nbrs.push(w);
                    }
                }
            }
            nbrs[start..].sort_unstable();
        }
        offsets.push(nbrs.len() as u32);
    }
    let g2 = Csr { offsets, nbrs };

    // Step 3: where the front ends at an odd node, join its closer neighbours that are not within
    // two hops in the step-2 graph (checked against step 2 only, as the reference does, so the
    // result does not depend on the visiting order).
    s.keys.clear();
    for v in 0..n as u32 {
        if !odd(v) {
            continue;
        }
        let d = dist[v as usize];
        if adj.of(v).iter().any(|&w| dist[w as usize] == d + 1) {
            continue;
        }
        s.closer.clear();
        s.closer.extend(adj.of(v).iter().copied().filter(|&w| dist[w as usize] == d - 1));
        for (i, &a) in s.closer.iter().enumerate() {
            s.marks.next();
            for &w in g2.of(a) {
                s.marks.set(w);
            }
            for &b in &s.closer[i + 1..] {
                if !s.marks.has(b) && !g2.of(b).iter().any(|&w| s.marks.has(w)) {
                    s.keys.push(edge_key(a, b));
                }
            }
        }
    }
    let g3 = g2.union_keys(&mut s.keys);

    // Step 4: join even nodes that were adjacent (hence at the same distance) unless already
    // within two hops, counting the edges this step has added so far.
    s.keys.clear();
    s.head.fill(UNREACHED);
    s.next.clear();
    s.to.clear();
    for v in 0..n as u32 {
        if !even(v) {
            continue;
        }
        let d = dist[v as usize];
        s.marks.next();
        s.marks.set(v);
        for &w in g3.of(v) {
            s.marks.set(w);
        }
        let mut e = s.head[v as usize];
        while e != UNREACHED {
            s.marks.set(s.to[e as usize]);
            e = s.next[e as usize];
        }
        for &a in adj.of(v) {
            if dist[a as usize] != d || s.marks.has(a) {
                continue;
            }
            let mut near = g3.of(a).iter().any(|&w| s.marks.has(w));
            let mut e = s.head[a as usize];
            while !near && e != UNREACHED {
                near = s.marks.has(s.to[e as usize]);
                e = s.next[e as usize];
            }
            if near {
                continue;
            }
            for (from, to) in [(v, a), (a, v)] {
                s.next.push(s.head[from as usize]);
                s.to.push(to);
                s.head[from as usize] = s.to.len() as u32 - 1;
            }
            s.marks.set(a);
            s.keys.push(edge_key(v, a));
        }
    }
    g3.union_keys(&mut s.keys)
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
fn candidates_of(adj: &Csr, component: &[u32], n_components: usize) -> Result<Vec<Vec<u32>>> {
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

#[cfg(test)]
mod tests;
