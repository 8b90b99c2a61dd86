//! The named workloads of EVALUATION.md, built in one place for the command line, the benches
//! and the report. Procedural ones need no files; asset ones read `../shared` (or a given
//! folder) and fail with [`Error::Io`] when it is absent.

use crate::body::BodyMesh;
use crate::error::{Error, Result};
use crate::io::safetensors::SafeTensors;
use crate::mesh::{shapes, Garment, GarmentDesc};
use crate::sim::{Graph, SimState};
use std::path::{Path, PathBuf};
use std::string::{String, ToString};
use std::vec::Vec;

/// A scene to step: a garment, optionally a body with its frames, optionally a fixed start
/// state (then every timed step restarts from it, so each measures the same step).
pub struct Workload {
    /// Name as in EVALUATION.md.
    pub name: String,
    /// The garment (pinned flags set).
    pub garment: Garment,
    /// Body topology and positions per frame (at least two frames).
    pub body: Option<(BodyMesh, Vec<Vec<[f32; 3]>>)>,
    /// A start state to restore before every step (the parity fixture's scene).
    pub fixed_state: Option<SimState>,
    /// A prepared graph (the fixture's reference coarse edges), if any.
    pub graph: Option<Graph>,
}

/// Names [`workload`] knows.
pub const NAMES: &[&str] = &["grid-1k", "tee", "tee-sub"];

/// `../shared` next to the crate's source checkout.
pub fn default_shared_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared"))
}

/// Builds workload `name`; asset workloads read `shared` (see [`default_shared_dir`]).
///
/// # Errors
/// [`Error::Parse`] for an unknown name; [`Error::Io`] when the files it needs are absent.
pub fn workload(name: &str, shared: &Path) -> Result<Workload> {
    match name {
        "grid-1k" => grid_1k(),
        "tee" => fixture_tee(shared, false),
        "tee-sub" => fixture_tee(shared, true),
        _ => Err(Error::parse("workload", 0, std::format!("unknown workload '{name}' (known: {})", NAMES.join(", ")))),
    }
}

/// `grid-1k`: a 32 x 32 square cloth (1,024 vertices, 1 m), pinned at two corners, no body.
fn grid_1k() -> Result<Workload> {
    let n = 32;
    let (rest, faces) = shapes::grid(n, n, 1.0, 1.0, 1.0);
    let mut pinned = std::vec![false; rest.len()];
    pinned[0] = true;
    pinned[n - 1] = true;
    let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned))?;
    Ok(Workload { name: "grid-1k".to_string(), garment, body: None, fixed_state: None, graph: None })
}

/// `tee` / `tee-sub`: the reference fixture's scene (the MakeHuman t-shirt on the 13,380-vertex
/// body, one step) and its one-step midpoint subdivision (5,148 vertices).
fn fixture_tee(shared: &Path, subdivide: bool) -> Result<Workload> {
    let path = shared.join("fixtures/hood-parity/fixture_scene.safetensors");
    let st = SafeTensors::read(&path)?;
    let rows = |n: &str| -> Result<Vec<[f32; 3]>> { st.f32(n)?.rows::<3>() };
    let tris = |n: &str| -> Result<Vec<[u32; 3]>> {
        Ok(st.i64(n)?.rows::<3>()?.iter().map(|f| f.map(|v| v as u32)).collect())
    };
    let (mut rest, mut faces) = (rows("cloth_rest_pos")?, tris("cloth_faces")?);
    let (mut pos, mut prev) = (rows("cloth_pos")?, rows("cloth_prev_pos")?);
    let mut graph = None;
    if subdivide {
        let f0 = faces.clone();
        (rest, faces) = shapes::subdivide(&rest, &f0);
        pos = shapes::subdivide(&pos, &f0).0;
        prev = shapes::subdivide(&prev, &f0).0;
    }
    let garment = Garment::new(GarmentDesc::new(&rest, &faces))?;
    if !subdivide {
        let coarse = (0..3)
            .map(|l| -> Result<Vec<[u32; 2]>> {
                let t = st.i64(&std::format!("coarse_edge_index{l}"))?;
                let e = t.shape[1] / 2;
                Ok((0..e).map(|k| [t.data[k] as u32, t.data[t.shape[1] + k] as u32]).collect())
            })
            .collect::<Result<Vec<_>>>()?;
        let level: Vec<u8> = st.i64("cloth_vertex_level")?.data.iter().map(|&l| l as u8).collect();
        graph = Some(Graph::from_parts(&garment, &coarse, &level)?);
    }
    let velocity = pos.iter().zip(&prev).map(|(p, q)| [p[0] - q[0], p[1] - q[1], p[2] - q[2]]).collect();
    let (bprev, bpos, bnext) = (rows("body_prev_pos")?, rows("body_pos")?, rows("body_target_pos")?);
    let body = BodyMesh::new(bpos.len(), &tris("body_faces")?)?;
    let state = SimState { pos, velocity, body_prev: bprev, body_pos: bpos.clone(), started: true };
    Ok(Workload {
        name: if subdivide { "tee-sub" } else { "tee" }.to_string(),
        garment,
        body: Some((body, std::vec![bpos, bnext])),
        fixed_state: Some(state),
        graph,
    })
}
