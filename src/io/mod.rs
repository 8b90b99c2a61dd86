//! File formats (feature `tools`): readers and writers that turn files into the crate's plain
//! arrays and back. Errors are [`crate::Error::Parse`] (with the 1-based line) and
//! [`crate::Error::Io`].

pub mod bvh;
pub mod export;
pub mod gltf;
pub mod json;
pub mod makehuman;
pub mod obj;
pub mod png;
pub mod safetensors;

use crate::error::{Error, Result};
use std::path::Path;

/// Writes `bytes` to `path` through a temporary file beside it (`path` with the extension
/// `tmp`), then renames it over `path`, so that a reader never sees a half-written file.
///
/// # Errors
/// [`Error::Io`] naming `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let io = |e: std::io::Error| Error::io(path, e);
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}
