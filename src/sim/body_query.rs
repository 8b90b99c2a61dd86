//! The body's search structures of a frame (the grid of its vertices and their normals for the
//! network's body edges; face centroids, face normals and their grid for the solver's contact
//! terms and the collision projection), built once per body frame and reused by every step that
//! asks for the same frame: the next step of the same sim (whose current frame was the last
//! one's next) and the other garments of an [`Outfit`](super::Outfit) on the same body.
//!
//! Each structure is keyed by the exact bits of the body positions it was built at, so a reuse
//! is bitwise the same as a rebuild: sharing changes only the time a step takes.

use crate::body::{BodyMesh, PointGrid};
use crate::error::{Error, Result};
use crate::mesh::vertex_normals;
use crate::physics::{face_frames, FaceFrame};
use alloc::vec;
use alloc::vec::Vec;

/// What a step of some sim reads from the body (its configuration decides, at creation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct BodyNeeds {
    /// The vertex grid and vertex normals of the current frame (the network's body edges).
    pub vertices: bool,
    /// Face frames and their grid (the solver's contact terms, the collision projection).
    pub faces: bool,
}

impl BodyNeeds {
    /// Whether nothing is needed.
    pub fn none(self) -> bool {
        !self.vertices && !self.faces
    }

    /// What either needs.
    pub fn union(self, other: BodyNeeds) -> BodyNeeds {
        BodyNeeds { vertices: self.vertices || other.vertices, faces: self.faces || other.faces }
    }
}

/// The body positions a structure was built at (bits), or none while it is stale.
#[derive(Clone, Debug)]
struct Key {
    at: Vec<[f32; 3]>,
    valid: bool,
}

impl Key {
    fn new(n: usize) -> Key {
        Key { at: Vec::with_capacity(n), valid: false }
    }

    /// Whether the structure was built at exactly `positions` (bit for bit: a negative zero is
    /// another frame).
    fn holds(&self, positions: &[[f32; 3]]) -> bool {
        self.valid && bytemuck::cast_slice::<_, u32>(&self.at) == bytemuck::cast_slice::<_, u32>(positions)
    }

    fn invalidate(&mut self) {
        self.valid = false;
        self.at.clear();
    }

    /// Records `positions` (within the capacity of [`new`](Self::new): no allocation).
    fn set(&mut self, positions: &[[f32; 3]]) {
        self.at.clear();
        if self.at.capacity() >= positions.len() {
            self.at.extend_from_slice(positions);
            self.valid = true;
        }
    }
}

/// The body's vertices at one frame: their grid and normals.
#[derive(Clone, Debug)]
struct VertexSlot {
    key: Key,
    grid: PointGrid,
    normals: Vec<[f32; 3]>,
}

/// The body's faces at one frame: centroids and unit normals, and a nearest-centroid grid.
#[derive(Clone, Debug)]
struct FaceSlot {
    key: Key,
    centroids: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    grid: PointGrid,
}

impl FaceSlot {
    fn new(mesh: &BodyMesh) -> Result<FaceSlot> {
        let nf = mesh.n_faces();
        Ok(FaceSlot {
            key: Key::new(mesh.n_vertices()),
            centroids: vec![[0.0; 3]; nf],
            normals: vec![[0.0; 3]; nf],
            grid: PointGrid::new(nf, (8 * nf).max(64))?,
        })
    }

    fn build(&mut self, mesh: &BodyMesh, at: &[[f32; 3]]) -> Result<()> {
        // Stale until rebuilt, in case the rebuild fails.
        self.key.invalidate();
        face_frames(at, mesh.faces(), &mut self.centroids, &mut self.normals)?;
        self.grid.rebuild(&self.centroids)?;
        self.key.set(at);
        Ok(())
    }

    fn view(&self) -> BodyFaces<'_> {
        BodyFaces { frame: FaceFrame { centroids: &self.centroids, normals: &self.normals }, grid: &self.grid }
    }
}

/// The body's faces at one frame as a step reads them.
#[derive(Clone, Copy)]
pub(super) struct BodyFaces<'a> {
    /// Centroids and unit normals, m.
    pub frame: FaceFrame<'a, f32>,
    /// Nearest-centroid grid over `frame.centroids`.
    pub grid: &'a PointGrid,
}

/// The body's search structures, sized once for one [`BodyMesh`] and what its users need;
/// building and reusing them allocates nothing.
#[derive(Clone, Debug)]
pub(super) struct BodyQuery {
    vertices: Option<VertexSlot>,
    /// Two frames, for a step that reads the current and the next one.
    faces: Option<[FaceSlot; 2]>,
    /// The face slot of the frame asked for last (the other one is overwritten first).
    keep: usize,
    /// Grids built so far.
    builds: u64,
}

impl BodyQuery {
    /// Buffers for what `needs` asks of `mesh` (nothing else is allocated).
    pub fn new(mesh: &BodyMesh, needs: BodyNeeds) -> Result<BodyQuery> {
        let nb = mesh.n_vertices();
        let vertices = match needs.vertices {
            true => Some(VertexSlot {
                key: Key::new(nb),
                grid: PointGrid::new(nb, (8 * nb).max(64))?,
                normals: vec![[0.0; 3]; nb],
            }),
            false => None,
        };
        let faces = match needs.faces {
            true => Some([FaceSlot::new(mesh)?, FaceSlot::new(mesh)?]),
            false => None,
        };
        Ok(BodyQuery { vertices, faces, keep: 1, builds: 0 })
    }

    /// Grids built so far (a reuse builds none).
    pub fn builds(&self) -> u64 {
        self.builds
    }

    /// The grid and unit normals of the body's vertices at `at` (m).
    ///
    /// # Errors
    /// [`Error::UnsupportedEffect`] when the query was sized without vertices; errors of the
    /// grid (none for positions of the mesh it was sized for).
    pub fn vertices(&mut self, mesh: &BodyMesh, at: &[[f32; 3]]) -> Result<(&PointGrid, &[[f32; 3]])> {
        let slot = self.vertices.as_mut().ok_or(Error::UnsupportedEffect { effect: "body vertex query" })?;
        if !slot.key.holds(at) {
            slot.key.invalidate();
            slot.grid.rebuild(at)?;
            vertex_normals(mesh.faces(), at, &mut slot.normals);
            slot.key.set(at);
            self.builds += 1;
        }
        Ok((&slot.grid, &slot.normals))
    }

    /// The body's faces at `at` (m).
    ///
    /// # Errors
    /// As [`faces`](Self::faces).
    pub fn faces_at(&mut self, mesh: &BodyMesh, at: &[[f32; 3]]) -> Result<BodyFaces<'_>> {
        let slots = self.faces.as_mut().ok_or(Error::UnsupportedEffect { effect: "body face query" })?;
        let i = match slots.iter().position(|s| s.key.holds(at)) {
            Some(i) => i,
            None => {
                let i = 1 - self.keep;
                slots[i].build(mesh, at)?;
                self.builds += 1;
                i
            }
        };
        self.keep = i;
        Ok(slots[i].view())
    }

    /// The body's faces at `now` and at `next` (m); the frame that is already built is kept.
    ///
    /// # Errors
    /// [`Error::UnsupportedEffect`] when the query was sized without faces; errors of the
    /// faces' indices or the grid (none for positions of the mesh it was sized for).
    pub fn faces(&mut self, mesh: &BodyMesh, now: &[[f32; 3]], next: &[[f32; 3]]) -> Result<[BodyFaces<'_>; 2]> {
        let slots = self.faces.as_mut().ok_or(Error::UnsupportedEffect { effect: "body face query" })?;
        let find = |slots: &[FaceSlot; 2], at: &[[f32; 3]]| slots.iter().position(|s| s.key.holds(at));
        let (i_now, i_next) = match (find(slots, now), find(slots, next)) {
            (Some(a), Some(b)) => (a, b),
            (Some(a), None) => {
                slots[1 - a].build(mesh, next)?;
                self.builds += 1;
                (a, 1 - a)
            }
            (None, Some(b)) => {
                slots[1 - b].build(mesh, now)?;
                self.builds += 1;
                (1 - b, b)
            }
            (None, None) => {
                slots[0].build(mesh, now)?;
                slots[1].build(mesh, next)?;
                self.builds += 2;
                (0, 1)
            }
        };
        self.keep = i_next;
        Ok([slots[i_now].view(), slots[i_next].view()])
    }
}
