//! Collision penalty against the body (MODEL.md section 6) and the body-face data it reads.

use super::check_len;
use crate::error::{Error, Result};
use crate::math::{add3, cross3, dot3, neg3, norm3, scale3, sub3, v3_from_f32, Real};
use alloc::vec::Vec;

/// Body faces at one frame: centroid and unit normal of every face (parallel slices).
#[derive(Clone, Copy, Debug)]
pub struct FaceFrame<'a, T> {
    /// Face centroids, m.
    pub centroids: &'a [[T; 3]],
    /// Unit face normals (outward for counter-clockwise faces).
    pub normals: &'a [[T; 3]],
}

/// Writes the centroid `(a + b + c) / 3` and unit normal `(b - a) × (c - a) / |..|` of every
/// body face at vertex positions `pos` (m). A zero-area face gets a zero normal. Face indices
/// must be in range and the outputs must have one entry per face (checked).
///
/// # Errors
/// [`Error::SizeMismatch`] for outputs of the wrong length; [`Error::IndexOutOfRange`] for a
/// face naming a missing vertex.
pub fn face_frames<T: Real>(
    pos: &[[f32; 3]],
    faces: &[[u32; 3]],
    centroids: &mut [[T; 3]],
    normals: &mut [[T; 3]],
) -> Result<()> {
    check_len("body face centroids", centroids.len(), faces.len())?;
    check_len("body face normals", normals.len(), faces.len())?;
    let third = T::ONE / T::from_f64(3.0);
    for (fi, f) in faces.iter().enumerate() {
        let mut v = [[T::ZERO; 3]; 3];
        for k in 0..3 {
            let i = f[k] as usize;
            let p = pos.get(i).ok_or(Error::IndexOutOfRange { what: "body face", at: fi, index: i, len: pos.len() })?;
            v[k] = v3_from_f32(*p);
        }
        centroids[fi] = scale3(add3(add3(v[0], v[1]), v[2]), third);
        let n = cross3(sub3(v[1], v[0]), sub3(v[2], v[0]));
        let len = norm3(n);
        normals[fi] = if len > T::ZERO { scale3(n, T::ONE / len) } else { [T::ZERO; 3] };
    }
    Ok(())
}

/// Nearest body-face centroid of a point: the query the collision and friction terms need. The
/// body module's grid index implements it; [`BruteForceCentroids`] is the exact fallback.
pub trait CentroidQuery {
    /// Index of the centroid nearest to `p` (m), ties to the lowest index.
    fn nearest(&self, p: [f32; 3]) -> u32;

    /// [`CentroidQuery::nearest`] for every point of `points` into `out` (same length).
    fn nearest_into(&self, points: &[[f32; 3]], out: &mut [u32]) {
        for (p, o) in points.iter().zip(out.iter_mut()) {
            *o = self.nearest(*p);
        }
    }

    /// As [`CentroidQuery::nearest`], the search starting from `hint` (a guess such as the last
    /// answer for a point that moved a little): the same answer, usually faster. The default
    /// ignores the hint.
    fn nearest_hinted(&self, p: [f32; 3], hint: u32) -> u32 {
        let _ = hint;
        self.nearest(p)
    }

    /// [`CentroidQuery::nearest_hinted`] for every point of `points` into `out`, with `hints[i]`
    /// for point `i` (all three the same length).
    fn nearest_into_hinted(&self, points: &[[f32; 3]], hints: &[u32], out: &mut [u32]) {
        for ((p, &h), o) in points.iter().zip(hints).zip(out.iter_mut()) {
            *o = self.nearest_hinted(*p, h);
        }
    }
}

/// The body module's grid over face centroids (rebuilt by the caller for the frame).
impl CentroidQuery for crate::body::PointGrid {
    fn nearest(&self, p: [f32; 3]) -> u32 {
        // Only an empty grid has no answer; 0 is then as good as any (the terms check indices).
        self.nearest_one(p).map_or(0, |n| n.index)
    }

    fn nearest_hinted(&self, p: [f32; 3], hint: u32) -> u32 {
        self.nearest_one_hinted(p, hint).map_or(0, |n| n.index)
    }
}

/// A body frame answers through its centroid grid.
impl CentroidQuery for crate::body::BodyFrame {
    fn nearest(&self, p: [f32; 3]) -> u32 {
        CentroidQuery::nearest(self.centroid_grid(), p)
    }

    fn nearest_hinted(&self, p: [f32; 3], hint: u32) -> u32 {
        CentroidQuery::nearest_hinted(self.centroid_grid(), p, hint)
    }
}

/// Exact nearest centroid by scanning them all (O(faces) per query): for tests and small bodies.
#[derive(Clone, Debug, Default)]
pub struct BruteForceCentroids {
    /// The centroids searched, m.
    pub centroids: Vec<[f32; 3]>,
}

impl CentroidQuery for BruteForceCentroids {
    fn nearest(&self, p: [f32; 3]) -> u32 {
        let mut best = (f32::INFINITY, 0u32);
        for (i, c) in self.centroids.iter().enumerate() {
            let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            if d2 < best.0 {
                best = (d2, i as u32);
            }
        }
        best.1
    }
}

/// Collision penalty: for every garment vertex `i` with body face `k = nearest[i]` (the face
/// whose centroid is nearest to the vertex at the **current** frame), `d = (x_i - c'_k)·n'_k`
/// with the centroid and unit normal of that face at the **next** frame (`next`), and
/// `E = weight × sum max(eps - d, 0)³` (eps in m). When `grad` is given, `dE/dx` is **added**.
///
/// # Errors
/// [`Error::SizeMismatch`] for buffers of the wrong length; [`Error::IndexOutOfRange`] for a
/// nearest index past the body's faces.
pub fn collision<T: Real>(
    x: &[[T; 3]],
    nearest: &[u32],
    next: FaceFrame<'_, T>,
    eps: T,
    weight: T,
    mut grad: Option<&mut [[T; 3]]>,
) -> Result<T> {
    let n = x.len();
    check_len("nearest body faces", nearest.len(), n)?;
    check_len("body face normals", next.normals.len(), next.centroids.len())?;
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let nf = next.centroids.len();
    let mut energy = T::ZERO;
    for i in 0..n {
        let k = nearest[i] as usize;
        if k >= nf {
            return Err(Error::IndexOutOfRange { what: "nearest body face", at: i, index: k, len: nf });
        }
        let (e, gi) = vertex_collision(x[i], k, next, eps, weight);
        energy += e;
        if let Some(g) = grad.as_deref_mut() {
            g[i] = add3(g[i], gi);
        }
    }
    Ok(energy * weight)
}

/// Vertex collision penalty against face `k` of `next` before the weight (`max(eps - d, 0)³`,
/// m³) and its weighted gradient: the one place of the term's per-vertex math ([`collision`]
/// multiplies the sum by the weight). `k` must be in range.
#[inline(always)]
pub(super) fn vertex_collision<T: Real>(x: [T; 3], k: usize, next: FaceFrame<'_, T>, eps: T, weight: T) -> (T, [T; 3]) {
    let nrm = next.normals[k];
    let d = dot3(sub3(x, next.centroids[k]), nrm);
    let pen = eps - d;
    if pen > T::ZERO {
        (pen * pen * pen, neg3(scale3(nrm, weight * T::from_f64(3.0) * pen * pen)))
    } else {
        (T::ZERO, [T::ZERO; 3])
    }
}

/// Signed distance (m) of every vertex to the plane of its nearest face at the next frame, as
/// the collision term measures it, into `out`.
pub fn plane_distances<T: Real>(x: &[[T; 3]], nearest: &[u32], next: FaceFrame<'_, T>, out: &mut [T]) {
    for ((p, &k), o) in x.iter().zip(nearest).zip(out.iter_mut()) {
        *o = plane_distance(*p, k as usize, next);
    }
}

/// Signed distance (m) of `x` to the plane of face `face` of `frame`: positive on the side its
/// normal points to (outside the body).
#[inline]
pub fn plane_distance<T: Real>(x: [T; 3], face: usize, frame: FaceFrame<'_, T>) -> T {
    dot3(sub3(x, frame.centroids[face]), frame.normals[face])
}

/// The smallest move that puts `x` at least `margin` (m) in front of the plane of face `face`
/// (along its normal; zero when it already is): the push-out of collision projection.
#[inline]
pub fn push_out<T: Real>(x: [T; 3], face: usize, frame: FaceFrame<'_, T>, margin: T) -> [T; 3] {
    let d = plane_distance(x, face, frame);
    if d < margin {
        scale3(frame.normals[face], margin - d)
    } else {
        [T::ZERO; 3]
    }
}
