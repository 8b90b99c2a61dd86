//! Per-frame triangle geometry into caller buffers (no allocation, no validation: the callers in
//! [`BodyMesh`](super::BodyMesh) check lengths). Faces must index into `positions` (a corner out
//! of range reads as the origin); `out` entries past the faces are left untouched.

use glam::Vec3;

/// Writes the centroid `(v0 + v1 + v2) / 3` of every face (metres).
pub fn face_centroids(faces: &[[u32; 3]], positions: &[[f32; 3]], out: &mut [[f32; 3]]) {
    for (f, o) in faces.iter().zip(out.iter_mut()) {
        let [a, b, c] = corners(f, positions);
        *o = ((a + b + c) / 3.0).to_array();
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
    f.map(|i| positions.get(i as usize).map_or(Vec3::ZERO, |p| Vec3::from_array(*p)))
}
