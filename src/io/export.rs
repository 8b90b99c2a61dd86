//! Exports of a simulated garment (or body) that other tools open: an OBJ with new positions that
//! keeps the input file's texture coordinates, groups and materials ([`ObjTemplate`]), the PC2
//! and MDD point caches ([`pc2::write`], [`mdd::write`]) and a USD stage as `.usda` text with
//! time-sampled points ([`usda::write`]).
//!
//! Every writer takes the frames of one mesh as a slice of position arrays, all of the same
//! length: metres, y up, frame `i` at `i / 30` s (30 Hz, frame 0 the starting state), and
//! writes to any [`std::io::Write`]; [`write_file`] puts the bytes in a file.

pub mod mdd;
mod obj_template;
pub mod pc2;
pub mod usda;

pub use obj_template::ObjTemplate;

use crate::error::{Error, Result};
use crate::io::obj::Obj;
use std::path::Path;
use std::string::ToString;
use std::vec::Vec;

/// Frames per second of the exported sequences.
pub const FRAME_RATE: f32 = 30.0;

/// The faces of an exported mesh: polygons as corner counts and vertex indices (the layout of
/// USD's `faceVertexCounts` / `faceVertexIndices`), with optional texture coordinates per corner.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExportMesh {
    /// Corners of every polygon.
    pub face_sizes: Vec<u32>,
    /// Vertex index of every corner, polygon after polygon (0-based).
    pub corners: Vec<u32>,
    /// Texture coordinates (u, v): the values, and for every corner the index of its value.
    pub uvs: Option<(Vec<[f32; 2]>, Vec<u32>)>,
}

impl ExportMesh {
    /// Triangles without texture coordinates.
    pub fn from_triangles(triangles: &[[u32; 3]]) -> ExportMesh {
        ExportMesh {
            face_sizes: std::vec![3; triangles.len()],
            corners: triangles.iter().flatten().copied().collect(),
            uvs: None,
        }
    }

    /// The polygons of an OBJ as written (not triangulated), with its texture coordinates when
    /// every corner names one.
    pub fn from_obj(obj: &Obj) -> ExportMesh {
        let vt: Option<Vec<u32>> = obj.corners.iter().map(|c| c.vt).collect();
        ExportMesh {
            face_sizes: obj.face_sizes.clone(),
            corners: obj.corners.iter().map(|c| c.v).collect(),
            uvs: vt.filter(|_| !obj.uvs.is_empty()).map(|vt| (obj.uvs.clone(), vt)),
        }
    }
}

/// The number of points of `frames` (the length of each).
///
/// # Errors
/// [`Error::Empty`] without frames; [`Error::SizeMismatch`] for a frame of another length than
/// the first; [`Error::NonFinite`] for a NaN or infinite coordinate.
pub(crate) fn check_frames<P: AsRef<[[f32; 3]]>>(frames: &[P]) -> Result<usize> {
    let n = frames.first().ok_or(Error::Empty { what: "exported frames" })?.as_ref().len();
    for f in frames {
        let f = f.as_ref();
        if f.len() != n {
            return Err(Error::SizeMismatch { what: "exported frame points", expected: n, got: f.len() });
        }
        if let Some(i) = f.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(Error::NonFinite { what: "exported point", index: i });
        }
    }
    Ok(n)
}

/// An [`Error::Io`] of a writer (the stream has no path; [`write_file`] names the file).
pub(crate) fn stream_error(e: std::io::Error) -> Error {
    Error::Io { path: "export stream".to_string(), message: e.to_string() }
}

/// Writes every frame's points as `x y z`, each number as `bytes` gives it.
pub(crate) fn write_points<P: AsRef<[[f32; 3]]>>(
    mut w: impl std::io::Write,
    frames: &[P],
    bytes: fn(f32) -> [u8; 4],
) -> Result<()> {
    let mut buf = Vec::new();
    for f in frames {
        buf.clear();
        buf.extend(f.as_ref().iter().flatten().flat_map(|&c| bytes(c)));
        w.write_all(&buf).map_err(stream_error)?;
    }
    Ok(())
}

/// Runs `write` into memory, then writes the bytes to `path` with [`crate::io::write_atomic`].
///
/// # Errors
/// What `write` returns; [`Error::Io`] naming `path`.
pub fn write_file(path: &Path, write: impl FnOnce(&mut Vec<u8>) -> Result<()>) -> Result<()> {
    let mut bytes = Vec::new();
    write(&mut bytes)?;
    crate::io::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests;
