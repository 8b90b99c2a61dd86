//! Simple procedural cloth shapes (no files needed), used by tests, benches and examples.

use alloc::vec::Vec;

/// A flat rectangular cloth in the x-z plane at height `y`, `nx` x `nz` vertices spanning
/// `width` x `depth` metres, centred on the origin. Each quad is split along alternating
/// diagonals; faces are counter-clockwise seen from +y.
///
/// # Panics
/// When `nx < 2` or `nz < 2`.
pub fn grid(nx: usize, nz: usize, width: f32, depth: f32, y: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    assert!(nx >= 2 && nz >= 2, "a grid needs at least 2 x 2 vertices");
    let mut rest = Vec::with_capacity(nx * nz);
    for j in 0..nz {
        for i in 0..nx {
            let x = width * (i as f32 / (nx - 1) as f32 - 0.5);
            let z = depth * (j as f32 / (nz - 1) as f32 - 0.5);
            rest.push([x, y, z]);
        }
    }
    // Seen from +y with x right and z down the page, each cell's triangles are counter-clockwise.
    let faces = grid_triangles(nx, nz, false);
    (rest, faces)
}

/// The triangles of an `nu x nv` grid of vertices (index `j * nu + i`, `i` fastest), wrapping in
/// `i` when `closed` (a tube), two per cell with alternating diagonals, all wound as the cell's
/// corners `(i, j)`, `(i, j + 1)`, `(i + 1, j + 1)` are.
pub(crate) fn grid_triangles(nu: usize, nv: usize, closed: bool) -> Vec<[u32; 3]> {
    let cols = if closed { nu } else { nu.saturating_sub(1) };
    let mut faces = Vec::with_capacity(2 * cols * nv.saturating_sub(1));
    let id = |i: usize, j: usize| (j * nu + i % nu) as u32;
    for j in 0..nv.saturating_sub(1) {
        for i in 0..cols {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                faces.push([a, d, c]);
                faces.push([a, c, b]);
            } else {
                faces.push([a, d, b]);
                faces.push([b, d, c]);
            }
        }
    }
    faces
}

/// One 1-to-4 midpoint subdivision: a new vertex at the middle of every edge (appended after
/// the original vertices, in the order of the garment's sorted unique edges), each triangle
/// split into four with the same orientation. Apply the same call to any per-vertex positions
/// of the mesh (rest, current, previous) to get consistent subdivided copies.
///
/// # Panics
/// When a face names a vertex past `positions` (a validated [`crate::mesh::Garment`]'s faces
/// never do).
pub fn subdivide(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut edges: Vec<[u32; 2]> = faces.iter().flat_map(|f| [0, 1, 2].map(|k| sorted(f[k], f[(k + 1) % 3]))).collect();
    edges.sort_unstable();
    edges.dedup();
    let n = positions.len() as u32;
    let mut out = positions.to_vec();
    for &[a, b] in &edges {
        let (pa, pb) = (positions[a as usize], positions[b as usize]);
        out.push([0.5 * (pa[0] + pb[0]), 0.5 * (pa[1] + pb[1]), 0.5 * (pa[2] + pb[2])]);
    }
    let mid = |a: u32, b: u32| n + edges.binary_search(&sorted(a, b)).unwrap_or(0) as u32;
    let mut new_faces = Vec::with_capacity(faces.len() * 4);
    for &[a, b, c] in faces {
        let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
        new_faces.extend_from_slice(&[[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    (out, new_faces)
}

fn sorted(a: u32, b: u32) -> [u32; 2] {
    [a.min(b), a.max(b)]
}
