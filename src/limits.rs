//! Bounds on what `hood` accepts, checked before anything is allocated for an input, so that a
//! garment, body or model file of absurd size is refused with an [`Error::CapacityExceeded`]
//! (C: `HOOD_ERR_CAPACITY_EXCEEDED`) instead of exhausting memory.
//!
//! The bounds sit far above real use: the largest garment of the tests has about 12,000
//! vertices, a MakeHuman body about 20,000, and the shipped models are 2 MB (compact) and 8 MB
//! (medium).
//!
//! ```
//! use hood::body::BodyMesh;
//! use hood::Error;
//! // A body declaring 10^8 vertices is refused before its flags are allocated.
//! let e = BodyMesh::new(100_000_000, &[[0, 1, 2]]).unwrap_err();
//! assert!(matches!(e, Error::CapacityExceeded { what: "body vertices", .. }));
//! ```

use crate::error::{Error, Result};

/// Most vertices of one garment, and of one body: 2^24 (16,777,216).
pub const MAX_VERTICES: usize = 1 << 24;

/// Most triangles of one garment, and of one body: 2^25 (a closed mesh has about twice as many
/// triangles as vertices).
pub const MAX_FACES: usize = 1 << 25;

/// Most joint samples (frames times joints) of one motion clip, read or resampled, 2^24 (470 MB
/// of rotations and translations): a 100-joint skeleton over 167,000 frames (90 minutes at
/// 30 Hz).
pub const MAX_MOTION_SAMPLES: usize = 1 << 24;

/// Most bytes of a model: the file itself, and the weights its shape needs (f32 and bf16 copies
/// of every parameter), 1 GiB. A file whose spec would need more is refused on load, before its
/// layers are viewed.
pub const MAX_MODEL_BYTES: usize = 1 << 30;

/// Most bytes of the scratch a sim sizes for its model and garment (latents of every vertex and
/// edge at the model's width), 16 GiB: a wide model on a huge garment is refused when the sim is
/// created instead of failing to allocate.
pub const MAX_WORKSPACE_BYTES: u64 = 1 << 34;

/// `Ok` when `n <= max`, else [`Error::CapacityExceeded`] naming `what`.
///
/// # Errors
/// [`Error::CapacityExceeded`] with `capacity: max` and `needed: n`.
pub fn within(what: &'static str, n: usize, max: usize) -> Result<()> {
    if n <= max {
        Ok(())
    } else {
        Err(Error::CapacityExceeded { what, capacity: max, needed: n })
    }
}

/// Checks a garment's vertex and face counts against [`MAX_VERTICES`] and [`MAX_FACES`].
///
/// # Errors
/// [`Error::CapacityExceeded`] (`what`: "garment vertices" or "garment faces").
pub fn garment(n_vertices: usize, n_faces: usize) -> Result<()> {
    within("garment vertices", n_vertices, MAX_VERTICES)?;
    within("garment faces", n_faces, MAX_FACES)
}

/// Checks a body's vertex and face counts against [`MAX_VERTICES`] and [`MAX_FACES`].
///
/// # Errors
/// [`Error::CapacityExceeded`] (`what`: "body vertices" or "body faces").
pub fn body(n_vertices: usize, n_faces: usize) -> Result<()> {
    within("body vertices", n_vertices, MAX_VERTICES)?;
    within("body faces", n_faces, MAX_FACES)
}

/// The threads this machine runs at once (1 when the system cannot tell).
#[cfg(feature = "std")]
pub fn available_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// A thread count for a sim's pool: `threads` (0 counts as 1), at most [`available_threads`].
/// More threads than cores only make the step's workers wait for each other.
#[cfg(feature = "std")]
pub fn cap_threads(threads: usize) -> usize {
    threads.clamp(1, available_threads().max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_at_the_limit_pass_and_one_more_is_refused() {
        assert!(garment(MAX_VERTICES, MAX_FACES).is_ok());
        let e = garment(MAX_VERTICES + 1, 1).unwrap_err();
        assert_eq!(
            e,
            Error::CapacityExceeded { what: "garment vertices", capacity: MAX_VERTICES, needed: MAX_VERTICES + 1 }
        );
        assert!(matches!(body(1, MAX_FACES + 1), Err(Error::CapacityExceeded { what: "body faces", .. })));
        assert_eq!(e.code(), 9);
    }

    #[cfg(feature = "std")]
    #[test]
    fn threads_are_capped_at_the_cores() {
        let cores = available_threads();
        assert_eq!(cap_threads(0), 1);
        assert_eq!(cap_threads(1), 1);
        assert_eq!(cap_threads(cores + 5), cores);
        assert_eq!(cap_threads(usize::MAX), cores);
    }
}
