//! Network input features (MODEL.md section 3), assembled into caller-provided row-major
//! buffers so that the runtime and the trainer share one implementation.
//!
//! Positions are metres at the current frame, velocities metres per frame, `dt` seconds.
//! Column order and widths are part of the model contract (they must match reference
//! checkpoints): see the constants below.

use crate::error::{check_len, Error, Result};
use glam::Vec3;

/// Width of a node feature row.
pub const NODE_WIDTH: usize = 24;
/// Leading node columns that are normalised (the material inputs after them are not).
pub const NODE_NORMALISED: usize = 21;
/// Width of a mesh or coarse edge feature row.
pub const EDGE_WIDTH: usize = 12;
/// Leading edge columns that are normalised (the material inputs after them are not).
pub const EDGE_NORMALISED: usize = 9;
/// Width of a body edge feature row (all normalised).
pub const BODY_EDGE_WIDTH: usize = 9;
/// Rows of the node-type embedding table (it is square: 9 x 9).
pub const NODE_TYPES: usize = 9;
/// Rows of the vertex-level embedding table (it is square: 4 x 4).
pub const LEVELS: usize = 4;
/// Start-up ("relaxation") step length, seconds (MODEL.md section 5).
pub const DT_STARTUP: f32 = 1.0 / 3.0;
/// Regular step length, seconds: the model runs at 30 Hz.
pub const DT: f32 = 1.0 / 30.0;

/// Node types, the rows of the node-type embedding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum NodeType {
    /// A free garment vertex.
    Normal = 0,
    /// A body vertex.
    Body = 1,
    /// A body vertex that never receives a body edge (e.g. hands).
    BodyOmitted = 2,
    /// A garment vertex driven to a target (skinned) position.
    Pinned = 3,
}

/// The two learned embedding tables, row-major.
#[derive(Clone, Copy, Debug)]
pub struct Embeddings<'a> {
    /// Node-type table, `NODE_TYPES x NODE_TYPES`.
    pub node_type: &'a [f32],
    /// Vertex-level table, `LEVELS x LEVELS`.
    pub level: &'a [f32],
}

impl Embeddings<'_> {
    fn check(&self) -> Result<()> {
        check_len("node-type embedding", self.node_type.len(), NODE_TYPES * NODE_TYPES)?;
        check_len("vertex-level embedding", self.level.len(), LEVELS * LEVELS)
    }
}

/// Per-vertex inputs of the garment node features.
#[derive(Clone, Copy, Debug)]
pub struct GarmentNodes<'a> {
    /// Velocity, m/frame (MODEL.md section 5: `pos - prev` at the first step, then the previous
    /// step's new velocity).
    pub velocity: &'a [[f32; 3]],
    /// Unit vertex normals at the current positions.
    pub normals: &'a [[f32; 3]],
    /// Vertex masses, kg.
    pub mass: &'a [f32],
    /// Pinned flags (type `Pinned` instead of `Normal`).
    pub pinned: &'a [bool],
    /// Vertex level 0..=3 (deepest coarse level touching the vertex).
    pub level: &'a [u8],
    /// Material network inputs `(bend_in, mu_in, lambda_in)` per vertex.
    pub material: &'a [[f32; 3]],
    /// Step length, s.
    pub dt: f32,
}

/// Writes one 24-wide row per garment vertex into `out` (length `24 n`).
///
/// # Errors
/// [`Error::SizeMismatch`] when an input or `out` has the wrong length;
/// [`Error::OutOfRange`] for a level above 3.
pub fn garment_node_features(g: &GarmentNodes<'_>, emb: &Embeddings<'_>, out: &mut [f32]) -> Result<()> {
    let n = g.velocity.len();
    emb.check()?;
    check_len("garment normals", g.normals.len(), n)?;
    check_len("garment masses", g.mass.len(), n)?;
    check_len("garment pinned flags", g.pinned.len(), n)?;
    check_len("garment levels", g.level.len(), n)?;
    check_len("garment materials", g.material.len(), n)?;
    check_len("garment node features", out.len(), n * NODE_WIDTH)?;
    if let Some(i) = g.level.iter().position(|&l| l as usize >= LEVELS) {
        return Err(Error::OutOfRange { what: "vertex level", index: i });
    }
    for (i, row) in out.chunks_exact_mut(NODE_WIDTH).enumerate() {
        let ty = if g.pinned[i] { NodeType::Pinned } else { NodeType::Normal };
        let [mass_in, b, m, l] = [libm::logf(g.mass[i]), g.material[i][0], g.material[i][1], g.material[i][2]];
        write_node_row(row, g.velocity[i], ty, g.level[i], g.normals[i], g.dt, mass_in, [b, m, l], emb);
    }
    Ok(())
}

/// Per-frame inputs of the body node features.
#[derive(Clone, Copy, Debug)]
pub struct BodyNodes<'a> {
    /// Body positions at the current frame, m.
    pub pos: &'a [[f32; 3]],
    /// Body positions at the previous frame, m.
    pub prev: &'a [[f32; 3]],
    /// Unit vertex normals of the body at the current frame.
    pub normals: &'a [[f32; 3]],
    /// Omitted flags per body vertex (type `BodyOmitted` instead of `Body`), or empty for none.
    pub omitted: &'a [bool],
    /// Step length, s.
    pub dt: f32,
}

/// Writes one 24-wide row per *active* body vertex (`active` lists body vertex indices) into `out`
/// (length `24 active.len()`). Body rows carry level 0, mass input -1 and material inputs -1.
///
/// # Errors
/// [`Error::SizeMismatch`] for inconsistent lengths, [`Error::IndexOutOfRange`] for a bad index.
pub fn body_node_features(b: &BodyNodes<'_>, active: &[u32], emb: &Embeddings<'_>, out: &mut [f32]) -> Result<()> {
    let n = b.pos.len();
    emb.check()?;
    check_len("body previous positions", b.prev.len(), n)?;
    check_len("body normals", b.normals.len(), n)?;
    if !b.omitted.is_empty() {
        check_len("body omitted flags", b.omitted.len(), n)?;
    }
    check_len("body node features", out.len(), active.len() * NODE_WIDTH)?;
    for (k, (&v, row)) in active.iter().zip(out.chunks_exact_mut(NODE_WIDTH)).enumerate() {
        let v = v as usize;
        if v >= n {
            return Err(Error::IndexOutOfRange { what: "active body vertex", at: k, index: v, len: n });
        }
        let vel = (Vec3::from_array(b.pos[v]) - Vec3::from_array(b.prev[v])).to_array();
        let ty = if b.omitted.get(v).copied().unwrap_or(false) { NodeType::BodyOmitted } else { NodeType::Body };
        write_node_row(row, vel, ty, 0, b.normals[v], b.dt, -1.0, [-1.0; 3], emb);
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
#[inline]
fn write_node_row(
    row: &mut [f32],
    vel: [f32; 3],
    ty: NodeType,
    level: u8,
    normal: [f32; 3],
    dt: f32,
    mass_in: f32,
    material: [f32; 3],
    emb: &Embeddings<'_>,
) {
    row[0..3].copy_from_slice(&vel);
    let t = ty as usize * NODE_TYPES;
    row[3..12].copy_from_slice(&emb.node_type[t..t + NODE_TYPES]);
    let l = level as usize * LEVELS;
    row[12..16].copy_from_slice(&emb.level[l..l + LEVELS]);
    row[16..19].copy_from_slice(&normal);
    row[19] = dt;
    row[20] = mass_in;
    row[21..24].copy_from_slice(&material);
}

/// Writes one 12-wide row per directed edge `(source, target)` into `out`:
/// `[x_s - x_r (3), |x_s - x_r|, X_s - X_r (3), |X_s - X_r|, dt, material (3)]` with `x` the
/// current and `X` the rest positions. The material inputs of an edge are the mean of its two
/// vertices' (identical to either for a uniform material). Used for mesh and coarse edges.
///
/// # Errors
/// [`Error::SizeMismatch`] for inconsistent lengths. Edge indices must be in range (they come
/// from the garment's own topology).
pub fn edge_features(
    edges: &[[u32; 2]],
    pos: &[[f32; 3]],
    rest: &[[f32; 3]],
    material: &[[f32; 3]],
    dt: f32,
    out: &mut [f32],
) -> Result<()> {
    check_len("rest positions", rest.len(), pos.len())?;
    check_len("edge materials", material.len(), pos.len())?;
    check_len("edge features", out.len(), edges.len() * EDGE_WIDTH)?;
    for (&[s, r], row) in edges.iter().zip(out.chunks_exact_mut(EDGE_WIDTH)) {
        let (s, r) = (s as usize, r as usize);
        let d = Vec3::from_array(pos[s]) - Vec3::from_array(pos[r]);
        let d0 = Vec3::from_array(rest[s]) - Vec3::from_array(rest[r]);
        row[0..3].copy_from_slice(&d.to_array());
        row[3] = d.length();
        row[4..7].copy_from_slice(&d0.to_array());
        row[7] = d0.length();
        row[8] = dt;
        for c in 0..3 {
            let (a, b) = (material[s][c], material[r][c]);
            row[9 + c] = if a == b { a } else { 0.5 * (a + b) };
        }
    }
    Ok(())
}

/// Writes the two directions of every body edge. `pairs[k] = (garment vertex c, body vertex o)`;
/// with `o'` the body vertex at the next frame, row `k` of `garment_to_body` is
/// `[c - o, |c - o|, c - o', |c - o'|, dt]` and row `k` of `body_to_garment` is
/// `[o - c, |o - c|, o' - c, |o' - c|, dt]` (always source minus target).
///
/// # Errors
/// [`Error::SizeMismatch`] for inconsistent lengths. Indices must be in range.
pub fn body_edge_features(
    pairs: &[[u32; 2]],
    garment_pos: &[[f32; 3]],
    body_pos: &[[f32; 3]],
    body_next: &[[f32; 3]],
    dt: f32,
    garment_to_body: &mut [f32],
    body_to_garment: &mut [f32],
) -> Result<()> {
    check_len("body next positions", body_next.len(), body_pos.len())?;
    check_len("garment->body features", garment_to_body.len(), pairs.len() * BODY_EDGE_WIDTH)?;
    check_len("body->garment features", body_to_garment.len(), pairs.len() * BODY_EDGE_WIDTH)?;
    let rows = garment_to_body.chunks_exact_mut(BODY_EDGE_WIDTH).zip(body_to_garment.chunks_exact_mut(BODY_EDGE_WIDTH));
    for (&[c, o], (g2b, b2g)) in pairs.iter().zip(rows) {
        let c = Vec3::from_array(garment_pos[c as usize]);
        let (o, o1) = (Vec3::from_array(body_pos[o as usize]), Vec3::from_array(body_next[o as usize]));
        let (d, d1) = (c - o, c - o1);
        g2b[0..3].copy_from_slice(&d.to_array());
        g2b[3] = d.length();
        g2b[4..7].copy_from_slice(&d1.to_array());
        g2b[7] = d1.length();
        g2b[8] = dt;
        b2g[0..3].copy_from_slice(&(-d).to_array());
        b2g[3] = g2b[3];
        b2g[4..7].copy_from_slice(&(-d1).to_array());
        b2g[7] = g2b[7];
        b2g[8] = dt;
    }
    Ok(())
}
