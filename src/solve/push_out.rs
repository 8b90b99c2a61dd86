//! Collision push-out: the start-up repair of garments that begin inside or too near the body,
//! each vertex moved as [`crate::physics::push_out`] moves it.

use crate::error::{Error, Result};
use crate::math::{add3, Real};
use crate::physics::{check_len, push_out as vertex_push_out, FaceFrame};

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
