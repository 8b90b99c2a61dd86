//! Garments on bodies: the MakeHuman `.mhclo` binding (barycentric + scaled offset) and fitting
//! onto any posed body; skinning weights for a garment borrowed from the nearest body vertex, and
//! the diffused version of the HOOD supplement (eq. 1-2); pinned-vertex selection; garment
//! initialisation by skinning.
//!
//! Units: whatever the body is in (metres for everything `hood` builds); the binding's own
//! lengths are converted by the `unit` given to [`MhcloBinding::parse`].

use super::{skin, Pose, Skeleton, SkinTransforms, SkinWeights};
use crate::body::PointGrid;
use crate::error::{Error, Result};
use crate::mesh::Garment;
use alloc::format;
use alloc::vec;
use alloc::vec::Vec;
use glam::{Mat3, Vec3};

/// One garment vertex bound to three body vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VertexBinding {
    /// Body vertices.
    pub v: [u32; 3],
    /// Barycentric weights.
    pub w: [f32; 3],
    /// Offset before scaling (body units).
    pub offset: [f32; 3],
}

/// A `.mhclo` binding: per garment vertex, three body vertices, weights and an offset scaled per
/// axis by the body's extent between two reference vertices (`x_scale v1 v2 length`, ...).
#[derive(Clone, Debug, PartialEq)]
pub struct MhcloBinding {
    /// Per garment vertex (in the garment OBJ's vertex order).
    pub vertices: Vec<VertexBinding>,
    /// `(v1, v2, reference length)` for x, y, z: the offset along an axis is multiplied by
    /// `|body[v1] - body[v2]|` along that axis over the reference length.
    pub scale: [(u32, u32, f32); 3],
    /// The garment OBJ file named by the binding (empty if none).
    pub obj_file: alloc::string::String,
}

fn perr(line: usize, msg: impl Into<alloc::string::String>) -> Error {
    Error::parse("mhclo", line, msg)
}

impl MhcloBinding {
    /// Parses `.mhclo` text; `unit` is body units per file unit (0.1 for MakeHuman decimetres to
    /// metres). Lines other than `x_scale`/`y_scale`/`z_scale`, `obj_file` and the `verts`
    /// section are ignored; a vertex line holds either one body vertex or `v1 v2 v3 w1 w2 w3 dx dy
    /// dz`.
    ///
    /// # Errors
    /// [`Error::Parse`] with format `"mhclo"` and the line: a malformed number or vertex line, a
    /// missing scale line or `verts` section.
    pub fn parse(text: &str, unit: f32) -> Result<MhcloBinding> {
        let mut scale: [Option<(u32, u32, f32)>; 3] = [None; 3];
        let mut vertices = Vec::new();
        let mut obj_file = alloc::string::String::new();
        let mut in_verts = false;
        let mut saw_verts = false;
        for (i, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let tok: Vec<&str> = line.split_whitespace().collect();
            let num = |t: &str| {
                t.parse::<f32>().ok().filter(|x| x.is_finite()).ok_or_else(|| perr(i + 1, format!("bad number '{t}'")))
            };
            let idx = |t: &str| t.parse::<u32>().map_err(|_| perr(i + 1, format!("bad vertex index '{t}'")));
            if in_verts {
                let first_is_number = tok[0].parse::<f64>().is_ok();
                if first_is_number {
                    match tok.len() {
                        1 => {
                            vertices.push(VertexBinding { v: [idx(tok[0])?; 3], w: [1.0, 0.0, 0.0], offset: [0.0; 3] })
                        }
                        9 => vertices.push(VertexBinding {
                            v: [idx(tok[0])?, idx(tok[1])?, idx(tok[2])?],
                            w: [num(tok[3])?, num(tok[4])?, num(tok[5])?],
                            offset: [num(tok[6])? * unit, num(tok[7])? * unit, num(tok[8])? * unit],
                        }),
                        n => return Err(perr(i + 1, format!("vertex line with {n} values (1 or 9 expected)"))),
                    }
                    continue;
                }
                in_verts = false;
            }
            match tok[0] {
                "verts" => {
                    in_verts = true;
                    saw_verts = true;
                }
                "obj_file" if tok.len() >= 2 => obj_file = tok[1..].join(" "),
                "x_scale" | "y_scale" | "z_scale" => {
                    if tok.len() != 4 {
                        return Err(perr(i + 1, format!("{} needs 3 values", tok[0])));
                    }
                    let a = (tok[0].as_bytes()[0] - b'x') as usize;
                    scale[a] = Some((idx(tok[1])?, idx(tok[2])?, num(tok[3])? * unit));
                }
                _ => {}
            }
        }
        if !saw_verts || vertices.is_empty() {
            return Err(perr(0, "no 'verts' section"));
        }
        let mut s = [(0, 0, 1.0); 3];
        for a in 0..3 {
            s[a] = scale[a].ok_or_else(|| perr(0, format!("missing {}_scale", ['x', 'y', 'z'][a])))?;
        }
        Ok(MhcloBinding { vertices, scale: s, obj_file })
    }

    /// Checks that every body index is below `n_body`.
    pub fn check(&self, n_body: usize) -> Result<()> {
        for (i, b) in self.vertices.iter().enumerate() {
            for &v in &b.v {
                if v as usize >= n_body {
                    return Err(Error::IndexOutOfRange {
                        what: "mhclo body vertex",
                        at: i,
                        index: v as usize,
                        len: n_body,
                    });
                }
            }
        }
        for &(a, b, _) in &self.scale {
            if a.max(b) as usize >= n_body {
                return Err(Error::IndexOutOfRange {
                    what: "mhclo scale vertex",
                    at: 0,
                    index: a.max(b) as usize,
                    len: n_body,
                });
            }
        }
        Ok(())
    }

    /// Places the garment on a body with MakeHuman's formula. `rest_body` is the body the
    /// binding was made for (its extents give the offset scales); `posed_body` the same vertices
    /// in any pose: each offset turns with its triangle's frame from rest to posed (for
    /// `posed_body == rest_body` this is exactly MakeHuman's fitting). Writes one position per
    /// bound vertex into `out`.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for bodies of different lengths or `out` of the wrong length;
    /// [`Error::IndexOutOfRange`] for a body index past the body.
    pub fn fit(&self, rest_body: &[[f32; 3]], posed_body: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
        self.fit_impl(rest_body, None, posed_body, out)
    }

    /// As [`Self::fit`], but without the part of each offset that points into the body (along
    /// the binding's interpolated rest vertex normal, `rest_normals` one per body vertex). The
    /// MakeHuman garments' offsets were authored on a body with other morphs: applied to
    /// base.obj as they are, they push 21% of female_casualsuit01's vertices up to 11 mm under
    /// the skin; without their inward part none is (the helper surface they bind to lies outside
    /// the skin).
    ///
    /// # Errors
    /// As [`Self::fit`], and [`Error::SizeMismatch`] for normals of the wrong length.
    pub fn fit_outside(
        &self,
        rest_body: &[[f32; 3]],
        rest_normals: &[[f32; 3]],
        posed_body: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<()> {
        if rest_normals.len() != rest_body.len() {
            return Err(Error::SizeMismatch {
                what: "body normals",
                expected: rest_body.len(),
                got: rest_normals.len(),
            });
        }
        self.fit_impl(rest_body, Some(rest_normals), posed_body, out)
    }

    fn fit_impl(
        &self,
        rest_body: &[[f32; 3]],
        rest_normals: Option<&[[f32; 3]]>,
        posed_body: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<()> {
        if rest_body.len() != posed_body.len() {
            return Err(Error::SizeMismatch { what: "posed body", expected: rest_body.len(), got: posed_body.len() });
        }
        if out.len() != self.vertices.len() {
            return Err(Error::SizeMismatch { what: "fitted garment", expected: self.vertices.len(), got: out.len() });
        }
        self.check(rest_body.len())?;
        let r = |i: u32| Vec3::from(rest_body[i as usize]);
        let p = |i: u32| Vec3::from(posed_body[i as usize]);
        let mut s = Vec3::ONE;
        for a in 0..3 {
            let (v1, v2, len) = self.scale[a];
            if len > 0.0 {
                s[a] = (r(v1)[a] - r(v2)[a]).abs() / len;
            }
        }
        for (b, o) in self.vertices.iter().zip(out.iter_mut()) {
            let base = p(b.v[0]) * b.w[0] + p(b.v[1]) * b.w[1] + p(b.v[2]) * b.w[2];
            let mut off = Vec3::from(b.offset) * s;
            if let Some(nrm) = rest_normals {
                let n = (0..3).map(|k| Vec3::from(nrm[b.v[k] as usize]) * b.w[k]).sum::<Vec3>().normalize_or_zero();
                let inward = off.dot(n);
                if inward < 0.0 {
                    off -= n * inward;
                }
            }
            let turned = match (
                triangle_frame(r(b.v[0]), r(b.v[1]), r(b.v[2])),
                triangle_frame(p(b.v[0]), p(b.v[1]), p(b.v[2])),
            ) {
                (Some(fr), Some(fp)) if rest_body.as_ptr() != posed_body.as_ptr() => fp * (fr.transpose() * off),
                _ => off,
            };
            *o = (base + turned).into();
        }
        Ok(())
    }
}

/// Orthonormal frame (columns: edge, in-plane normal to it, face normal) of a triangle, `None`
/// when degenerate.
fn triangle_frame(a: Vec3, b: Vec3, c: Vec3) -> Option<Mat3> {
    let e = (b - a).try_normalize()?;
    let n = (b - a).cross(c - a).try_normalize()?;
    Some(Mat3::from_cols(e, n.cross(e), n))
}

/// A point grid over `body` (for nearest-vertex queries).
fn body_grid(body: &[[f32; 3]]) -> Result<PointGrid> {
    let mut grid = PointGrid::new(body.len(), (body.len() * 4).max(64))?;
    grid.rebuild(body)?;
    Ok(grid)
}

/// Skinning weights for garment vertices copied from the nearest body vertex.
///
/// # Errors
/// [`Error::SizeMismatch`] when `body_weights` does not cover `body`; [`Error::Empty`] for an
/// empty body; [`Error::NonFinite`] for a NaN position.
pub fn nearest_vertex_weights(
    garment: &[[f32; 3]],
    body: &[[f32; 3]],
    body_weights: &SkinWeights,
) -> Result<SkinWeights> {
    check_weights(body, body_weights)?;
    let grid = body_grid(body)?;
    let mut triples = Vec::with_capacity(garment.len() * 4);
    for (i, x) in garment.iter().enumerate() {
        let nn = nearest(&grid, *x, i)?;
        for (b, w) in body_weights.influences(nn.index as usize) {
            triples.push((i as u32, b as u16, w));
        }
    }
    SkinWeights::from_triples(garment.len(), body_weights.bone_bound(), &triples, 4)
}

fn check_weights(body: &[[f32; 3]], w: &SkinWeights) -> Result<()> {
    if body.is_empty() {
        return Err(Error::Empty { what: "body" });
    }
    if w.n_vertices() != body.len() {
        return Err(Error::SizeMismatch { what: "body skin weights", expected: body.len(), got: w.n_vertices() });
    }
    Ok(())
}

fn nearest(grid: &PointGrid, x: [f32; 3], i: usize) -> Result<crate::body::Nearest> {
    if !crate::math::finite3(x) {
        return Err(Error::NonFinite { what: "garment vertex", index: i });
    }
    grid.nearest_one(x).ok_or(Error::Empty { what: "body" })
}

/// Default number of samples per vertex of [`diffused_weights`] (the supplement's M).
pub const DIFFUSION_SAMPLES: usize = 10_000;

/// Diffused skinning weights (HOOD supplement, eq. 1-2): for a garment vertex `x` at distance
/// `d` from its nearest body vertex, the average of the body weights at the nearest body vertex
/// of `samples` points drawn from the normal distribution `N(x, d^2 I)`. Loose cloth thus moves
/// with a blend of the bones around it instead of snapping to one.
///
/// For speed, a sample's nearest body vertex is that of the centre of its voxel, on lazily
/// filled voxel grids of edge `voxel * 2^k` metres, the level chosen per garment vertex so that
/// the edge is about `d / 2` (at least `voxel`): the quantisation stays well inside the spread
/// of the samples, and the work per vertex stays bounded. The same `samples` standard-normal
/// offsets (from `seed`) serve every vertex, scaled by its `d`; samples beyond 12 voxels of the
/// vertex's voxel (at least 6 standard deviations) count at the window's edge. Each vertex keeps its
/// 4 largest weights.
///
/// # Errors
/// As [`nearest_vertex_weights`]; [`Error::OutOfRange`] for zero samples or a voxel edge that is
/// not positive.
pub fn diffused_weights(
    garment: &[[f32; 3]],
    body: &[[f32; 3]],
    body_weights: &SkinWeights,
    samples: usize,
    voxel: f32,
    seed: u64,
) -> Result<SkinWeights> {
    check_weights(body, body_weights)?;
    if samples == 0 {
        return Err(Error::OutOfRange { what: "diffusion samples", index: 0 });
    }
    if !(voxel > 0.0 && voxel.is_finite()) {
        return Err(Error::OutOfRange { what: "diffusion voxel", index: 0 });
    }
    let grid = body_grid(body)?;
    let offsets = normal_offsets(samples, seed);
    // Voxel cache over the garment's box grown by 3 d_max (samples beyond are clamped).
    let mut d = Vec::with_capacity(garment.len());
    for (i, x) in garment.iter().enumerate() {
        d.push(nearest(&grid, *x, i)?.distance);
    }
    let reach = 3.5 * d.iter().fold(0.0f32, |m, &v| m.max(v));
    let lo = garment.iter().fold(Vec3::splat(f32::INFINITY), |m, p| m.min(Vec3::from(*p))) - Vec3::splat(reach + voxel);
    let hi =
        garment.iter().fold(Vec3::splat(f32::NEG_INFINITY), |m, p| m.max(Vec3::from(*p))) + Vec3::splat(reach + voxel);
    const EMPTY: u32 = u32::MAX;
    // Voxel levels: level k has edge voxel * 2^k; a vertex uses the level whose edge is about
    // d / 2, so that its samples touch a bounded number of voxels whatever its distance.
    struct Level {
        edge: f32,
        dims: [i32; 3],
        cache: Vec<u32>,
    }
    let mut levels: Vec<Option<Level>> = (0..12).map(|_| None).collect();
    let nb = body_weights.bone_bound();
    let mut acc = vec![0.0f32; nb];
    let mut triples = Vec::with_capacity(garment.len() * 4);
    // Samples are first counted per voxel in a window around the vertex (cheap), then each
    // touched voxel contributes its nearest body vertex's weights once, times its count.
    const R: i32 = 12;
    const SIDE: usize = 2 * R as usize + 1;
    let mut counts: Vec<u32> = vec![0; SIDE * SIDE * SIDE];
    let mut touched: Vec<u32> = Vec::new();
    for (i, x) in garment.iter().enumerate() {
        let x = Vec3::from(*x);
        acc.fill(0.0);
        let mut k = 0usize;
        while k + 1 < levels.len() && voxel * (1u32 << k) as f32 * 2.0 < d[i] {
            k += 1;
        }
        let level = match &mut levels[k] {
            Some(l) => l,
            slot => {
                let edge = voxel * (1u32 << k) as f32;
                let dims = ((hi - lo) / edge).ceil().as_ivec3().max(glam::IVec3::ONE);
                let n = dims.x as u64 * dims.y as u64 * dims.z as u64;
                if n > 64_000_000 {
                    return Err(Error::CapacityExceeded {
                        what: "diffusion voxels",
                        capacity: 64_000_000,
                        needed: n as usize,
                    });
                }
                slot.insert(Level { edge, dims: dims.into(), cache: vec![EMPTY; n as usize] })
            }
        };
        let inv = 1.0 / level.edge;
        let [mx, my, mz] = level.dims.map(|v| v - 1);
        let base = (x - lo) * inv;
        // Window centred on the vertex's voxel; `as` casts (truncating) instead of floor(),
        // which is a libm call per component in this no_std build (coordinates are >= 0 here).
        let (wx, wy, wz) = (base.x as i32 - R, base.y as i32 - R, base.z as i32 - R);
        let scale = d[i] * inv;
        touched.clear();
        for o in &offsets {
            let f = base + *o * scale;
            // +1/-1 makes truncation agree with floor for f > -1 (samples just outside the box).
            let lx = (((f.x + 1.0) as i32 - 1).clamp(0, mx) - wx).clamp(0, 2 * R) as usize;
            let ly = (((f.y + 1.0) as i32 - 1).clamp(0, my) - wy).clamp(0, 2 * R) as usize;
            let lz = (((f.z + 1.0) as i32 - 1).clamp(0, mz) - wz).clamp(0, 2 * R) as usize;
            let c = (lz * SIDE + ly) * SIDE + lx;
            if counts[c] == 0 {
                touched.push(c as u32);
            }
            counts[c] += 1;
        }
        for &c in &touched {
            let c = c as usize;
            let gx = (wx + (c % SIDE) as i32).clamp(0, mx);
            let gy = (wy + ((c / SIDE) % SIDE) as i32).clamp(0, my);
            let gz = (wz + (c / (SIDE * SIDE)) as i32).clamp(0, mz);
            let g = (gz as usize * level.dims[1] as usize + gy as usize) * level.dims[0] as usize + gx as usize;
            let mut v = level.cache[g];
            if v == EMPTY {
                let centre = lo + (Vec3::new(gx as f32, gy as f32, gz as f32) + Vec3::splat(0.5)) * level.edge;
                v = grid.nearest_one(centre.into()).map_or(0, |n| n.index);
                level.cache[g] = v;
            }
            let n = core::mem::take(&mut counts[c]) as f32;
            for (b, w) in body_weights.influences(v as usize) {
                acc[b] += w * n;
            }
        }
        for (b, &w) in acc.iter().enumerate() {
            if w > 0.0 {
                triples.push((i as u32, b as u16, w));
            }
        }
    }
    SkinWeights::from_triples(garment.len(), nb, &triples, 4)
}

/// `n` standard-normal 3D offsets from a seeded splitmix64 + Box-Muller.
fn normal_offsets(n: usize, seed: u64) -> Vec<Vec3> {
    let mut state = seed;
    let mut uniform = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (((z ^ (z >> 31)) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut normal = move || {
        let (u, v) = (uniform(), uniform());
        (crate::math::sqrt_f64(-2.0 * libm::log(u)) * libm::cos(core::f64::consts::TAU * v)) as f32
    };
    (0..n).map(|_| Vec3::new(normal(), normal(), normal())).collect()
}

/// Which boundary loop to pin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LoopChoice {
    /// The loop with the highest mean height (a waist: jeans, skirt).
    Highest,
    /// The loop with the lowest mean height.
    Lowest,
    /// The `k`-th loop of [`Garment::boundary_loops`].
    Index(usize),
}

/// The vertices of one boundary loop of `garment` at its rest positions, ascending.
///
/// # Errors
/// [`Error::Empty`] when the garment has no boundary; [`Error::OutOfRange`] for a loop index
/// past the last loop.
pub fn boundary_loop_pins(garment: &Garment, choice: LoopChoice) -> Result<Vec<u32>> {
    let loops = garment.boundary_loops();
    if loops.is_empty() {
        return Err(Error::Empty { what: "garment boundary" });
    }
    let mean_y = |l: &Vec<u32>| l.iter().map(|&v| garment.rest()[v as usize][1] as f64).sum::<f64>() / l.len() as f64;
    let k = match choice {
        LoopChoice::Index(k) if k < loops.len() => k,
        LoopChoice::Index(k) => return Err(Error::OutOfRange { what: "boundary loop", index: k }),
        LoopChoice::Highest => {
            (0..loops.len()).max_by(|&a, &b| mean_y(&loops[a]).total_cmp(&mean_y(&loops[b]))).unwrap_or(0)
        }
        LoopChoice::Lowest => {
            (0..loops.len()).min_by(|&a, &b| mean_y(&loops[a]).total_cmp(&mean_y(&loops[b]))).unwrap_or(0)
        }
    };
    let mut v = loops[k].clone();
    v.sort_unstable();
    v.dedup();
    Ok(v)
}

/// Pinned flags for `n_vertices` from a user list of vertex indices.
///
/// # Errors
/// [`Error::IndexOutOfRange`] for an index past the garment.
pub fn pinned_flags(n_vertices: usize, pins: &[u32]) -> Result<Vec<bool>> {
    let mut flags = vec![false; n_vertices];
    for (k, &p) in pins.iter().enumerate() {
        *flags.get_mut(p as usize).ok_or(Error::IndexOutOfRange {
            what: "pinned vertex",
            at: k,
            index: p as usize,
            len: n_vertices,
        })? = true;
    }
    Ok(flags)
}

/// Garment initialisation: the garment's rest positions skinned with `weights` at `pose` (e.g.
/// a frame of a retargeted clip), into `out`. The physics then pushes it out of the body.
pub fn pose_garment(
    skel: &Skeleton,
    pose: &Pose,
    weights: &SkinWeights,
    garment_rest: &[[f32; 3]],
    out: &mut [[f32; 3]],
) -> Result<()> {
    let mut tr = SkinTransforms::new(skel.len());
    tr.update(skel, pose)?;
    skin(&tr, weights, garment_rest, out)
}

#[cfg(test)]
mod tests;
