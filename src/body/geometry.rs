//! Per-frame triangle geometry into caller buffers (no allocation, no validation: the callers in
//! [`BodyMesh`](super::BodyMesh) check lengths). Faces must index into `positions` (a corner out
//! of range reads as the origin); `out` entries past the faces are left untouched.

use glam::{Vec3, Vec3A};

/// Writes the centroid `(v0 + v1 + v2) / 3` of every face (metres).
pub fn face_centroids(faces: &[[u32; 3]], positions: &[[f32; 3]], out: &mut [[f32; 3]]) {
    for (f, o) in faces.iter().zip(out.iter_mut()) {
        // Four-lane vectors: one division instruction per face (the same correctly rounded
        // quotients as three scalar ones). Corners read one by one: building an array of them
        // first measured twice as slow (its stores stall the vector loads).
        let corner = |k: usize| Vec3A::from_array(positions.get(f[k] as usize).copied().unwrap_or([0.0; 3]));
        *o = ((corner(0) + corner(1) + corner(2)) / 3.0).to_array();
    }
}

/// Writes the unit normal `(v1 - v0) × (v2 - v0) / max(|·|, 1e-12)` of every face: outward for
/// counter-clockwise faces, the zero vector for a degenerate face.
pub fn face_normals(faces: &[[u32; 3]], positions: &[[f32; 3]], out: &mut [[f32; 3]]) {
    for (f, o) in faces.iter().zip(out.iter_mut()) {
        let [a, b, c] = corners(f, positions);
        let n = (b - a).cross(c - a);
        *o = (n / n.length().max(1e-12)).to_array();
    }
}

#[inline(always)]
fn corners(f: &[u32; 3], positions: &[[f32; 3]]) -> [Vec3; 3] {
    // Written out rather than `f.map(..)`, which is not inlined here (the array it returns goes
    // through the stack).
    let corner = |k: usize| positions.get(f[k] as usize).map_or(Vec3::ZERO, |p| Vec3::from_array(*p));
    [corner(0), corner(1), corner(2)]
}
