//! One frame of the body: centroids, normals and both grids, in buffers sized once.

use super::grid::{check_batch, check_queries, check_within, chunks_for, hint_range};
use super::{BodyMesh, Nearest, PointGrid};
use crate::error::{Error, Result};
use crate::exec::par::{split, BuildOnce, Disjoint};
use crate::exec::{Executor, Serial};
use alloc::vec;
use alloc::vec::Vec;
use core::sync::atomic::{AtomicUsize, Ordering};

/// The body's geometry at one frame and the two nearest-point grids (body vertices, face
/// centroids). [`new`](Self::new) sizes everything for one [`BodyMesh`]; [`update`](Self::update)
/// and the queries then allocate nothing.
#[derive(Clone, Debug)]
pub struct BodyFrame {
    n_vertices: usize,
    centroids: Vec<[f32; 3]>,
    face_normals: Vec<[f32; 3]>,
    vertex_normals: Vec<[f32; 3]>,
    vertex_grid: PointGrid,
    centroid_grid: PointGrid,
}

/// The garment side of a whole body query, [`BodyFrame::update_and_query_on`].
#[derive(Clone, Copy, Debug)]
pub struct GarmentQuery<'a> {
    /// Garment vertex positions, metres.
    pub points: &'a [[f32; 3]],
    /// Body-edge radius, metres (inclusive).
    pub radius: f32,
    /// A guessed nearest body vertex per garment vertex (e.g. last frame's; `u32::MAX` for
    /// none), or empty.
    pub vertex_hints: &'a [u32],
    /// A guessed nearest face per garment vertex (e.g. last frame's), or empty.
    pub face_hints: &'a [u32],
}

/// Cells allowed per point: the grids aim for [`super::DEFAULT_CELLS_PER_POINT`], this leaves
/// room for flat or thin point sets, whose block padding wastes cells.
const MAX_CELLS_PER_POINT: usize = 32;

/// Cells per centroid: the unbounded nearest-face search does best with coarser cells than the
/// radius search over the vertices (measured on the MakeHuman body: 1 beats 2 by ~8 %).
const CENTROID_CELLS_PER_POINT: f32 = 1.0;

impl BodyFrame {
    /// Buffers and grids for `mesh` (empty until the first [`update`](Self::update)).
    pub fn new(mesh: &BodyMesh) -> Result<BodyFrame> {
        let (nv, nf) = (mesh.n_vertices(), mesh.n_faces());
        let mut centroid_grid = PointGrid::new(nf, (MAX_CELLS_PER_POINT * nf).max(64))?;
        centroid_grid.set_cells_per_point(CENTROID_CELLS_PER_POINT)?;
        Ok(BodyFrame {
            n_vertices: nv,
            centroids: vec![[0.0; 3]; nf],
            face_normals: vec![[0.0; 3]; nf],
            vertex_normals: vec![[0.0; 3]; nv],
            vertex_grid: PointGrid::new(nv, (MAX_CELLS_PER_POINT * nv).max(64))?,
            centroid_grid,
        })
    }

    /// Sets the cells per point of both grids (speed only), see
    /// [`PointGrid::set_cells_per_point`].
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a non-positive or non-finite value.
    pub fn set_cells_per_point(&mut self, cells_per_point: f32) -> Result<()> {
        self.vertex_grid.set_cells_per_point(cells_per_point)?;
        self.centroid_grid.set_cells_per_point(cells_per_point)
    }

    /// Recomputes centroids, face and vertex normals and both grids at `positions` (metres, one
    /// per body vertex).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `mesh` is not the mesh of [`new`](Self::new) (by size) or
    /// `positions` has the wrong length; [`Error::NonFinite`] naming the first NaN/Inf body vertex
    /// (the frame is then not updated).
    pub fn update(&mut self, mesh: &BodyMesh, positions: &[[f32; 3]]) -> Result<()> {
        self.check_mesh(mesh)?;
        mesh.check_positions(positions)?;
        mesh.face_normals(positions, &mut self.face_normals)?;
        mesh.vertex_normals(positions, &mut self.vertex_normals)?;
        self.update_grids(mesh, positions)
    }

    /// Rebuilds only the two grids at `positions` (for callers that compute normals
    /// themselves): the face centroids are recomputed first, since the centroid grid needs them.
    ///
    /// # Errors
    /// As [`update`](Self::update).
    pub fn update_grids(&mut self, mesh: &BodyMesh, positions: &[[f32; 3]]) -> Result<()> {
        self.update_grids_on(&Serial, mesh, positions)
    }

    /// As [`update_grids`](Self::update_grids), rebuilding the two grids as two tasks of `exec`
    /// (the vertex grid; the centroids and their grid). Same result for any executor.
    ///
    /// # Errors
    /// As [`update`](Self::update).
    pub fn update_grids_on(&mut self, exec: &dyn Executor, mesh: &BodyMesh, positions: &[[f32; 3]]) -> Result<()> {
        // The whole query with no garment: the same two rebuild tasks, and empty query chunks.
        let none = GarmentQuery { points: &[], radius: 0.0, vertex_hints: &[], face_hints: &[] };
        self.update_and_query_on(exec, mesh, positions, none, &mut [], &mut []).map(drop)
    }

    /// [`Error::SizeMismatch`] unless `mesh` is the mesh of [`new`](Self::new) (by size).
    fn check_mesh(&self, mesh: &BodyMesh) -> Result<()> {
        if mesh.n_vertices() != self.n_vertices || mesh.n_faces() != self.centroids.len() {
            return Err(Error::SizeMismatch {
                what: "body frame mesh",
                expected: self.n_vertices,
                got: mesh.n_vertices(),
            });
        }
        Ok(())
    }

    /// The whole body query of one frame in one job of `exec`: rebuilds both grids at
    /// `positions` (as [`update_grids`](Self::update_grids)), then writes the body edges of
    /// `query` into `edges` (as [`body_edges_on`](Self::body_edges_on)) and the nearest faces into
    /// `faces` (as [`nearest_faces_on`](Self::nearest_faces_on)). Returns the number of edges.
    ///
    /// The two rebuilds are the job's first two tasks, so they run side by side; each query chunk
    /// starts as soon as its own grid is built, so the queries over the vertex grid fill the
    /// time the centroid grid takes. Same results as the separate serial calls for any executor.
    /// Allocates nothing.
    ///
    /// # Errors
    /// As [`update_grids`](Self::update_grids), [`body_edges_on`](Self::body_edges_on) and
    /// [`nearest_faces_on`](Self::nearest_faces_on). All input is checked before anything is
    /// rebuilt, so on error the frame and the outputs are unchanged.
    pub fn update_and_query_on(
        &mut self,
        exec: &dyn Executor,
        mesh: &BodyMesh,
        positions: &[[f32; 3]],
        query: GarmentQuery<'_>,
        edges: &mut [Option<Nearest>],
        faces: &mut [Nearest],
    ) -> Result<usize> {
        self.check_mesh(mesh)?;
        mesh.check_positions(positions)?;
        let points = query.points;
        let n = points.len();
        check_within(n, query.vertex_hints.len(), edges.len(), query.radius)?;
        check_batch(n, query.face_hints.len(), faces.len())?;
        check_queries(points)?;

        let chunks = chunks_for(exec.parallelism(), n);
        let vertex_grid = BuildOnce::new(&mut self.vertex_grid);
        let centroid_grid = BuildOnce::new(&mut self.centroid_grid);
        let centroids = &mut self.centroids;
        let build_vertex_grid = |g: &mut PointGrid| g.rebuild(positions);
        // Only the task that builds the centroid grid touches the centroids.
        let centroids = Disjoint::new(centroids);
        let build_centroid_grid = |g: &mut PointGrid| {
            // SAFETY: `BuildOnce` runs this closure at most once, so this is the only reference.
            let c = unsafe { centroids.range(0..mesh.n_faces()) };
            super::geometry::face_centroids(mesh.faces(), positions, c);
            g.rebuild(c)
        };
        let kept = AtomicUsize::new(0);
        let (edges, faces) = (Disjoint::new(edges), Disjoint::new(faces));
        // Tasks: the centroid grid (the longer rebuild, first), the vertex grid, the chunks of body
        // edges, the chunks of nearest faces.
        let task = |t: usize| -> Result<()> {
            match t {
                0 => centroid_grid.get(build_centroid_grid).map(drop),
                1 => vertex_grid.get(build_vertex_grid).map(drop),
                _ if t < 2 + chunks => {
                    let r = split(n, chunks, t - 2);
                    let grid = vertex_grid.get(build_vertex_grid)?;
                    // SAFETY: the chunks of `split` are disjoint.
                    let out = unsafe { edges.range(r.clone()) };
                    grid.nearest_within_hinted(
                        &points[r.clone()],
                        query.radius,
                        hint_range(query.vertex_hints, r),
                        out,
                    )?;
                    kept.fetch_add(mesh.keep_not_omitted(out), Ordering::Relaxed);
                    Ok(())
                }
                _ => {
                    let r = split(n, chunks, t - 2 - chunks);
                    let grid = centroid_grid.get(build_centroid_grid)?;
                    // SAFETY: the chunks of `split` are disjoint.
                    let out = unsafe { faces.range(r.clone()) };
                    grid.nearest_hinted(&points[r.clone()], hint_range(query.face_hints, r), out)
                }
            }
        };
        // The lowest failing task (the input was checked, so this only guards broken invariants).
        let failed = AtomicUsize::new(usize::MAX);
        exec.run(2 + 2 * chunks, &|t| {
            if task(t).is_err() {
                failed.fetch_min(t, Ordering::Relaxed);
            }
        });
        match failed.load(Ordering::Relaxed) {
            usize::MAX => Ok(kept.into_inner()),
            // Rerun on its own to return its error: a build's error is kept, a chunk repeats.
            t => task(t).map(|()| kept.into_inner()),
        }
    }

    /// Face centroids of the last update, metres.
    pub fn centroids(&self) -> &[[f32; 3]] {
        &self.centroids
    }
    /// Unit face normals of the last update.
    pub fn face_normals(&self) -> &[[f32; 3]] {
        &self.face_normals
    }
    /// Unit vertex normals of the last update.
    pub fn vertex_normals(&self) -> &[[f32; 3]] {
        &self.vertex_normals
    }
    /// The grid over the body vertices.
    pub fn vertex_grid(&self) -> &PointGrid {
        &self.vertex_grid
    }
    /// The grid over the face centroids.
    pub fn centroid_grid(&self) -> &PointGrid {
        &self.centroid_grid
    }

    /// Body edges (MODEL.md section 1): for every garment vertex (metres), its nearest body vertex
    /// if that is within `radius` (inclusive) and not `body_omitted`, else `None`. This is
    /// [`PointGrid::nearest_within`] followed by [`BodyMesh::keep_not_omitted`]. Returns the number
    /// of edges.
    ///
    /// # Errors
    /// As [`PointGrid::nearest_within`].
    pub fn body_edges(
        &self,
        mesh: &BodyMesh,
        garment: &[[f32; 3]],
        radius: f32,
        out: &mut [Option<Nearest>],
    ) -> Result<usize> {
        self.vertex_grid.nearest_within(garment, radius, out)?;
        Ok(mesh.keep_not_omitted(out))
    }

    /// As [`body_edges`](Self::body_edges), starting each search from a guessed body vertex
    /// (e.g. last frame's; `u32::MAX` for none), see [`PointGrid::nearest_within_hinted`]. Same
    /// result, usually faster.
    ///
    /// # Errors
    /// As [`PointGrid::nearest_within_on`] (nothing is written on error).
    pub fn body_edges_hinted(
        &self,
        mesh: &BodyMesh,
        garment: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<usize> {
        self.body_edges_on(&Serial, mesh, garment, radius, hints, out)
    }

    /// As [`body_edges_hinted`](Self::body_edges_hinted) (`hints` may be empty), with the
    /// garment vertices split into chunks run as tasks of `exec`, see
    /// [`PointGrid::nearest_within_on`]. Same result for any executor.
    ///
    /// # Errors
    /// As [`PointGrid::nearest_within_on`].
    pub fn body_edges_on(
        &self,
        exec: &dyn Executor,
        mesh: &BodyMesh,
        garment: &[[f32; 3]],
        radius: f32,
        hints: &[u32],
        out: &mut [Option<Nearest>],
    ) -> Result<usize> {
        self.vertex_grid.nearest_within_on(exec, garment, radius, hints, out)?;
        Ok(mesh.keep_not_omitted(out))
    }

    /// For every garment vertex (metres), the body face whose centroid is nearest (no radius), as
    /// used by the collision and friction terms.
    ///
    /// # Errors
    /// As [`PointGrid::nearest`].
    pub fn nearest_faces(&self, garment: &[[f32; 3]], out: &mut [Nearest]) -> Result<()> {
        self.centroid_grid.nearest(garment, out)
    }

    /// As [`nearest_faces`](Self::nearest_faces), starting each search from a guessed face (e.g.
    /// last frame's answer), see [`PointGrid::nearest_hinted`]. Same result, usually much faster.
    ///
    /// # Errors
    /// As [`PointGrid::nearest_on`] (nothing is written on error).
    pub fn nearest_faces_hinted(&self, garment: &[[f32; 3]], hints: &[u32], out: &mut [Nearest]) -> Result<()> {
        self.nearest_faces_on(&Serial, garment, hints, out)
    }

    /// As [`nearest_faces_hinted`](Self::nearest_faces_hinted) (`hints` may be empty), with the
    /// garment vertices split into chunks run as tasks of `exec`, see [`PointGrid::nearest_on`].
    /// Same result for any executor.
    ///
    /// # Errors
    /// As [`PointGrid::nearest_on`].
    pub fn nearest_faces_on(
        &self,
        exec: &dyn Executor,
        garment: &[[f32; 3]],
        hints: &[u32],
        out: &mut [Nearest],
    ) -> Result<()> {
        self.centroid_grid.nearest_on(exec, garment, hints, out)
    }
}
