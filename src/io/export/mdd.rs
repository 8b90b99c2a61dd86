//! MDD point caches (LightWave's Motion Designer format; Blender's Mesh Cache modifier, Maya,
//! Houdini and three.js read them).
//!
//! Big-endian: `i32` frame count, `i32` point count, the time of every frame as `f32` seconds,
//! then every frame's points as `x y z` `f32`.

use super::{check_frames, stream_error, write_points, FRAME_RATE};
use crate::error::Result;
use std::io::Write;
use std::vec::Vec;

/// Writes `frames` (metres, y up, 30 Hz; see [`crate::io::export`]) as an MDD file, frame `i`
/// at `i / 30` s.
///
/// # Errors
/// Frames that cannot be written (no frames, frames of different lengths, a
/// non-finite coordinate); [`crate::Error::Io`] from `w`.
pub fn write<P: AsRef<[[f32; 3]]>>(mut w: impl Write, frames: &[P]) -> Result<()> {
    let n = check_frames(frames)?;
    let mut buf = Vec::with_capacity(8 + 4 * frames.len());
    buf.extend_from_slice(&(frames.len() as i32).to_be_bytes());
    buf.extend_from_slice(&(n as i32).to_be_bytes());
    buf.extend((0..frames.len()).flat_map(|i| (i as f32 / FRAME_RATE).to_be_bytes()));
    w.write_all(&buf).map_err(stream_error)?;
    write_points(w, frames, f32::to_be_bytes)
}
