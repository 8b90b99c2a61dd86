//! Explicit repairs for meshes that [`Garment::new`](super::Garment::new) refuses. Nothing is
//! fixed silently: each function returns what it removed, or the index remap it applied.

use super::is_degenerate;
use alloc::vec;
use alloc::vec::Vec;

/// Faces kept and the indices (into the input) of the faces dropped.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DroppedFaces {
    /// The faces that remain, in input order.
    pub faces: Vec<[u32; 3]>,
    /// Input indices of the faces removed.
    pub dropped: Vec<usize>,
}

/// Drops triangles that repeat a vertex, name a vertex past `rest.len()`, or have zero area.
pub fn drop_degenerate_faces(rest: &[[f32; 3]], faces: &[[u32; 3]]) -> DroppedFaces {
    let mut kept = Vec::with_capacity(faces.len());
    let mut dropped = Vec::new();
    for (i, f) in faces.iter().enumerate() {
        let in_range = f.iter().all(|&v| (v as usize) < rest.len());
        let distinct = f[0] != f[1] && f[1] != f[2] && f[0] != f[2];
        if in_range && distinct && !is_degenerate(rest, f) {
            kept.push(*f);
        } else {
            dropped.push(i);
        }
    }
    DroppedFaces { faces: kept, dropped }
}

/// A vertex renumbering: which old vertex each new one was, and where each old one went.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VertexRemap {
    /// `old_to_new[old]` is the new index, or `None` when the vertex was removed.
    pub old_to_new: Vec<Option<u32>>,
    /// `new_to_old[new]` is the old index.
    pub new_to_old: Vec<u32>,
}

impl VertexRemap {
    /// Applies the remap to any per-vertex array of the old mesh (materials, pinned flags, ...).
    ///
    /// # Panics
    /// When `per_old_vertex` is shorter than the old mesh's vertex count.
    pub fn apply<T: Clone>(&self, per_old_vertex: &[T]) -> Vec<T> {
        self.new_to_old.iter().map(|&o| per_old_vertex[o as usize].clone()).collect()
    }
}

/// The mesh without its unused vertices.
#[derive(Clone, Debug, PartialEq)]
pub struct CompactedMesh {
    /// Remaining positions.
    pub rest: Vec<[f32; 3]>,
    /// Faces renumbered.
    pub faces: Vec<[u32; 3]>,
    /// The renumbering.
    pub remap: VertexRemap,
}

/// Removes vertices used by no face and renumbers the faces.
///
/// # Panics
/// When a face names a vertex past `rest`.
pub fn drop_unused_vertices(rest: &[[f32; 3]], faces: &[[u32; 3]]) -> CompactedMesh {
    let mut used = vec![false; rest.len()];
    for f in faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    let mut old_to_new = vec![None; rest.len()];
    let mut new_to_old = Vec::new();
    for (i, &u) in used.iter().enumerate() {
        if u {
            old_to_new[i] = Some(new_to_old.len() as u32);
            new_to_old.push(i as u32);
        }
    }
    let faces = faces.iter().map(|f| f.map(|v| old_to_new[v as usize].unwrap_or(0))).collect();
    let rest = new_to_old.iter().map(|&o| rest[o as usize]).collect();
    CompactedMesh { rest, faces, remap: VertexRemap { old_to_new, new_to_old } }
}
