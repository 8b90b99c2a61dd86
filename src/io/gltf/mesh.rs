//! The skinned meshes: every primitive's positions, triangles and joint influences, merged,
//! read by the `gltf` crate's primitive reader after [`accessor::check`].

use super::{accessor, buffers, err};
use crate::error::{Error, Result};
use crate::limits;
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::{Mode, Semantic};
use std::borrow::Cow;
use std::format;
use std::vec;
use std::vec::Vec;

/// The merged mesh of the skinned meshes: positions (bind space), triangles and
/// `(vertex, skin joint, weight)` triples with the influences per vertex.
pub(super) struct RawMesh {
    pub(super) positions: Vec<[f32; 3]>,
    pub(super) triangles: Vec<[u32; 3]>,
    pub(super) triples: Vec<(u32, u16, f32)>,
    pub(super) max_influences: usize,
}

/// Reads `meshes` (skinned by a skin of `n_joints` joints), all their primitives merged in order.
pub(super) fn read(buffers: &[Cow<'_, [u8]>], meshes: &[gltf::Mesh], n_joints: usize) -> Result<RawMesh> {
    // Counts first, so that an absurd body is refused before anything is allocated for it.
    let (mut nv, mut nt) = (0usize, 0usize);
    for m in meshes {
        for p in m.primitives() {
            let count = p.get(&Semantic::Positions).map_or(0, |a| a.count());
            nv = nv.saturating_add(count);
            nt = nt.saturating_add(p.indices().map_or(count, |a| a.count()) / 3);
        }
    }
    limits::body(nv, nt)?;
    let mut out = RawMesh {
        positions: Vec::with_capacity(nv),
        triangles: Vec::with_capacity(nt),
        triples: Vec::new(),
        max_influences: 4,
    };
    for m in meshes {
        let mesh_name = m.name().map_or_else(|| format!("mesh {}", m.index()), |s| format!("mesh '{s}'"));
        for p in m.primitives() {
            read_primitive(buffers, &p, &format!("{mesh_name} primitive {}", p.index()), n_joints, &mut out)?;
        }
    }
    if out.triangles.is_empty() {
        return Err(Error::Empty { what: "glTF skinned mesh triangles" });
    }
    Ok(out)
}

/// Appends a primitive (named `at` in errors) to `out`.
fn read_primitive(
    buffers: &[Cow<'_, [u8]>],
    p: &gltf::Primitive,
    at: &str,
    n_joints: usize,
    out: &mut RawMesh,
) -> Result<()> {
    if p.mode() != Mode::Triangles {
        return Err(err(format!("{at}: mode {:?} (only triangle lists are read)", p.mode())));
    }
    let reader = p.reader(buffers::lookup(buffers));
    let acc = p.get(&Semantic::Positions).ok_or_else(|| err(format!("{at}: no POSITION")))?;
    let what = accessor::label(&format!("{at} POSITION"), &acc);
    let n = accessor::check(buffers, &acc, &what, Dimensions::Vec3, &[DataType::F32], limits::MAX_VERTICES)?;
    let pos = accessor::collect(n, &what, || reader.read_positions())?;
    accessor::finite(pos.as_flattened(), 3, &what)?;
    let base = out.positions.len();
    // Re-checked against the limit: sparse or repeated accessors cannot grow the body.
    limits::body(base + n, 0)?;
    out.positions.extend_from_slice(&pos);

    let indices = match p.indices() {
        Some(acc) => {
            let what = accessor::label(&format!("{at} indices"), &acc);
            let types = [DataType::U8, DataType::U16, DataType::U32];
            let max = limits::MAX_FACES.saturating_mul(3);
            let k = accessor::check_integers(buffers, &acc, &what, Dimensions::Scalar, &types, max)?;
            accessor::collect(k, &what, || reader.read_indices().map(|i| i.into_u32()))?
        }
        None => (0..n as u32).collect(),
    };
    if indices.len() % 3 != 0 {
        return Err(err(format!("{at}: {} indices is not a whole number of triangles", indices.len())));
    }
    limits::body(0, out.triangles.len() + indices.len() / 3)?;
    for (t, tri) in indices.chunks_exact(3).enumerate() {
        let mut f = [0u32; 3];
        for (k, &v) in tri.iter().enumerate() {
            if v as usize >= n {
                return Err(err(format!("{at}: triangle {t} names vertex {v}, but the primitive has {n} vertices")));
            }
            f[k] = (base + v as usize) as u32;
        }
        out.triangles.push(f);
    }

    // Influence sets: JOINTS_k with WEIGHTS_k.
    let mut sets: Vec<u32> = p
        .attributes()
        .filter_map(|(s, _)| match s {
            Semantic::Joints(k) | Semantic::Weights(k) => Some(k),
            _ => None,
        })
        .collect();
    sets.sort_unstable();
    sets.dedup();
    if sets.is_empty() {
        return Err(err(format!("{at}: no JOINTS_0/WEIGHTS_0 (the primitive is not skinned)")));
    }
    out.max_influences = out.max_influences.max(4 * sets.len());
    let mut weighted = vec![false; n];
    for &k in &sets {
        let (Some(ja), Some(wa)) = (p.get(&Semantic::Joints(k)), p.get(&Semantic::Weights(k))) else {
            return Err(err(format!("{at}: JOINTS_{k} and WEIGHTS_{k} must come together")));
        };
        let what = accessor::label(&format!("{at} JOINTS_{k}"), &ja);
        let types = [DataType::U8, DataType::U16];
        let nj = accessor::check_integers(buffers, &ja, &what, Dimensions::Vec4, &types, limits::MAX_VERTICES)?;
        let joints = accessor::collect(nj, &what, || reader.read_joints(k).map(|j| j.into_u16()))?;
        let what = accessor::label(&format!("{at} WEIGHTS_{k}"), &wa);
        let types = [DataType::F32, DataType::U8, DataType::U16];
        let nw = accessor::check(buffers, &wa, &what, Dimensions::Vec4, &types, limits::MAX_VERTICES)?;
        let weights = accessor::collect(nw, &what, || reader.read_weights(k).map(|w| w.into_f32()))?;
        accessor::finite(weights.as_flattened(), 4, &what)?;
        if nj != n || nw != n {
            return Err(err(format!("{at}: JOINTS_{k} has {nj} and WEIGHTS_{k} {nw} elements for {n} vertices")));
        }
        for (v, (js, ws)) in joints.iter().zip(&weights).enumerate() {
            for (&j, &w) in js.iter().zip(ws) {
                if w <= 0.0 {
                    continue;
                }
                if j as usize >= n_joints {
                    return Err(err(format!(
                        "{at}: vertex {v} names joint {j} in JOINTS_{k}, but the skin has {n_joints} joints"
                    )));
                }
                weighted[v] = true;
                out.triples.push(((base + v) as u32, j, w));
            }
        }
    }
    if let Some(v) = weighted.iter().position(|&w| !w) {
        return Err(err(format!("{at}: vertex {v} has no positive skin weight")));
    }
    Ok(())
}
