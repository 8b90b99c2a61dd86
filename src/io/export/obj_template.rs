//! An OBJ file written again with new positions, everything else as it was.

use super::{check_frames, stream_error};
use crate::error::{Error, Result};
use crate::io::obj::Obj;
use glam::Vec3;
use std::fmt::Write as _;
use std::format;
use std::io::Write;
use std::ops::Range;
use std::path::Path;
use std::string::String;
use std::vec::Vec;

/// An OBJ file kept as text, to be written again with new positions: texture coordinates,
/// faces (polygons as written, corner references unchanged), groups, objects, materials,
/// smoothing groups and comments stay as they are.
///
/// Each `v` statement is rewritten as `v x y z` with the new position (a `w` or vertex colour
/// on it is dropped). Each `vn` statement is rewritten with a normal **recomputed** from the new
/// positions: the normalised sum of the area-weighted normals of the polygons whose corners
/// name it, so split normals (hard edges) stay split; a normal no corner names is kept as
/// written. Numbers are written in the shortest form that reads back to the same `f32`.
#[derive(Clone, Debug)]
pub struct ObjTemplate {
    text: String,
    pieces: Vec<Piece>,
    obj: Obj,
}

#[derive(Clone, Debug)]
enum Piece {
    /// Text kept as written.
    Text(Range<usize>),
    /// The `v` statement of this vertex.
    Position(usize),
    /// The `vn` statement of this normal.
    Normal(usize),
}

impl ObjTemplate {
    /// Parses OBJ text and keeps it.
    ///
    /// # Errors
    /// As [`Obj::parse`].
    pub fn parse(text: &str) -> Result<ObjTemplate> {
        let obj = Obj::parse(text)?;
        let mut pieces = Vec::new();
        let (mut n_v, mut n_vn) = (0, 0);
        // `kept`: where the text not yet in a piece starts; `continued`: the line continues the
        // statement of the line before (ending in `\`), which `replaced` says was a slot.
        let (mut kept, mut end) = (0, 0);
        let (mut continued, mut replaced) = (false, false);
        for line in text.split_inclusive('\n') {
            let start = end;
            end += line.len();
            let was_continued = continued;
            continued = line.trim_end().ends_with('\\');
            if was_continued {
                if replaced {
                    kept = end;
                }
                continue;
            }
            let piece = match line.split('#').next().unwrap_or("").split_whitespace().next() {
                Some("v") => Piece::Position(n_v),
                Some("vn") => Piece::Normal(n_vn),
                _ => {
                    replaced = false;
                    continue;
                }
            };
            match piece {
                Piece::Position(_) => n_v += 1,
                _ => n_vn += 1,
            }
            replaced = true;
            if start > kept {
                pieces.push(Piece::Text(kept..start));
            }
            pieces.push(piece);
            kept = end;
        }
        if kept < text.len() {
            pieces.push(Piece::Text(kept..text.len()));
        }
        if (n_v, n_vn) != (obj.positions.len(), obj.normals.len()) {
            return Err(Error::parse(
                "obj",
                0,
                format!(
                    "{n_v} vertex and {n_vn} normal lines, {} and {} statements",
                    obj.positions.len(),
                    obj.normals.len()
                ),
            ));
        }
        Ok(ObjTemplate { text: text.into(), pieces, obj })
    }

    /// Reads the OBJ file at `path` and keeps its text.
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read (or is not UTF-8); as [`Obj::parse`].
    pub fn read(path: impl AsRef<Path>) -> Result<ObjTemplate> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        ObjTemplate::parse(&text)
    }

    /// The parsed file.
    pub fn obj(&self) -> &Obj {
        &self.obj
    }

    /// Writes the file with `positions` (one per `v` statement, in file order) in place of the
    /// file's, and normals recomputed from them (see [`ObjTemplate`]).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for positions not one per vertex; [`Error::NonFinite`] for a NaN
    /// or infinite coordinate; [`Error::Io`] from `w`.
    pub fn write(&self, mut w: impl Write, positions: &[[f32; 3]]) -> Result<()> {
        if positions.len() != self.obj.positions.len() {
            return Err(Error::SizeMismatch {
                what: "obj template positions",
                expected: self.obj.positions.len(),
                got: positions.len(),
            });
        }
        check_frames(&[positions])?;
        let normals = self.normals(positions);
        let mut s = String::with_capacity(self.text.len() + 8 * positions.len());
        // Writing into a String cannot fail.
        for piece in &self.pieces {
            let _ = match piece {
                Piece::Text(r) => s.write_str(&self.text[r.clone()]),
                Piece::Position(i) => writeln!(s, "v {} {} {}", positions[*i][0], positions[*i][1], positions[*i][2]),
                Piece::Normal(i) => writeln!(s, "vn {} {} {}", normals[*i][0], normals[*i][1], normals[*i][2]),
            };
        }
        w.write_all(s.as_bytes()).map_err(stream_error)
    }

    /// The file's normals recomputed from `positions` (one per `vn` statement).
    fn normals(&self, positions: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut sum = std::vec![Vec3::ZERO; self.obj.normals.len()];
        let mut first = 0;
        for &size in &self.obj.face_sizes {
            let corners = &self.obj.corners[first..first + size as usize];
            first += size as usize;
            let p = |k: usize| Vec3::from_array(positions[corners[k].v as usize]);
            // The fan's cross products add up to twice the polygon's area-weighted normal.
            let n: Vec3 = (1..corners.len() - 1).map(|k| (p(k) - p(0)).cross(p(k + 1) - p(0))).sum();
            for vn in corners.iter().filter_map(|c| c.vn) {
                sum[vn as usize] += n;
            }
        }
        sum.iter()
            .zip(&self.obj.normals)
            .map(|(s, written)| if s.length() > 0.0 { s.normalize().to_array() } else { *written })
            .collect()
    }
}
