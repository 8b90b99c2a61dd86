//! The named workloads of EVALUATION.md (feature `tools`), built in one place for the command line,
//! the benches and the report. Procedural ones need no files; asset ones read the parity fixtures
//! beside the assets folder ([`crate::assets`]) and fail with [`Error::Io`] when they are absent.

use crate::body::BodyMesh;
use crate::error::{Error, Result};
use crate::io::safetensors::SafeTensors;
use crate::mesh::{shapes, Garment, GarmentDesc};
use crate::rig::procedural::Mannequin;
use crate::scene::{self, GarmentKind, MotionKind};
use crate::sim::{Graph, Sim, SimState};
use std::path::Path;
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
    /// The garment worn through a body motion, frame by frame (the procedural scenes).
    pub worn: Option<WornSequence>,
}

/// A garment worn on a moving body, as start states for the timed steps: step `t` restarts from
/// `states[t % len]` (the garment skinned to body frame `k + 1` and pushed out of the body, its
/// velocity the skinned motion since frame `k`), sets the pinned vertices' targets to
/// `pin_targets[t % len]` (frame `k + 2`) and steps the body to frame `k + 2`. So every timed
/// step is a step of a garment worn on the walking body, with a realistic number of body edges,
/// whatever the (random) weights of the timed model do to the garment.
pub struct WornSequence {
    /// Start state per step, at 30 Hz.
    pub states: Vec<SimState>,
    /// Targets of the pinned vertices per step (one entry per garment vertex), m.
    pub pin_targets: Vec<Vec<[f32; 3]>>,
}

impl Workload {
    /// Whether a [`Sim`] of this workload runs the start-up step (not when every timed step
    /// restarts from a prepared state).
    pub fn startup(&self) -> bool {
        self.fixed_state.is_none() && self.worn.is_none()
    }

    /// Readies `sim` (built for this workload, body collision on) for timed step `t`: restores
    /// the step's start state and pin targets, if the workload has them. Returns the body
    /// positions to pass to [`Sim::step`] (empty without a body).
    ///
    /// # Errors
    /// Errors of [`Sim::set_state`] and [`Sim::set_pin_targets`] (a sim of another workload).
    pub fn prepare_step(&self, sim: &mut Sim<'_>, t: usize) -> Result<&[[f32; 3]]> {
        if let Some(w) = &self.worn {
            let k = t % w.states.len();
            sim.set_state(&w.states[k])?;
            sim.set_pin_targets(&w.pin_targets[k])?;
        } else if let Some(s) = &self.fixed_state {
            sim.set_state(s)?;
        }
        Ok(match &self.body {
            Some((_, frames)) if sim.config().body_collision => match &self.worn {
                Some(w) => &frames[(t % w.states.len()) + 2],
                None => &frames[1 + t % (frames.len() - 1)],
            },
            _ => &[],
        })
    }
}

/// Names [`workload`] knows.
pub const NAMES: &[&str] = &["grid-1k", "skirt-4k", "dress-12k", "tee", "tee-sub"];

/// Seconds of the walk the procedural workloads step through (30 frames at 30 Hz).
pub const WALK_SECONDS: f32 = 1.0;

/// Builds workload `name`; asset workloads (`tee`, `tee-sub`) read the parity fixtures beside
/// `assets` ([`crate::assets::fixtures`]).
///
/// # Errors
/// [`Error::Parse`] for an unknown name; [`Error::Io`] when the files it needs are absent.
pub fn workload(name: &str, assets: &Path) -> Result<Workload> {
    match name {
        "grid-1k" => grid_1k(),
        "skirt-4k" => worn_procedural("skirt-4k", GarmentKind::Skirt, 4400),
        "dress-12k" => worn_procedural("dress-12k", GarmentKind::Dress, 12_000),
        "tee" => fixture_tee(assets, false),
        "tee-sub" => fixture_tee(assets, true),
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
    Ok(Workload { name: "grid-1k".to_string(), garment, body: None, fixed_state: None, graph: None, worn: None })
}

/// `skirt-4k` / `dress-12k`: a procedural garment of about `vertices` vertices (its suggested
/// pins set) on the procedural mannequin walking for [`WALK_SECONDS`], as a [`WornSequence`].
fn worn_procedural(name: &str, kind: GarmentKind, vertices: usize) -> Result<Workload> {
    let sc = scene::procedural(&Mannequin::new(), kind, vertices, MotionKind::Walk, WALK_SECONDS)?;
    let frames = sc.n_frames();
    if frames < 3 {
        return Err(Error::Empty { what: "walk frames" });
    }
    let worn: Vec<Vec<[f32; 3]>> = (0..frames).map(|f| sc.initial_garment(f)).collect::<Result<_>>()?;
    let body: Vec<Vec<[f32; 3]>> = (0..frames).map(|f| sc.body_frame(f).to_vec()).collect();
    let n = sc.garment.n_vertices();
    let mut states = Vec::with_capacity(frames - 2);
    let mut pin_targets = Vec::with_capacity(frames - 2);
    for k in 0..frames - 2 {
        let velocity = worn[k + 1].iter().zip(&worn[k]).map(|(p, q)| [0, 1, 2].map(|a| p[a] - q[a])).collect();
        states.push(SimState {
            pos: worn[k + 1].clone(),
            velocity,
            body_prev: body[k].clone(),
            body_pos: body[k + 1].clone(),
            started: true,
        });
        let mut pins = std::vec![[0.0; 3]; n];
        sc.skinned_garment(k + 2, &mut pins)?;
        pin_targets.push(pins);
    }
    Ok(Workload {
        name: name.to_string(),
        garment: sc.garment,
        body: Some((sc.body, body)),
        fixed_state: None,
        graph: None,
        worn: Some(WornSequence { states, pin_targets }),
    })
}

/// `tee` / `tee-sub`: the reference fixture's scene (the MakeHuman t-shirt on the 13,380-vertex
/// body, one step) and its one-step midpoint subdivision (5,148 vertices).
fn fixture_tee(assets: &Path, subdivide: bool) -> Result<Workload> {
    let path = crate::assets::fixtures(assets).join("hood-parity/fixture_scene.safetensors");
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
        worn: None,
    })
}

/// The scene of a fixed-state workload (`tee`, `tee-sub`) in the layout of the parity fixture's
/// `fixture_scene.safetensors` (positions in m, y up; edge indices `(2, E)` with both directions
/// of each edge), as safetensors bytes: what `tools/reference/forward.py` reads to time the
/// reference network's forward on the same garment, graph and body as `hood bench`. The coarse
/// edges and vertex levels are this crate's (the fixture's own for `tee`).
///
/// # Errors
/// [`Error::UnsupportedEffect`] for a workload without a body or a fixed start state (the
/// procedural ones); errors of the garment's hierarchy.
pub fn reference_scene(w: &Workload) -> Result<Vec<u8>> {
    use crate::io::safetensors::{to_bytes, TensorData};
    let (Some((mesh, frames)), Some(state)) = (&w.body, &w.fixed_state) else {
        return Err(Error::UnsupportedEffect { effect: "reference scene of a workload without a fixed state" });
    };
    let graph = match &w.graph {
        Some(g) => g.clone(),
        // As the bench's sim builds it for HOOD's architecture.
        None => Graph::build(&w.garment, crate::hierarchy::DEFAULT_LEVELS)?,
    };
    let flat = |rows: &[[f32; 3]]| -> Vec<f32> { rows.iter().flatten().copied().collect() };
    let faces = |f: &[[u32; 3]]| -> Vec<i64> { f.iter().flatten().map(|&v| v as i64).collect() };
    let edges =
        |e: &[[u32; 2]]| -> Vec<i64> { e.iter().map(|p| p[0] as i64).chain(e.iter().map(|p| p[1] as i64)).collect() };
    let prev: Vec<[f32; 3]> =
        state.pos.iter().zip(&state.velocity).map(|(p, v)| [p[0] - v[0], p[1] - v[1], p[2] - v[2]]).collect();
    let material = w.garment.materials().first().copied().unwrap_or_default();
    let (v, b) = (w.garment.n_vertices(), state.body_pos.len());
    let (rest, pos, prev) = (flat(w.garment.rest()), flat(&state.pos), flat(&prev));
    let (body_prev, body_pos, body_next) = (flat(&state.body_prev), flat(&state.body_pos), flat(&frames[1]));
    let (cloth_faces, body_faces) = (faces(w.garment.faces()), faces(mesh.faces()));
    let level: Vec<i64> = graph.vertex_level.iter().map(|&l| l as i64).collect();
    let mesh_edges = edges(&graph.mesh.global);
    let coarse: Vec<Vec<i64>> = graph.coarse.iter().map(|c| edges(&c.edges.global)).collect();
    let names: Vec<String> = (0..coarse.len()).map(|l| std::format!("coarse_edge_index{l}")).collect();
    let inputs = material.network_inputs();
    let dt = [crate::features::DT];
    // Owned shapes first: the tensor list borrows them.
    let (v3, b3, v1) = ([v, 3], [b, 3], [v]);
    let (cf, bf) = ([cloth_faces.len() / 3, 3], [body_faces.len() / 3, 3]);
    let (three, one, mesh_shape) = ([3], [1], [2, mesh_edges.len() / 2]);
    let coarse_shapes: Vec<[usize; 2]> = coarse.iter().map(|c| [2, c.len() / 2]).collect();
    let mut tensors: Vec<(&str, &[usize], TensorData<'_>)> = std::vec![
        ("cloth_rest_pos", &v3, TensorData::F32(&rest)),
        ("cloth_pos", &v3, TensorData::F32(&pos)),
        ("cloth_prev_pos", &v3, TensorData::F32(&prev)),
        ("cloth_faces", &cf, TensorData::I64(&cloth_faces)),
        ("cloth_v_mass", &v1, TensorData::F32(w.garment.vertex_mass())),
        ("cloth_vertex_level", &v1, TensorData::I64(&level)),
        ("body_pos", &b3, TensorData::F32(&body_pos)),
        ("body_prev_pos", &b3, TensorData::F32(&body_prev)),
        ("body_target_pos", &b3, TensorData::F32(&body_next)),
        ("body_faces", &bf, TensorData::I64(&body_faces)),
        ("material_inputs_bending_mu_lambda", &three, TensorData::F32(&inputs)),
        ("timestep", &one, TensorData::F32(&dt)),
        ("mesh_edge_index", &mesh_shape, TensorData::I64(&mesh_edges)),
    ];
    for ((name, c), shape) in names.iter().zip(&coarse).zip(&coarse_shapes) {
        tensors.push((name, shape, TensorData::I64(c)));
    }
    to_bytes(&tensors, &[("source", "hood::workloads::reference_scene")])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{write_model, ModelBytes, ModelSpec, Normalisers, Params};
    use crate::sim::{BodyDesc, SimConfig};

    #[test]
    fn workloads_worn_sequence_steps_through_the_walk() {
        let w = worn_procedural("skirt-small", GarmentKind::Skirt, 300).unwrap();
        let worn = w.worn.as_ref().unwrap();
        let (_, frames) = w.body.as_ref().unwrap();
        assert_eq!(worn.states.len(), frames.len() - 2);
        assert!(!w.startup());
        let pinned: Vec<usize> = (0..w.garment.n_vertices()).filter(|&i| w.garment.pinned()[i]).collect();
        assert!(!pinned.is_empty(), "the skirt's waist is pinned");
        for (k, s) in worn.states.iter().enumerate() {
            assert!(s.started);
            assert_eq!(s.body_prev, frames[k]);
            assert_eq!(s.body_pos, frames[k + 1]);
        }
        // The waist's targets move with the walk from step to step.
        let last = worn.pin_targets.len() - 1;
        let moved = pinned.iter().map(|&i| (worn.pin_targets[last][i][2] - worn.pin_targets[0][i][2]).abs());
        assert!(moved.fold(0.0f32, f32::max) > 0.2, "pins should follow the walking body");

        let mut p = Params::init(&ModelSpec::hood(8), 0).unwrap();
        p.normalisers = Normalisers::unit_scale(1);
        let bytes = ModelBytes::new(&write_model(&p, false, &[]).unwrap());
        let model = bytes.model().unwrap();
        let (mesh, frames) = w.body.as_ref().unwrap();
        let cfg = SimConfig { startup: w.startup(), ..SimConfig::network() };
        let mut sim = Sim::new(&model, &w.garment, Some(BodyDesc { mesh, positions: &frames[0] }), cfg).unwrap();
        for t in [0, 1, worn.states.len() + 3] {
            let k = t % worn.states.len();
            let next = w.prepare_step(&mut sim, t).unwrap();
            assert_eq!(next, &frames[k + 2][..], "step {t} goes to frame {}", k + 2);
            assert_eq!(sim.state().pos, worn.states[k].pos, "step {t} restarts from its state");
            let out = sim.step(next).unwrap();
            for &i in &pinned {
                assert_eq!(out[i], worn.pin_targets[k][i], "step {t}: pinned vertex {i} sits at its target");
            }
        }
    }
}
