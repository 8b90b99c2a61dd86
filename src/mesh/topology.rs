//! Connectivity derived from a triangle list: unique edges, directed edges sorted by target,
//! hinges, boundary loops and connected components.

use alloc::vec;
use alloc::vec::Vec;

/// An interior edge shared by two triangles: the unit of bending.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hinge {
    /// The shared edge `(v0, v1)` with `v0 < v1`.
    pub edge: [u32; 2],
    /// The two faces `(A, B)` in ascending face order.
    pub faces: [u32; 2],
    /// The vertex of face A and of face B opposite the shared edge.
    pub opposite: [u32; 2],
}

/// Everything [`build`] derives from the faces.
#[derive(Clone, Debug, Default)]
pub struct Topology {
    /// Unique undirected edges `(a, b)`, `a < b`, sorted.
    pub edges: Vec<[u32; 2]>,
    /// Both directions of every edge as `(source, target)`, sorted by `(target, source)`.
    pub directed: Vec<[u32; 2]>,
    /// CSR offsets into `directed`: the edges into vertex `v` are `directed[in_offsets[v]..in_offsets[v+1]]`.
    pub in_offsets: Vec<u32>,
    /// Interior edges with exactly (or, non-manifold, at least) two faces.
    pub hinges: Vec<Hinge>,
    /// Indices into `edges` of edges with more than two faces (their first two faces form the hinge).
    pub non_manifold_edges: Vec<u32>,
    /// Closed boundary loops as vertex sequences, following face orientation.
    pub boundary_loops: Vec<Vec<u32>>,
    /// Connected component of every vertex, numbered in order of each component's lowest vertex.
    pub component: Vec<u32>,
    /// Number of connected components.
    pub n_components: u32,
}

/// Derives the topology of `faces` over `n_vertices` vertices. Faces must be validated
/// (indices in range, no repeated vertex).
pub fn build(n_vertices: usize, faces: &[[u32; 3]]) -> Topology {
    // (a, b, face, opposite) per face side, a < b, sorted to group sides of the same edge.
    let mut sides: Vec<(u32, u32, u32, u32)> = Vec::with_capacity(faces.len() * 3);
    for (fi, f) in faces.iter().enumerate() {
        for k in 0..3 {
            let (a, b, o) = (f[k], f[(k + 1) % 3], f[(k + 2) % 3]);
            sides.push((a.min(b), a.max(b), fi as u32, o));
        }
    }
    sides.sort_unstable();

    let mut edges = Vec::new();
    let mut hinges = Vec::new();
    let mut non_manifold_edges = Vec::new();
    let mut boundary_edges: Vec<[u32; 2]> = Vec::new(); // oriented as in their face
    let mut i = 0;
    while i < sides.len() {
        let (a, b, f0, o0) = sides[i];
        let mut j = i + 1;
        while j < sides.len() && sides[j].0 == a && sides[j].1 == b {
            j += 1;
        }
        let count = j - i;
        if count == 1 {
            // Orientation of the edge inside its face: find whether a->b or b->a.
            let f = faces[f0 as usize];
            let k = f.iter().position(|&v| v == a).unwrap_or(0);
            let oriented = if f[(k + 1) % 3] == b { [a, b] } else { [b, a] };
            boundary_edges.push(oriented);
        } else {
            let (_, _, f1, o1) = sides[i + 1];
            hinges.push(Hinge { edge: [a, b], faces: [f0, f1], opposite: [o0, o1] });
            if count > 2 {
                non_manifold_edges.push(edges.len() as u32);
            }
        }
        edges.push([a, b]);
        i = j;
    }

    let (directed, in_offsets) = directed_csr(n_vertices, &edges);
    let boundary_loops = chain_loops(n_vertices, &boundary_edges);
    let (component, n_components) = components(n_vertices, &edges);
    Topology { edges, directed, in_offsets, hinges, non_manifold_edges, boundary_loops, component, n_components }
}

/// Both directions of `edges`, sorted by `(target, source)`, with CSR offsets per target.
pub fn directed_csr(n_vertices: usize, edges: &[[u32; 2]]) -> (Vec<[u32; 2]>, Vec<u32>) {
    let mut directed: Vec<[u32; 2]> = Vec::with_capacity(edges.len() * 2);
    for &[a, b] in edges {
        directed.push([a, b]);
        directed.push([b, a]);
    }
    directed.sort_unstable_by_key(|&[s, t]| (t, s));
    let mut in_offsets = vec![0u32; n_vertices + 1];
    for &[_, t] in &directed {
        in_offsets[t as usize + 1] += 1;
    }
    for v in 0..n_vertices {
        in_offsets[v + 1] += in_offsets[v];
    }
    (directed, in_offsets)
}

/// Chains oriented boundary edges into loops. Where a vertex starts several boundary edges
/// (two boundary loops touching at a vertex), edges are taken in ascending order.
fn chain_loops(n_vertices: usize, boundary: &[[u32; 2]]) -> Vec<Vec<u32>> {
    let mut sorted: Vec<[u32; 2]> = boundary.to_vec();
    sorted.sort_unstable();
    let mut start = vec![0u32; n_vertices + 1];
    for &[a, _] in &sorted {
        start[a as usize + 1] += 1;
    }
    for v in 0..n_vertices {
        start[v + 1] += start[v];
    }
    let mut used = vec![false; sorted.len()];
    let mut loops = Vec::new();
    for first in 0..sorted.len() {
        if used[first] {
            continue;
        }
        let mut lp = Vec::new();
        let mut e = first;
        loop {
            used[e] = true;
            let [a, b] = sorted[e];
            lp.push(a);
            let (lo, hi) = (start[b as usize] as usize, start[b as usize + 1] as usize);
            match (lo..hi).find(|&k| !used[k]) {
                Some(k) => e = k,
                None => break,
            }
        }
        loops.push(lp);
    }
    loops
}

/// Connected components over edges (union-find). Returns the component of every vertex,
/// numbered by each component's lowest vertex, and their count.
pub fn components(n_vertices: usize, edges: &[[u32; 2]]) -> (Vec<u32>, u32) {
    let mut parent: Vec<u32> = (0..n_vertices as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for &[a, b] in edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra.max(rb) as usize] = ra.min(rb);
        }
    }
    let mut label = vec![u32::MAX; n_vertices];
    let mut comp = vec![0u32; n_vertices];
    let mut n = 0;
    for v in 0..n_vertices {
        let r = find(&mut parent, v as u32) as usize;
        if label[r] == u32::MAX {
            label[r] = n;
            n += 1;
        }
        comp[v] = label[r];
    }
    (comp, n)
}
