//! Whether a body mesh suits the model: its orientation (a mesh wound inside out, as a change
//! of handedness between engines gives, makes every body normal point inwards and the cloth
//! sinks into the body) and its resolution (the body edges of MODEL.md section 1 reach only the
//! body vertices within a fixed radius, so a body whose vertices lie farther apart than that
//! leaves cloth between them without a body edge, and unpinned cloth can fall through).

use super::BodyMesh;
use crate::error::Result;
use alloc::vec::Vec;

/// Orientation and resolution of a body mesh at one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodySurvey {
    /// Signed volume enclosed by the faces, m³ (divergence theorem about the vertex centroid):
    /// positive for faces counter-clockwise seen from outside, negative for a mesh inside out.
    /// Of an open mesh, an estimate.
    pub volume: f64,
    /// Median length of the face edges, m (each edge counted once per face that has it).
    pub median_edge: f32,
    /// Longest face edge, m.
    pub longest_edge: f32,
}

impl BodySurvey {
    /// Whether the faces are wound clockwise seen from outside (the signed volume is negative).
    pub fn inside_out(&self) -> bool {
        self.volume < 0.0
    }

    /// Whether the mesh is too coarse for body edges of `radius` metres: on a face of median edge
    /// `e`, the point farthest from the corners is `e / √3` from them (an equilateral face), so
    /// the typical face has points without a body vertex within `radius` once `e > √3 · radius`.
    pub fn too_coarse_for(&self, radius: f32) -> bool {
        self.median_edge > crate::math::sqrt_f32(3.0) * radius
    }
}

impl BodyMesh {
    /// The [`BodySurvey`] of this mesh at `positions` (metres). Allocates (one length per face
    /// edge); meant for setting up a scene, not for every frame.
    ///
    /// # Errors
    /// As [`BodyMesh::check_positions`].
    pub fn survey(&self, positions: &[[f32; 3]]) -> Result<BodySurvey> {
        self.check_positions(positions)?;
        let n = positions.len() as f64;
        let mut centre = [0.0f64; 3];
        for p in positions {
            for k in 0..3 {
                centre[k] += p[k] as f64 / n;
            }
        }
        let at = |i: u32| {
            let p = positions[i as usize];
            [p[0] as f64 - centre[0], p[1] as f64 - centre[1], p[2] as f64 - centre[2]]
        };
        let mut volume = 0.0f64;
        let mut edges = Vec::with_capacity(3 * self.faces().len());
        for f in self.faces() {
            let (a, b, c) = (at(f[0]), at(f[1]), at(f[2]));
            // a · (b × c) / 6: the signed volume of the tetrahedron with the centroid.
            let cross = [b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2], b[0] * c[1] - b[1] * c[0]];
            volume += (a[0] * cross[0] + a[1] * cross[1] + a[2] * cross[2]) / 6.0;
            for (p, q) in [(a, b), (b, c), (c, a)] {
                let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                edges.push(crate::math::sqrt_f64(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) as f32);
            }
        }
        let mid = edges.len() / 2;
        let (_, median, _) = edges.select_nth_unstable_by(mid, f32::total_cmp);
        let median_edge = *median;
        let longest_edge = edges.iter().copied().fold(0.0, f32::max);
        Ok(BodySurvey { volume, median_edge, longest_edge })
    }
}

#[cfg(test)]
mod tests {
    use crate::body::shapes;
    use crate::body::BodyMesh;

    #[test]
    fn a_sphere_is_outward_and_its_mirror_inside_out() {
        let (pos, faces) = shapes::ellipsoid(24, 48, [0.3; 3], [0.1, 1.0, -0.2]);
        let mesh = BodyMesh::new(pos.len(), &faces).unwrap();
        let s = mesh.survey(&pos).unwrap();
        let exact = 4.0 / 3.0 * core::f64::consts::PI * 0.027;
        assert!(s.volume > 0.9 * exact && s.volume < exact, "{s:?}");
        assert!(!s.inside_out());
        let flipped: alloc::vec::Vec<[u32; 3]> = faces.iter().map(|f| [f[0], f[2], f[1]]).collect();
        let inverted = BodyMesh::new(pos.len(), &flipped).unwrap().survey(&pos).unwrap();
        assert!(inverted.inside_out());
        assert!((inverted.volume + s.volume).abs() < 1e-9);
    }

    #[test]
    fn coarse_is_judged_by_the_median_edge_against_the_radius() {
        // About 13,000 vertices and 160, as a full body mesh and a crude proxy of one.
        let (fine, fine_faces) = shapes::ellipsoid(80, 160, [0.3; 3], [0.0; 3]);
        let (coarse, coarse_faces) = shapes::ellipsoid(9, 18, [0.3; 3], [0.0; 3]);
        let fine = BodyMesh::new(fine.len(), &fine_faces).unwrap().survey(&fine).unwrap();
        let coarse = BodyMesh::new(coarse.len(), &coarse_faces).unwrap().survey(&coarse).unwrap();
        assert!(coarse.median_edge > 4.0 * fine.median_edge, "{fine:?} {coarse:?}");
        assert!(!fine.too_coarse_for(0.03) && coarse.too_coarse_for(0.03), "{fine:?} {coarse:?}");
        assert!(coarse.longest_edge >= coarse.median_edge);
    }
}
