//! Collision push-out: the start-up repair of garments that begin inside or too near the body,
//! each vertex moved as [`crate::physics::push_out`] moves it: on given nearest faces
//! ([`push_out`]) or on a body's vertices, nearest faces found here ([`push_out_of`]).

use crate::body::{BodyFrame, BodyMesh, Nearest};
use crate::error::{Error, Result};
use crate::math::{add3, Real};
use crate::physics::{check_len, push_out as vertex_push_out, FaceFrame};
use alloc::vec;
use alloc::vec::Vec;

/// Clearance a garment's initial state keeps from the body (MODEL.md section 7), m: the margin of
/// [`push_out_of`].
pub const INITIAL_CLEARANCE: f32 = 2e-3;

/// Moves every vertex closer than `eps` (m) to the plane of its nearest body face (index in
/// `nearest`, face data in `frame`) out along that face's normal to distance `eps`. Vertices
/// flagged in `pinned` (may be empty) stay. Returns how many vertices moved.
///
/// # Errors
/// [`Error::SizeMismatch`] for buffers of the wrong length; [`Error::IndexOutOfRange`] for a
/// nearest index past the body's faces.
pub fn push_out<T: Real>(
    x: &mut [[T; 3]],
    nearest: &[u32],
    frame: FaceFrame<'_, T>,
    eps: T,
    pinned: &[bool],
) -> Result<usize> {
    check_len("nearest body faces", nearest.len(), x.len())?;
    if !pinned.is_empty() {
        check_len("pinned flags", pinned.len(), x.len())?;
    }
    let nf = frame.centroids.len().min(frame.normals.len());
    let mut moved = 0;
    for (i, p) in x.iter_mut().enumerate() {
        let k = nearest[i] as usize;
        if k >= nf {
            return Err(Error::IndexOutOfRange { what: "nearest body face", at: i, index: k, len: nf });
        }
        if pinned.get(i).copied().unwrap_or(false) {
            continue;
        }
        let step = vertex_push_out(*p, k, frame, eps);
        if step != [T::ZERO; 3] {
            *p = add3(*p, step);
            moved += 1;
        }
    }
    Ok(moved)
}

/// Pushes the unpinned vertices of `x` at least [`INITIAL_CLEARANCE`] out of the body at
/// `body_pos`, along the normal of the face whose centroid is nearest: a garment's start-up
/// repair before its first step (the C ABI's `hood_garment_push_out`). Vertices flagged in
/// `pinned` (may be empty) stay. Returns how many vertices moved.
///
/// # Errors
/// Errors of the body queries ([`BodyFrame::update`], [`BodyFrame::nearest_faces`]) and of
/// [`push_out`].
pub fn push_out_of(body: &BodyMesh, body_pos: &[[f32; 3]], x: &mut [[f32; 3]], pinned: &[bool]) -> Result<usize> {
    let mut frame = BodyFrame::new(body)?;
    frame.update(body, body_pos)?;
    let mut near = vec![Nearest { index: 0, distance: 0.0 }; x.len()];
    frame.nearest_faces(x, &mut near)?;
    let idx: Vec<u32> = near.iter().map(|n| n.index).collect();
    let ff = FaceFrame { centroids: frame.centroids(), normals: frame.face_normals() };
    push_out(x, &idx, ff, INITIAL_CLEARANCE, pinned)
}
