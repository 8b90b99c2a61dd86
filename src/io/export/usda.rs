//! USD point caches as `.usda` text: one `Mesh` prim per mesh, its faces and texture
//! coordinates as authored once, its points time-sampled at every frame (usdview, Blender,
//! Houdini and Omniverse open it).
//!
//! The stage says what the numbers are: `metersPerUnit = 1`, `upAxis = "Y"`,
//! `timeCodesPerSecond = 30` (time code `i` is frame `i`), start and end time codes. Texture
//! coordinates are the `faceVarying` primvar `st` with an index per corner.

use super::{check_frames, stream_error, ExportMesh, FRAME_RATE};
use crate::error::{Error, Result};
use std::fmt::Write as _;
use std::format;
use std::io::Write;
use std::string::String;
use std::vec::Vec;

/// One mesh of a stage: a prim name, its faces and its frames (metres, y up, 30 Hz).
#[derive(Clone, Copy, Debug)]
pub struct UsdMesh<'a> {
    /// The prim's name (`/name`): letters, digits and `_`, not starting with a digit.
    pub name: &'a str,
    /// Faces and optional texture coordinates.
    pub mesh: &'a ExportMesh,
    /// Points at every frame, frame 0 first.
    pub frames: &'a [Vec<[f32; 3]>],
}

/// Writes a `.usda` stage holding `meshes` (the first is the default prim): for each, the faces,
/// the texture coordinates if it has them, `points` as at frame 0 and `points.timeSamples` at
/// time codes 0, 1, ... (30 per second).
///
/// # Errors
/// [`Error::Empty`] without meshes; [`Error::Parse`] (format `"usda"`) for a name that is not an
/// identifier; for each mesh, frames that cannot be written (as in [`super::pc2::write`]);
/// [`Error::SizeMismatch`] for meshes with different frame counts or faces whose corner counts
/// do not add up; [`Error::IndexOutOfRange`] for a corner naming a missing point or texture
/// coordinate; [`Error::Io`] from `w`.
pub fn write(mut w: impl Write, meshes: &[UsdMesh<'_>]) -> Result<()> {
    let first = meshes.first().ok_or(Error::Empty { what: "usda meshes" })?;
    let n_frames = first.frames.len();
    for m in meshes {
        check(m)?;
        if m.frames.len() != n_frames {
            return Err(Error::SizeMismatch { what: "usda mesh frames", expected: n_frames, got: m.frames.len() });
        }
    }
    let mut s = String::new();
    // Writing into a String cannot fail.
    let _ = write!(
        s,
        "#usda 1.0\n(\n    defaultPrim = \"{}\"\n    doc = \"hood cloth simulation\"\n    endTimeCode = {}\n    \
         framesPerSecond = {FRAME_RATE}\n    metersPerUnit = 1\n    startTimeCode = 0\n    \
         timeCodesPerSecond = {FRAME_RATE}\n    upAxis = \"Y\"\n)\n",
        first.name,
        n_frames - 1
    );
    for m in meshes {
        let _ = write!(s, "\ndef Mesh \"{}\"\n{{\n    uniform bool doubleSided = 1\n", m.name);
        s.push_str("    int[] faceVertexCounts = ");
        list(&mut s, &m.mesh.face_sizes, |s, c| write!(s, "{c}"));
        s.push_str("\n    int[] faceVertexIndices = ");
        list(&mut s, &m.mesh.corners, |s, c| write!(s, "{c}"));
        s.push_str("\n    uniform token orientation = \"rightHanded\"\n    point3f[] points = ");
        list(&mut s, &m.frames[0], point);
        s.push_str("\n    point3f[] points.timeSamples = {\n");
        w.write_all(s.as_bytes()).map_err(stream_error)?;
        for (i, f) in m.frames.iter().enumerate() {
            s.clear();
            let _ = write!(s, "        {i}: ");
            list(&mut s, f, point);
            s.push_str(",\n");
            w.write_all(s.as_bytes()).map_err(stream_error)?;
        }
        s.clear();
        s.push_str("    }\n");
        if let Some((values, indices)) = &m.mesh.uvs {
            s.push_str("    texCoord2f[] primvars:st = ");
            list(&mut s, values, |s, [u, v]| write!(s, "({u}, {v})"));
            s.push_str(" (\n        interpolation = \"faceVarying\"\n    )\n    int[] primvars:st:indices = ");
            list(&mut s, indices, |s, c| write!(s, "{c}"));
            s.push('\n');
        }
        s.push_str("    uniform token subdivisionScheme = \"none\"\n}\n");
    }
    w.write_all(s.as_bytes()).map_err(stream_error)
}

fn point(s: &mut String, p: &[f32; 3]) -> std::fmt::Result {
    write!(s, "({}, {}, {})", p[0], p[1], p[2])
}

/// `[a, b, ...]` with `item` writing each element.
fn list<T>(s: &mut String, items: &[T], item: impl Fn(&mut String, &T) -> std::fmt::Result) {
    s.push('[');
    for (i, x) in items.iter().enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        let _ = item(s, x);
    }
    s.push(']');
}

/// The name is an identifier, the frames are sound, the faces and texture coordinates in range.
fn check(m: &UsdMesh<'_>) -> Result<()> {
    let identifier = m.name.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && m.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if !identifier {
        return Err(Error::parse("usda", 0, format!("prim name '{}' is not an identifier", m.name)));
    }
    let n = check_frames(m.frames)?;
    let corners: usize = m.mesh.face_sizes.iter().map(|&c| c as usize).sum();
    if corners != m.mesh.corners.len() {
        return Err(Error::SizeMismatch { what: "usda face corners", expected: corners, got: m.mesh.corners.len() });
    }
    in_range(&m.mesh.corners, n, "usda face corner")?;
    if let Some((values, indices)) = &m.mesh.uvs {
        if indices.len() != corners {
            return Err(Error::SizeMismatch { what: "usda texture indices", expected: corners, got: indices.len() });
        }
        in_range(indices, values.len(), "usda texture index")?;
    }
    Ok(())
}

fn in_range(indices: &[u32], len: usize, what: &'static str) -> Result<()> {
    match indices.iter().position(|&i| i as usize >= len) {
        Some(at) => Err(Error::IndexOutOfRange { what, at, index: indices[at] as usize, len }),
        None => Ok(()),
    }
}
