//! Wavefront OBJ: a reader for positions, texture coordinates, normals, polygons (kept corner by
//! corner and fan-triangulated) and groups; group extraction; connected components; a writer.
//! [`crate::io::export::ObjTemplate`] writes a file again with new positions.
//!
//! Read: `v x y z [...]` (extra components such as `w` or vertex colours are ignored), `vt u [v
//! [w]]` (`v` 0 when missing, `w` ignored), `vn x y z`, `f` with `v`,
//! `v/vt`, `v//vn` or `v/vt/vn` corners (the forms may mix), 1-based or negative (relative)
//! indices, polygons fan-triangulated as `(a,b,c), (a,c,d), ...`; `g` and `o` set the current
//! group (see [`Obj::groups`]); `#` starts a comment; a line ending in `\` continues on the next.
//! Every other statement (`s`, `usemtl`, `mtllib`, `l`, ...) is ignored. Units are whatever the
//! file uses (MakeHuman assets: decimetres; see [`Obj::scale`]).

use crate::error::{Error, Result};
use crate::mesh::repair::{drop_unused_vertices, CompactedMesh};
use crate::mesh::topology::components;
use std::fmt::Write as _;
use std::format;
use std::path::Path;
use std::string::{String, ToString};
use std::vec::Vec;

/// The content of an OBJ file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Obj {
    /// Vertex positions in file units.
    pub positions: Vec<[f32; 3]>,
    /// Texture coordinates (`vt`), in file order.
    pub uvs: Vec<[f32; 2]>,
    /// Normals (`vn`) as written (not normalised), in file order.
    pub normals: Vec<[f32; 3]>,
    /// The corners of every `f` statement, polygon after polygon (`face_sizes` says how many
    /// each has), as written: 0-based indices into `positions`, `uvs` and `normals`.
    pub corners: Vec<Corner>,
    /// Corners per `f` statement, in file order.
    pub face_sizes: Vec<u32>,
    /// Triangles (polygons fan-triangulated), 0-based indices into `positions`. Kept as read: a
    /// polygon that repeats a vertex gives triangles that do too (see [`crate::mesh::repair`]).
    pub triangles: Vec<[u32; 3]>,
    /// For every triangle, its group (index into `groups`).
    pub triangle_group: Vec<u32>,
    /// For every triangle, the `f` statement it came from (0-based, counting `f` statements).
    pub triangle_polygon: Vec<u32>,
    /// Group names in order of first appearance: the text after `g` or `o` (whitespace trimmed;
    /// a `g` naming several groups gives one entry whose names are separated by spaces). Faces
    /// before any `g`/`o` are in the group `""`. A name seen again reuses its entry.
    pub groups: Vec<String>,
    /// Number of `f` statements.
    pub n_polygons: usize,
}

/// One corner of an OBJ face: 0-based indices of its position, texture coordinate and normal.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Corner {
    /// Index into [`Obj::positions`].
    pub v: u32,
    /// Index into [`Obj::uvs`], if the corner names one.
    pub vt: Option<u32>,
    /// Index into [`Obj::normals`], if the corner names one.
    pub vn: Option<u32>,
}

impl Obj {
    /// Parses OBJ text.
    ///
    /// # Errors
    /// [`Error::Parse`] with format `"obj"` and the 1-based line of the statement: a vertex or
    /// normal without three numbers, a texture coordinate without one, a non-finite number, a face with fewer than three corners, a
    /// malformed corner, index 0, or an index past the elements defined so far;
    /// [`Error::CapacityExceeded`] beyond [`crate::limits::MAX_VERTICES`] vertices or
    /// [`crate::limits::MAX_FACES`] triangles.
    pub fn parse(text: &str) -> Result<Obj> {
        Obj::parse_within(text, crate::limits::MAX_VERTICES, crate::limits::MAX_FACES)
    }

    /// [`Obj::parse`] with other bounds on the vertices and triangles (for the tests).
    fn parse_within(text: &str, max_vertices: usize, max_triangles: usize) -> Result<Obj> {
        let mut obj = Obj::default();
        let mut current_group: Option<u32> = None;
        let mut logical = String::new();
        let mut lines = text.lines().enumerate().peekable();
        while let Some((i, raw)) = lines.next() {
            // Errors name the first line of a statement continued over several lines.
            let start_line = i + 1;
            // Join continuation lines ("\" at the end) into one statement.
            let mut line = raw;
            if line.trim_end().ends_with('\\') {
                logical.clear();
                let mut cur = line;
                loop {
                    let t = cur.trim_end();
                    if let Some(head) = t.strip_suffix('\\') {
                        logical.push_str(head);
                        logical.push(' ');
                        match lines.next() {
                            Some((_, next)) => cur = next,
                            None => break,
                        }
                    } else {
                        logical.push_str(cur);
                        break;
                    }
                }
                line = &logical;
            }
            let line = line.split('#').next().unwrap_or("");
            let mut tokens = line.split_whitespace();
            let Some(keyword) = tokens.next() else { continue };
            let err = |m: String| Error::parse("obj", start_line, m);
            match keyword {
                "v" => {
                    crate::limits::within("obj vertices", obj.positions.len() + 1, max_vertices)?;
                    obj.positions.push(numbers(&mut tokens, 3, "vertex").map_err(&err)?);
                }
                "vt" => {
                    let [u, v, _] = numbers(&mut tokens, 1, "texture").map_err(&err)?;
                    obj.uvs.push([u, v]);
                }
                "vn" => obj.normals.push(numbers(&mut tokens, 3, "normal").map_err(&err)?),
                "f" => {
                    let first = obj.corners.len();
                    for t in tokens {
                        let c = parse_corner(t, obj.positions.len(), obj.uvs.len(), obj.normals.len()).map_err(&err)?;
                        obj.corners.push(c);
                    }
                    let n = obj.corners.len() - first;
                    if n < 3 {
                        return Err(err(format!("face has {n} corners, needs at least 3")));
                    }
                    crate::limits::within("obj triangles", obj.triangles.len() + n - 2, max_triangles)?;
                    obj.face_sizes.push(n as u32);
                    let g = match current_group {
                        Some(g) => g,
                        None => {
                            let g = group_id(&mut obj.groups, "");
                            current_group = Some(g);
                            g
                        }
                    };
                    let poly = obj.n_polygons as u32;
                    let v = |k: usize| obj.corners[first + k].v;
                    for k in 1..n - 1 {
                        obj.triangles.push([v(0), v(k), v(k + 1)]);
                        obj.triangle_group.push(g);
                        obj.triangle_polygon.push(poly);
                    }
                    obj.n_polygons += 1;
                }
                "g" | "o" => {
                    let name = tokens.collect::<Vec<_>>().join(" ");
                    current_group = Some(group_id(&mut obj.groups, &name));
                }
                _ => {}
            }
        }
        Ok(obj)
    }

    /// Reads and parses the OBJ file at `path`.
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read (or is not UTF-8); as [`Obj::parse`].
    pub fn read(path: impl AsRef<Path>) -> Result<Obj> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Obj::parse(&text)
    }

    /// Multiplies every position by `factor` (e.g. 0.1 for MakeHuman decimetres to metres).
    pub fn scale(&mut self, factor: f32) {
        for p in &mut self.positions {
            *p = p.map(|c| c * factor);
        }
    }

    /// The index of the group entry named exactly `name`, or containing `name` as one of its
    /// space-separated names.
    pub fn group_index(&self, name: &str) -> Option<usize> {
        self.groups
            .iter()
            .position(|g| g == name)
            .or_else(|| self.groups.iter().position(|g| g.split(' ').any(|n| n == name)))
    }

    /// Indices of the triangles in any of the groups `names` (each matched as in
    /// [`group_index`](Self::group_index), every entry containing the name counts), ascending.
    ///
    /// # Errors
    /// [`Error::Parse`] (line 0) naming a group that does not exist.
    pub fn triangles_in_groups(&self, names: &[&str]) -> Result<Vec<usize>> {
        let mut wanted = std::vec![false; self.groups.len()];
        for name in names {
            let mut found = false;
            for (g, w) in self.groups.iter().zip(wanted.iter_mut()) {
                if g == name || g.split(' ').any(|n| n == *name) {
                    *w = true;
                    found = true;
                }
            }
            if !found {
                return Err(Error::parse("obj", 0, format!("no group named '{name}'")));
            }
        }
        Ok((0..self.triangles.len()).filter(|&t| wanted[self.triangle_group[t] as usize]).collect())
    }

    /// The triangles of the groups `names` as a compact mesh: only the vertices those triangles
    /// use, renumbered in ascending original order; `remap` maps between file and mesh indices.
    ///
    /// # Errors
    /// As [`triangles_in_groups`](Self::triangles_in_groups).
    pub fn extract_groups(&self, names: &[&str]) -> Result<CompactedMesh> {
        let tris: Vec<[u32; 3]> = self.triangles_in_groups(names)?.into_iter().map(|t| self.triangles[t]).collect();
        Ok(drop_unused_vertices(&self.positions, &tris))
    }
}

fn group_id(groups: &mut Vec<String>, name: &str) -> u32 {
    match groups.iter().position(|g| g == name) {
        Some(g) => g as u32,
        None => {
            groups.push(name.to_string());
            (groups.len() - 1) as u32
        }
    }
}

/// The first three numbers of a statement (at least `needed` of them; the others 0), finite.
fn numbers<'a>(
    tokens: &mut impl Iterator<Item = &'a str>,
    needed: usize,
    what: &str,
) -> core::result::Result<[f32; 3], String> {
    let mut p = [0.0f32; 3];
    for (a, c) in p.iter_mut().enumerate() {
        let Some(t) = tokens.next() else {
            if a < needed {
                return Err(format!("{what} has {a} coordinates, needs {needed}"));
            }
            break;
        };
        *c = t.parse::<f32>().map_err(|_| format!("bad {what} coordinate '{t}'"))?;
        if !c.is_finite() {
            return Err(format!("non-finite {what} coordinate '{t}'"));
        }
    }
    Ok(p)
}

/// One face corner `v`, `v/vt`, `v//vn` or `v/vt/vn`, 0-based.
fn parse_corner(t: &str, n_v: usize, n_vt: usize, n_vn: usize) -> core::result::Result<Corner, String> {
    let mut parts = t.split('/');
    let v = parts.next().unwrap_or("");
    let vt = parts.next();
    let vn = parts.next();
    if parts.next().is_some() {
        return Err(format!("bad face corner '{t}' (more than v/vt/vn)"));
    }
    let mut corner = Corner { v: resolve(v, n_v, "vertex", t)?, vt: None, vn: None };
    if let Some(vt) = vt {
        // "v//vn" has an empty texture part; "v/" alone is malformed.
        if !(vt.is_empty() && vn.is_some()) {
            corner.vt = Some(resolve(vt, n_vt, "texture coordinate", t)?);
        }
    }
    if let Some(vn) = vn {
        corner.vn = Some(resolve(vn, n_vn, "normal", t)?);
    }
    Ok(corner)
}

/// A 1-based or negative (relative to the `count` defined so far) index to 0-based.
fn resolve(s: &str, count: usize, what: &str, corner: &str) -> core::result::Result<u32, String> {
    let i: i64 = s.parse().map_err(|_| format!("bad {what} index '{s}' in face corner '{corner}'"))?;
    let zero_based = match i {
        0 => return Err(format!("{what} index 0 in face corner '{corner}' (OBJ indices start at 1)")),
        i if i > 0 => i - 1,
        i => count as i64 + i,
    };
    if zero_based < 0 || zero_based >= count as i64 {
        return Err(format!("{what} index {i} in face corner '{corner}' is out of range ({count} defined so far)"));
    }
    Ok(zero_based as u32)
}

/// Splits a triangle mesh into its connected components (vertices joined by triangle edges), in
/// order of each component's lowest vertex; vertices used by no triangle are dropped. Each part
/// carries the remap to the input's vertex indices.
///
/// # Errors
/// [`Error::IndexOutOfRange`] for a triangle naming a missing vertex.
pub fn split_components(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Vec<CompactedMesh>> {
    let n = positions.len();
    check_triangles(triangles, n)?;
    let edges: Vec<[u32; 2]> = triangles.iter().flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]]).collect();
    let (component, n_comp) = components(n, &edges);
    let mut per: Vec<Vec<[u32; 3]>> = std::vec![Vec::new(); n_comp as usize];
    for t in triangles {
        per[component[t[0] as usize] as usize].push(*t);
    }
    Ok(per.into_iter().filter(|f| !f.is_empty()).map(|f| drop_unused_vertices(positions, &f)).collect())
}

fn check_triangles(triangles: &[[u32; 3]], n: usize) -> Result<()> {
    for (fi, t) in triangles.iter().enumerate() {
        if let Some(&v) = t.iter().find(|&&v| v as usize >= n) {
            return Err(Error::IndexOutOfRange { what: "triangle", at: fi, index: v as usize, len: n });
        }
    }
    Ok(())
}

/// OBJ text for `positions` and `triangles` (0-based), with one normal per vertex when `normals`
/// is given (written as `vn` and referenced as `v//vn`). Numbers are written in the shortest form
/// that reads back to the same `f32`.
///
/// # Errors
/// [`Error::IndexOutOfRange`] for a triangle naming a missing vertex; [`Error::SizeMismatch`] for
/// normals not one per vertex.
pub fn to_string(positions: &[[f32; 3]], triangles: &[[u32; 3]], normals: Option<&[[f32; 3]]>) -> Result<String> {
    check_triangles(triangles, positions.len())?;
    if let Some(nr) = normals {
        if nr.len() != positions.len() {
            return Err(Error::SizeMismatch { what: "obj normals", expected: positions.len(), got: nr.len() });
        }
    }
    let mut s = String::with_capacity(40 * (positions.len() + triangles.len()));
    // Writing into a String cannot fail.
    for p in positions {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for n in normals.unwrap_or(&[]) {
        let _ = writeln!(s, "vn {} {} {}", n[0], n[1], n[2]);
    }
    for t in triangles {
        let [a, b, c] = t.map(|i| i + 1);
        if normals.is_some() {
            let _ = writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}");
        } else {
            let _ = writeln!(s, "f {a} {b} {c}");
        }
    }
    Ok(s)
}

/// Writes [`to_string`]'s text to the file at `path`.
///
/// # Errors
/// As [`to_string`]; [`Error::Io`] when the file cannot be written.
pub fn write(
    path: impl AsRef<Path>,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    normals: Option<&[[f32; 3]]>,
) -> Result<()> {
    let text = to_string(positions, triangles, normals)?;
    let path = path.as_ref();
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests;
