//! PC2 point caches, as Blender's Mesh Cache modifier and 3ds Max read them.
//!
//! Little-endian: the 12 bytes `POINTCACHE2\0`, `i32` version 1, `i32` point count, `f32` start
//! frame, `f32` sampling (frames between samples), `i32` sample count; then every sample's
//! points as `x y z` `f32`. [`write()`] starts at frame 0 with one sample per frame: at 30 Hz, as
//! the frames are simulated.

use super::{check_frames, stream_error, write_points};
use crate::error::Result;
use std::io::Write;
use std::vec::Vec;

/// Writes `frames` (metres, y up, 30 Hz; see [`crate::io::export`]) as a PC2 file: start frame
/// 0, sampling 1.
///
/// # Errors
/// Frames that cannot be written (no frames, frames of different lengths, a
/// non-finite coordinate); [`crate::Error::Io`] from `w`.
pub fn write<P: AsRef<[[f32; 3]]>>(mut w: impl Write, frames: &[P]) -> Result<()> {
    let n = check_frames(frames)?;
    let mut head = Vec::with_capacity(32);
    head.extend_from_slice(b"POINTCACHE2\0");
    head.extend_from_slice(&1i32.to_le_bytes());
    head.extend_from_slice(&(n as i32).to_le_bytes());
    head.extend_from_slice(&0.0f32.to_le_bytes());
    head.extend_from_slice(&1.0f32.to_le_bytes());
    head.extend_from_slice(&(frames.len() as i32).to_le_bytes());
    w.write_all(&head).map_err(stream_error)?;
    write_points(w, frames, f32::to_le_bytes)
}
