//! Per-garment constants of the energy terms, precomputed once in the working precision.

use super::THICKNESS;
use crate::error::{Error, Result};
use crate::math::{norm3, sub3, v3_from_f32, Real};
use crate::mesh::{Garment, Material};
use alloc::vec::Vec;

/// One bending hinge: the shared edge, the two opposite vertices, and how the two triangles
/// traverse the edge (which fixes the sign convention of their normals).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BendHinge {
    /// The shared edge `(v0, v1)`; `e = x[v1] - x[v0]`.
    pub edge: [u32; 2],
    /// The vertex of triangle A and of triangle B opposite the edge.
    pub opposite: [u32; 2],
    /// True when A and B traverse the edge in opposite directions (consistently oriented).
    pub consistent: bool,
}

/// True when triangle `f` runs from `a` to `b` along its edge `(a, b)`.
fn traverses(f: [u32; 3], a: u32, b: u32) -> bool {
    (0..3).any(|k| f[k] == a && f[(k + 1) % 3] == b)
}

/// Everything the terms need from the garment, in precision `T`: faces with their rest frames
/// and material weights, hinges with their bending weights, vertex masses, edges with rest
/// lengths.
#[derive(Clone, Debug)]
pub struct Cloth<T: Real> {
    pub(crate) faces: Vec<[u32; 3]>,
    /// Row-major `Dm^-1` per face, 1/m.
    pub(crate) dm_inv: Vec<[T; 4]>,
    /// `area × thickness × mu` per face.
    pub(crate) stretch_mu: Vec<T>,
    /// `area × thickness × lambda / 2` per face.
    pub(crate) stretch_lambda: Vec<T>,
    pub(crate) hinges: Vec<BendHinge>,
    /// `k_bend / (4 (area_A + area_B)) / 2` per hinge.
    pub(crate) bend_coef: Vec<T>,
    pub(crate) mass: Vec<T>,
    pub(crate) edges: Vec<[u32; 2]>,
    pub(crate) rest_len: Vec<T>,
}

impl<T: Real> Cloth<T> {
    /// The garment's own rest frames (`Garment::dm_inv`, `Garment::face_area`).
    pub fn new(garment: &Garment) -> Cloth<T> {
        let dm: Vec<[T; 4]> =
            garment.dm_inv().iter().map(|d| [d[0][0], d[0][1], d[1][0], d[1][1]].map(T::from_f32)).collect();
        let area: Vec<T> = garment.face_area().iter().map(|&a| T::from_f32(a)).collect();
        Self::build(garment, dm, &area)
    }

    /// Rest frames from separate 2D rest triangles (for example the UV layout, in metres), one
    /// point per garment vertex: `Dm = [u0 - u2, u1 - u2]`, stretching area `|det Dm| / 2`.
    /// Bending weights and masses still use the garment's 3D rest areas.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `rest_2d` does not have one point per vertex;
    /// [`Error::NonFinite`] for a NaN point; [`Error::DegenerateFace`] for a zero-area 2D triangle.
    pub fn with_rest_2d(garment: &Garment, rest_2d: &[[f32; 2]]) -> Result<Cloth<T>> {
        super::check_len("2D rest positions", rest_2d.len(), garment.n_vertices())?;
        if let Some(i) = rest_2d.iter().position(|p| !(p[0].is_finite() && p[1].is_finite())) {
            return Err(Error::NonFinite { what: "2D rest position", index: i });
        }
        let mut dm = Vec::with_capacity(garment.faces().len());
        let mut area = Vec::with_capacity(garment.faces().len());
        for (fi, f) in garment.faces().iter().enumerate() {
            let [u0, u1, u2] = f.map(|i| rest_2d[i as usize].map(|c| c as f64));
            let (a, b, c, d) = (u0[0] - u2[0], u1[0] - u2[0], u0[1] - u2[1], u1[1] - u2[1]);
            let det = a * d - b * c;
            let scale = (a * a + c * c).max(b * b + d * d);
            let nondegenerate = det.abs() > crate::mesh::DEGENERATE_RATIO * scale;
            if !nondegenerate {
                return Err(Error::DegenerateFace { face: fi });
            }
            dm.push([d / det, -b / det, -c / det, a / det].map(T::from_f64));
            area.push(T::from_f64(det.abs() / 2.0));
        }
        let mut cloth = Self::build(garment, dm, &area);
        // Bending keeps the 3D rest areas.
        let area3: Vec<T> = garment.face_area().iter().map(|&a| T::from_f32(a)).collect();
        cloth.bend_coef = bend_coefs(garment, &area3);
        Ok(cloth)
    }

    fn build(garment: &Garment, dm_inv: Vec<[T; 4]>, area: &[T]) -> Cloth<T> {
        let mats = garment.materials();
        let th = T::from_f64(THICKNESS);
        let half = T::from_f64(0.5);
        let mut stretch_mu = Vec::with_capacity(area.len());
        let mut stretch_lambda = Vec::with_capacity(area.len());
        for (f, &a) in garment.faces().iter().zip(area) {
            let m = Material::mean::<T>(&f.map(|i| mats[i as usize]));
            stretch_mu.push(a * th * m[1]);
            stretch_lambda.push(a * th * m[2] * half);
        }
        let faces = garment.faces();
        let hinges = garment
            .hinges()
            .iter()
            .map(|h| {
                let [fa, fb] = h.faces.map(|f| faces[f as usize]);
                let [v0, v1] = h.edge;
                BendHinge {
                    edge: h.edge,
                    opposite: h.opposite,
                    consistent: traverses(fa, v0, v1) != traverses(fb, v0, v1),
                }
            })
            .collect();
        let rest = garment.rest();
        let rest_len = garment
            .edges()
            .iter()
            .map(|e| norm3(sub3(v3_from_f32::<T>(rest[e[1] as usize]), v3_from_f32(rest[e[0] as usize]))))
            .collect();
        Cloth {
            faces: faces.to_vec(),
            dm_inv,
            stretch_mu,
            stretch_lambda,
            hinges,
            bend_coef: bend_coefs(garment, area),
            mass: garment.vertex_mass().iter().map(|&m| T::from_f32(m)).collect(),
            edges: garment.edges().to_vec(),
            rest_len,
        }
    }

    /// Adds to `out` (one entry per vertex, N/m) an estimate of the diagonal of the stretching
    /// energy's Hessian near rest: over the incident triangles, `area × thickness × (2 mu + lambda)
    /// × |∇φ_i|²`, with `∇φ_i` the rest-frame gradient of the vertex's linear basis function (a row
    /// of `Dm⁻¹`, or minus their sum for the third corner). Used to precondition solvers.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` does not have one entry per vertex.
    pub fn stretch_stiffness_into(&self, out: &mut [T]) -> Result<()> {
        super::check_len("stiffness diagonal", out.len(), self.n_vertices())?;
        let two = T::from_f64(2.0);
        for (fi, f) in self.faces.iter().enumerate() {
            let [a, b, c, d] = self.dm_inv[fi];
            let k = two * (self.stretch_mu[fi] + self.stretch_lambda[fi]);
            let (s0, s1) = (a + c, b + d);
            let w = [a * a + b * b, c * c + d * d, s0 * s0 + s1 * s1];
            for (corner, &v) in f.iter().enumerate() {
                out[v as usize] += k * w[corner];
            }
        }
        Ok(())
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.mass.len()
    }
    /// Triangles.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
    /// Row-major inverse rest frames `Dm^-1`, 1/m.
    pub fn dm_inv(&self) -> &[[T; 4]] {
        &self.dm_inv
    }
    /// Bending hinges.
    pub fn hinges(&self) -> &[BendHinge] {
        &self.hinges
    }
    /// Vertex masses, kg.
    pub fn mass(&self) -> &[T] {
        &self.mass
    }
    /// Unique edges `(a, b)`, `a < b`.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    /// Rest length of every edge, metres.
    pub fn rest_len(&self) -> &[T] {
        &self.rest_len
    }
}

/// `k_bend / (4 (area_A + area_B)) / 2` per hinge, `k_bend` the mean of the edge's two vertices.
fn bend_coefs<T: Real>(garment: &Garment, area: &[T]) -> Vec<T> {
    let mats = garment.materials();
    let eighth = T::from_f64(0.125);
    garment
        .hinges()
        .iter()
        .map(|h| {
            let k = (T::from_f32(mats[h.edge[0] as usize].bending) + T::from_f32(mats[h.edge[1] as usize].bending))
                * T::from_f64(0.5);
            k * eighth / (area[h.faces[0] as usize] + area[h.faces[1] as usize])
        })
        .collect()
}
