//! Brute-force geometry for tests: generalised winding numbers and point-triangle distances.

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

/// Distance from `p` to triangle `abc`.
pub(crate) fn point_triangle_distance(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> f32 {
    // Ericson, Real-Time Collision Detection, 5.1.5.
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.length();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).length();
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (p - (a + ab * v + ac * w)).length()
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
