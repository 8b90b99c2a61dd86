//! The body: its mesh (fixed), its per-frame geometry and the nearest-point queries that connect
//! it to the garment.
//!
//! * [`BodyMesh`]: vertex count, triangles and the per-vertex `body_omitted` flag (MODEL.md
//!   section 1). Body vertices move every frame, so positions (metres) are passed per call.
//! * [`geometry`]: face centroids, unit face normals and unit vertex normals into caller buffers.
//! * [`PointGrid`]: a uniform grid rebuilt every frame without allocation, answering exact
//!   nearest-point queries, with and without a radius.
//! * [`BodyFrame`]: owns the buffers and the two grids (vertices, face centroids) of one frame and
//!   answers the two queries of the model: body edges and nearest faces.
//! * [`shapes`]: procedural closed bodies.
//! * [`BodySurvey`]: whether a body mesh is inside out or too coarse for the model.
//! * [`Winding`]: which points lie inside the body (generalised winding number), for evaluation.

mod frame;
pub mod geometry;
mod grid;
pub mod rigid;
pub mod shapes;
mod survey;
mod winding;

pub use frame::{BodyFrame, GarmentQuery};
pub use grid::{Nearest, PointGrid, DEFAULT_CELLS_PER_POINT};
pub use survey::BodySurvey;
pub use winding::{winding_number_exact, Winding};

use crate::error::{Error, Result};
use crate::math::finite3;
use alloc::vec;
use alloc::vec::Vec;

/// The body's fixed connectivity: vertex count, triangles and the `body_omitted` flags.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyMesh {
    n_vertices: usize,
    faces: Vec<[u32; 3]>,
    omitted: Vec<bool>,
}

impl BodyMesh {
    /// A body of `n_vertices` vertices and `faces` (counter-clockwise seen from outside), with no
    /// vertex omitted. Degenerate (zero-area) faces are allowed: their normal is the zero vector.
    ///
    /// # Errors
    /// [`Error::Empty`] without vertices or faces; [`Error::IndexOutOfRange`] for a face naming a
    /// missing vertex (`at` is the face); [`Error::RepeatedVertex`] for a face naming a vertex
    /// twice; [`Error::CapacityExceeded`] beyond [`crate::limits::MAX_VERTICES`] or
    /// [`crate::limits::MAX_FACES`] (checked before anything is allocated).
    pub fn new(n_vertices: usize, faces: &[[u32; 3]]) -> Result<BodyMesh> {
        crate::limits::body(n_vertices, faces.len())?;
        if n_vertices == 0 {
            return Err(Error::Empty { what: "body vertices" });
        }
        if faces.is_empty() {
            return Err(Error::Empty { what: "body faces" });
        }
        for (fi, f) in faces.iter().enumerate() {
            if let Some(&v) = f.iter().find(|&&v| v as usize >= n_vertices) {
                return Err(Error::IndexOutOfRange { what: "body face", at: fi, index: v as usize, len: n_vertices });
            }
            if f[0] == f[1] || f[0] == f[2] {
                return Err(Error::RepeatedVertex { face: fi, vertex: f[0] as usize });
            }
            if f[1] == f[2] {
                return Err(Error::RepeatedVertex { face: fi, vertex: f[1] as usize });
            }
        }
        Ok(BodyMesh { n_vertices, faces: faces.to_vec(), omitted: vec![false; n_vertices] })
    }

    /// With the `body_omitted` flag of every vertex (true: the vertex never receives a body edge;
    /// the reference omits the hands).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `omitted` does not have one flag per vertex.
    pub fn with_omitted(mut self, omitted: &[bool]) -> Result<BodyMesh> {
        if omitted.len() != self.n_vertices {
            return Err(Error::SizeMismatch {
                what: "body omitted flags",
                expected: self.n_vertices,
                got: omitted.len(),
            });
        }
        self.omitted.copy_from_slice(omitted);
        Ok(self)
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }
    /// Number of triangles.
    pub fn n_faces(&self) -> usize {
        self.faces.len()
    }
    /// Triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
    /// The `body_omitted` flag of every vertex.
    pub fn omitted(&self) -> &[bool] {
        &self.omitted
    }

    /// Checks that `positions` has one finite position per vertex.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`]; [`Error::NonFinite`] naming the first bad vertex.
    pub fn check_positions(&self, positions: &[[f32; 3]]) -> Result<()> {
        if positions.len() != self.n_vertices {
            return Err(Error::SizeMismatch {
                what: "body positions",
                expected: self.n_vertices,
                got: positions.len(),
            });
        }
        match positions.iter().position(|p| !finite3(*p)) {
            Some(i) => Err(Error::NonFinite { what: "body vertex", index: i }),
            None => Ok(()),
        }
    }

    /// Face centroids `(v0 + v1 + v2) / 3` at `positions` (metres) into `out` (one per face).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for `positions` or `out` of the wrong length.
    pub fn face_centroids(&self, positions: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        self.check_lengths(positions, out.len(), self.faces.len(), "body face centroids")?;
        geometry::face_centroids(&self.faces, positions, out);
        Ok(())
    }

    /// Unit face normals at `positions` into `out` (one per face), see
    /// [`geometry::face_normals`].
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for `positions` or `out` of the wrong length.
    pub fn face_normals(&self, positions: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        self.check_lengths(positions, out.len(), self.faces.len(), "body face normals")?;
        geometry::face_normals(&self.faces, positions, out);
        Ok(())
    }

    /// Unit vertex normals at `positions` into `out` (one per vertex), by
    /// [`crate::mesh::vertex_normals`] (MODEL.md section 3).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for `positions` or `out` of the wrong length.
    pub fn vertex_normals(&self, positions: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        self.check_lengths(positions, out.len(), self.n_vertices, "body vertex normals")?;
        crate::mesh::vertex_normals(&self.faces, positions, out);
        Ok(())
    }

    /// Applies the body-edge rule of MODEL.md section 1 to raw nearest-vertex results (one per
    /// garment vertex, from [`PointGrid::nearest_within`] over the body vertices): an entry whose
    /// nearest body vertex is `body_omitted` becomes `None`. There is deliberately no fallback to
    /// the second-nearest vertex. Returns the number of entries left (the body-edge count).
    pub fn keep_not_omitted(&self, nearest: &mut [Option<Nearest>]) -> usize {
        let mut kept = 0;
        for n in nearest.iter_mut() {
            if let Some(m) = n {
                if self.omitted.get(m.index as usize).copied().unwrap_or(true) {
                    *n = None;
                } else {
                    kept += 1;
                }
            }
        }
        kept
    }

    fn check_lengths(&self, positions: &[[f32; 3]], out: usize, want: usize, what: &'static str) -> Result<()> {
        if positions.len() != self.n_vertices {
            return Err(Error::SizeMismatch {
                what: "body positions",
                expected: self.n_vertices,
                got: positions.len(),
            });
        }
        if out != want {
            return Err(Error::SizeMismatch { what, expected: want, got: out });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
