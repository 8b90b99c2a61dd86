//! Brute-force geometry for tests: generalised winding numbers and mesh distances.

use crate::body::geometry::point_triangle_distance;
use glam::Vec3;

/// Generalised winding number of a closed (or nearly closed) triangle mesh around `p`: about 1
/// inside, 0 outside (van Oosterom-Strackee solid angles).
pub(crate) fn winding_number(p: Vec3, pos: &[[f32; 3]], faces: &[[u32; 3]]) -> f64 {
    let mut total = 0.0f64;
    for f in faces {
        let a = (Vec3::from(pos[f[0] as usize]) - p).as_dvec3();
        let b = (Vec3::from(pos[f[1] as usize]) - p).as_dvec3();
        let c = (Vec3::from(pos[f[2] as usize]) - p).as_dvec3();
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let det = a.dot(b.cross(c));
        let div = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
        total += 2.0 * libm::atan2(det, div);
    }
    total / (4.0 * core::f64::consts::PI)
}

/// Distance from `p` to the nearest triangle of the mesh.
pub(crate) fn mesh_distance(p: Vec3, pos: &[[f32; 3]], faces: &[[u32; 3]]) -> f32 {
    let mut best = f32::INFINITY;
    for f in faces {
        let a = Vec3::from(pos[f[0] as usize]);
        // Cheap rejection: a vertex farther than the best plus the longest plausible edge.
        if (a - p).length() > best + 0.1 {
            continue;
        }
        best = best.min(point_triangle_distance(p, a, Vec3::from(pos[f[1] as usize]), Vec3::from(pos[f[2] as usize])));
    }
    best
}
