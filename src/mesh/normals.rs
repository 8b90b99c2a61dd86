//! Vertex normals (MODEL.md section 3), shared by garment and body.

use glam::Vec3;

/// Writes the unit vertex normal of every vertex into `out` (same length as `positions`).
///
/// For each face the three corner cross products `e0×e1 + e1×e2 + e2×e0` (with `e0 = v1-v0`,
/// `e1 = v2-v1`, `e2 = v0-v2`) are added to its vertices, then each sum is divided by
/// `max(|n|, 1e-12)`; a vertex in no face gets the zero vector. Face indices must be in range
/// (garments and bodies validate that at construction). Allocates nothing.
pub fn vertex_normals(faces: &[[u32; 3]], positions: &[[f32; 3]], out: &mut [[f32; 3]]) {
    debug_assert_eq!(positions.len(), out.len());
    out.iter_mut().for_each(|n| *n = [0.0; 3]);
    for f in faces {
        let [a, b, c] = f.map(|i| i as usize);
        let (Some(pa), Some(pb), Some(pc)) = (positions.get(a), positions.get(b), positions.get(c)) else {
            continue;
        };
        let (v0, v1, v2) = (Vec3::from_array(*pa), Vec3::from_array(*pb), Vec3::from_array(*pc));
        let (e0, e1, e2) = (v1 - v0, v2 - v1, v0 - v2);
        let n = e0.cross(e1) + e1.cross(e2) + e2.cross(e0);
        for i in [a, b, c] {
            if let Some(o) = out.get_mut(i) {
                *o = (Vec3::from_array(*o) + n).to_array();
            }
        }
    }
    for o in out.iter_mut() {
        let v = Vec3::from_array(*o);
        *o = (v / v.length().max(1e-12)).to_array();
    }
}
