//! The garment: rest geometry, topology and everything derived from them once.
//!
//! A [`Garment`] is built from rest positions and triangles (quads and polygons are triangulated
//! by the readers), per-vertex [`Material`]s and a per-vertex pinned flag. Construction validates
//! the input and refuses bad meshes with an [`Error`] naming the offending index; the functions
//! of [`repair`] offer explicit fixes instead of silent ones.

mod material;
mod normals;
pub mod repair;
pub mod shapes;
pub mod topology;

pub use material::{ranges as material_ranges, Material};
pub use normals::vertex_normals;
pub use topology::{Hinge, Topology};

use crate::error::{Error, Result};
use crate::math::finite3;
use alloc::vec;
use alloc::vec::Vec;

/// Below this ratio `2·area / longest_edge²` a triangle counts as degenerate (zero area): its
/// height is a millionth of its longest edge, and its rest frame would be singular.
pub const DEGENERATE_RATIO: f64 = 1e-6;

/// The input of [`Garment::new`].
#[derive(Clone, Copy, Debug)]
pub struct GarmentDesc<'a> {
    /// Rest positions, metres.
    pub rest: &'a [[f32; 3]],
    /// Triangles, counter-clockwise seen from outside.
    pub faces: &'a [[u32; 3]],
    /// One material per vertex, or one for all (length 1), or none for [`Material::default`].
    pub materials: &'a [Material],
    /// Pinned flag per vertex, or empty for none pinned.
    pub pinned: &'a [bool],
}

impl<'a> GarmentDesc<'a> {
    /// Rest positions and faces with the default material and no pinned vertex.
    pub fn new(rest: &'a [[f32; 3]], faces: &'a [[u32; 3]]) -> Self {
        GarmentDesc { rest, faces, materials: &[], pinned: &[] }
    }

    /// With materials (one per vertex, or a single one for all).
    pub fn materials(mut self, materials: &'a [Material]) -> Self {
        self.materials = materials;
        self
    }

    /// With a pinned flag per vertex.
    pub fn pinned(mut self, pinned: &'a [bool]) -> Self {
        self.pinned = pinned;
        self
    }
}

/// A validated garment mesh with its derived rest quantities.
///
/// # Examples
///
/// ```
/// use hood::mesh::{Garment, GarmentDesc};
///
/// // Two triangles, metres, y up; a bad index is refused with an error, not a panic.
/// let rest = [[0.0, 1.0, 0.0], [0.1, 1.0, 0.0], [0.0, 1.0, 0.1], [0.1, 1.0, 0.1]];
/// let garment = Garment::new(GarmentDesc::new(&rest, &[[0, 2, 1], [1, 2, 3]]))?;
/// assert_eq!(garment.n_vertices(), 4);
/// assert!(Garment::new(GarmentDesc::new(&rest, &[[0, 2, 9]])).is_err());
/// # Ok::<(), hood::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Garment {
    rest: Vec<[f32; 3]>,
    faces: Vec<[u32; 3]>,
    materials: Vec<Material>,
    pinned: Vec<bool>,
    topo: Topology,
    dm_inv: Vec<[[f32; 2]; 2]>,
    face_area: Vec<f32>,
    vertex_mass: Vec<f32>,
}

impl Garment {
    /// Validates `desc` and derives topology, rest frames, areas and masses.
    ///
    /// # Errors
    /// [`Error::CapacityExceeded`] beyond [`crate::limits::MAX_VERTICES`] or
    /// [`crate::limits::MAX_FACES`] (checked before anything is allocated); [`Error::Empty`]
    /// without vertices or faces; [`Error::NonFinite`] for a NaN/Inf rest coordinate; [`Error::IndexOutOfRange`] for a face naming a missing vertex;
    /// [`Error::RepeatedVertex`]; [`Error::DegenerateFace`] (see [`DEGENERATE_RATIO`]);
    /// [`Error::UnusedVertex`]; [`Error::SizeMismatch`] for materials or pinned flags of the
    /// wrong length; [`Error::OutOfRange`] for a non-positive or non-finite material, or a vertex
    /// mass out of `f32`'s range; [`Error::DegenerateFace`] also for a face whose rest frame or
    /// area is out of `f32`'s range (edges of 1e-39 m).
    pub fn new(desc: GarmentDesc<'_>) -> Result<Garment> {
        let n = desc.rest.len();
        validate(desc.rest, desc.faces)?;
        let materials = match desc.materials.len() {
            0 => vec![Material::default(); n],
            1 => vec![desc.materials[0]; n],
            m if m == n => desc.materials.to_vec(),
            m => return Err(Error::SizeMismatch { what: "materials", expected: n, got: m }),
        };
        if let Some(i) = materials.iter().position(|m| !m.is_valid()) {
            return Err(Error::OutOfRange { what: "material", index: i });
        }
        let pinned = match desc.pinned.len() {
            0 => vec![false; n],
            m if m == n => desc.pinned.to_vec(),
            m => return Err(Error::SizeMismatch { what: "pinned flags", expected: n, got: m }),
        };
        let topo = topology::build(n, desc.faces);
        let mut dm_inv = Vec::with_capacity(desc.faces.len());
        let mut face_area = Vec::with_capacity(desc.faces.len());
        for (i, f) in desc.faces.iter().enumerate() {
            let (d, a) = rest_frame(desc.rest, f);
            // Shape-valid but out of f32's range (edges of 1e-39 m): every step would refuse it.
            if !(d.iter().flatten().all(|v| v.is_finite()) && (a as f32) > 0.0 && (a as f32).is_finite()) {
                return Err(Error::DegenerateFace { face: i });
            }
            dm_inv.push(d);
            face_area.push(a as f32);
        }
        // Mass: density x (sum of incident rest areas) / 3, accumulated in f64 as the reference.
        let mut area_sum = vec![0.0f64; n];
        for (f, &a) in desc.faces.iter().zip(&face_area) {
            for &v in f {
                area_sum[v as usize] += a as f64 / 3.0;
            }
        }
        let vertex_mass: Vec<f32> =
            area_sum.iter().zip(&materials).map(|(a, m)| (a * m.density as f64) as f32).collect();
        // A huge garment of dense cloth (coordinates near 1e30, a density near f32::MAX).
        if let Some(i) = vertex_mass.iter().position(|m| !(m.is_finite() && *m > 0.0)) {
            return Err(Error::OutOfRange { what: "vertex mass (area times density out of f32's range)", index: i });
        }
        Ok(Garment {
            rest: desc.rest.to_vec(),
            faces: desc.faces.to_vec(),
            materials,
            pinned,
            topo,
            dm_inv,
            face_area,
            vertex_mass,
        })
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.rest.len()
    }
    /// Rest positions, metres.
    pub fn rest(&self) -> &[[f32; 3]] {
        &self.rest
    }
    /// Triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
    /// Per-vertex materials.
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }
    /// Per-vertex pinned flags.
    pub fn pinned(&self) -> &[bool] {
        &self.pinned
    }
    /// Indices of the pinned vertices, ascending.
    pub fn pinned_indices(&self) -> Vec<u32> {
        (0..self.rest.len() as u32).filter(|&i| self.pinned[i as usize]).collect()
    }
    /// Sets the pinned flags (one per vertex).
    pub fn set_pinned(&mut self, pinned: &[bool]) -> Result<()> {
        if pinned.len() != self.rest.len() {
            return Err(Error::SizeMismatch { what: "pinned flags", expected: self.rest.len(), got: pinned.len() });
        }
        self.pinned.copy_from_slice(pinned);
        Ok(())
    }
    /// All derived connectivity.
    pub fn topology(&self) -> &Topology {
        &self.topo
    }
    /// Unique undirected edges `(a, b)`, `a < b`.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.topo.edges
    }
    /// Directed edges `(source, target)` sorted by target; see [`Topology::in_offsets`].
    pub fn directed_edges(&self) -> &[[u32; 2]] {
        &self.topo.directed
    }
    /// Interior edges with their two faces.
    pub fn hinges(&self) -> &[Hinge] {
        &self.topo.hinges
    }
    /// Boundary loops (vertex sequences).
    pub fn boundary_loops(&self) -> &[Vec<u32>] {
        &self.topo.boundary_loops
    }
    /// Connected component of each vertex.
    pub fn component_of(&self) -> &[u32] {
        &self.topo.component
    }
    /// Number of connected components.
    pub fn n_components(&self) -> usize {
        self.topo.n_components as usize
    }
    /// Per-face inverse rest shape matrix `Dm^-1` (row-major 2x2, 1/m), see MODEL.md section 6.
    pub fn dm_inv(&self) -> &[[[f32; 2]; 2]] {
        &self.dm_inv
    }
    /// Per-face rest area, m^2.
    pub fn face_area(&self) -> &[f32] {
        &self.face_area
    }
    /// Per-vertex mass, kg.
    pub fn vertex_mass(&self) -> &[f32] {
        &self.vertex_mass
    }
    /// Total rest area, m^2.
    pub fn total_area(&self) -> f64 {
        self.face_area.iter().map(|&a| a as f64).sum()
    }
    /// Unit vertex normals at `positions` (one per vertex) into `out`; see [`vertex_normals`].
    pub fn normals_into(&self, positions: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        if positions.len() != self.rest.len() || out.len() != self.rest.len() {
            return Err(Error::SizeMismatch {
                what: "garment positions/normals",
                expected: self.rest.len(),
                got: positions.len().min(out.len()),
            });
        }
        vertex_normals(&self.faces, positions, out);
        Ok(())
    }
}

/// Checks positions and faces; the error names the first offending index.
///
/// # Errors
/// As [`Garment::new`], but for materials and pinned flags.
pub fn validate(rest: &[[f32; 3]], faces: &[[u32; 3]]) -> Result<()> {
    crate::limits::garment(rest.len(), faces.len())?;
    if rest.is_empty() {
        return Err(Error::Empty { what: "garment vertices" });
    }
    if faces.is_empty() {
        return Err(Error::Empty { what: "garment faces" });
    }
    if let Some(i) = rest.iter().position(|p| !finite3(*p)) {
        return Err(Error::NonFinite { what: "rest position", index: i });
    }
    let n = rest.len();
    let mut used = vec![false; n];
    for (fi, f) in faces.iter().enumerate() {
        for &v in f {
            if v as usize >= n {
                return Err(Error::IndexOutOfRange { what: "face", at: fi, index: v as usize, len: n });
            }
        }
        if f[0] == f[1] || f[0] == f[2] {
            return Err(Error::RepeatedVertex { face: fi, vertex: f[0] as usize });
        }
        if f[1] == f[2] {
            return Err(Error::RepeatedVertex { face: fi, vertex: f[1] as usize });
        }
        if is_degenerate(rest, f) {
            return Err(Error::DegenerateFace { face: fi });
        }
        for &v in f {
            used[v as usize] = true;
        }
    }
    if let Some(v) = used.iter().position(|u| !u) {
        return Err(Error::UnusedVertex { vertex: v });
    }
    Ok(())
}

fn corner(rest: &[[f32; 3]], i: u32) -> [f64; 3] {
    rest[i as usize].map(|c| c as f64)
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross_norm(a: [f64; 3], b: [f64; 3]) -> f64 {
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    crate::math::sqrt_f64(dot(c, c))
}

/// True when the triangle's height is below [`DEGENERATE_RATIO`] of its longest edge.
pub fn is_degenerate(rest: &[[f32; 3]], f: &[u32; 3]) -> bool {
    let (x0, x1, x2) = (corner(rest, f[0]), corner(rest, f[1]), corner(rest, f[2]));
    let (e0, e1, e2) = (sub(x1, x0), sub(x2, x0), sub(x2, x1));
    let longest2 = dot(e0, e0).max(dot(e1, e1)).max(dot(e2, e2));
    let twice_area = cross_norm(e0, e1);
    longest2 == 0.0 || twice_area.is_nan() || twice_area <= DEGENERATE_RATIO * longest2
}

/// Inverse rest frame `Dm^-1` and rest area of one triangle (MODEL.md section 6), in f64 then
/// rounded to f32 like the reference.
fn rest_frame(rest: &[[f32; 3]], f: &[u32; 3]) -> ([[f32; 2]; 2], f64) {
    let (x0, x1, x2) = (corner(rest, f[0]), corner(rest, f[1]), corner(rest, f[2]));
    let (e0, e1) = (sub(x0, x2), sub(x1, x2));
    let l0 = crate::math::sqrt_f64(dot(e0, e0));
    let b0 = e0.map(|c| c / l0);
    let p = dot(e1, b0);
    let perp = [e1[0] - p * b0[0], e1[1] - p * b0[1], e1[2] - p * b0[2]];
    let lp = crate::math::sqrt_f64(dot(perp, perp));
    let b1 = perp.map(|c| c / lp);
    // Dm = [[E0.b0, E1.b0], [E0.b1, E1.b1]]
    let (a, b, c, d) = (l0, p, dot(e0, b1), dot(e1, b1));
    let det = a * d - b * c;
    let inv = [[(d / det) as f32, (-b / det) as f32], [(-c / det) as f32, (a / det) as f32]];
    (inv, 0.5 * cross_norm(e0, e1))
}

#[cfg(test)]
mod tests;
