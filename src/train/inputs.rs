//! One step's network inputs for the trainer: the same features, body edges and orders as
//! `Sim::advance` builds, kept un-normalised (the normalisers and embedding tables are applied
//! by the differentiable forward, so that the embeddings can be trained).

use crate::body::{BodyMesh, Nearest, PointGrid};
use crate::error::{Error, Result};
use crate::features::{
    self, BodyNodes, Embeddings, GarmentNodes, NodeType, BODY_EDGE_WIDTH, LEVELS, NODE_TYPES, NODE_WIDTH,
};
use crate::mesh::{vertex_normals, Garment};
use crate::model::{EdgeKey, ModelSpec};
use crate::sim::{Graph, BODY_EDGE_RADIUS};
use alloc::vec;
use alloc::vec::Vec;

/// The body at the three frames a step reads, m.
#[derive(Clone, Copy, Debug)]
pub struct BodyFrames<'a> {
    /// Topology (and omitted vertices).
    pub mesh: &'a BodyMesh,
    /// Previous frame (equal to `pos` at the start-up step).
    pub prev: &'a [[f32; 3]],
    /// Current frame.
    pub pos: &'a [[f32; 3]],
    /// Next frame (equal to `pos` at the start-up step).
    pub next: &'a [[f32; 3]],
}

/// The garment state a step starts from.
#[derive(Clone, Copy, Debug)]
pub struct GarmentState<'a> {
    /// Positions at the current frame, m.
    pub pos: &'a [[f32; 3]],
    /// Velocities, m/frame.
    pub velocity: &'a [[f32; 3]],
    /// Pinned flags (all false to ignore pinning).
    pub pinned: &'a [bool],
    /// Targets of the pinned vertices at the next frame, m (only pinned entries are read).
    pub pin_targets: &'a [[f32; 3]],
}

/// Everything the network reads in one step besides its parameters.
#[derive(Clone, Debug)]
pub struct StepData {
    /// Step length, s.
    pub dt: f32,
    /// Garment vertices.
    pub n_garment: usize,
    /// Active body nodes (body vertices with a body edge).
    pub n_active: usize,
    /// Raw node features, garment then active body rows, 24 wide. Columns 3..16 (the
    /// embeddings) are zero here: the forward writes them from the current tables.
    pub node_features: Vec<f32>,
    /// Node type (embedding row) per node row.
    pub node_type: Vec<u8>,
    /// Vertex level (embedding row) per node row.
    pub node_level: Vec<u8>,
    /// Raw edge features per [`EdgeKey`] (indexed `key as usize`), 12 wide, in the graph's edge
    /// order; empty for keys no block uses.
    pub edge_features: [Vec<f32>; 4],
    /// Raw garment->body edge features, 9 wide, in [`Graph::body_order`] order.
    pub g2b_features: Vec<f32>,
    /// Raw body->garment edge features, 9 wide.
    pub b2g_features: Vec<f32>,
    /// Garment vertex of each body edge.
    pub body_garment: Vec<u32>,
    /// Active body row of each body edge.
    pub body_active: Vec<u32>,
    /// Body vertex of each active body row.
    pub active: Vec<u32>,
    /// Body edges whose garment end is in all / c0 / c1 / c2 nodes (a prefix each).
    pub prefix: [usize; 4],
    /// Garment positions the network sees (pinned vertices at their targets), m.
    pub pos: Vec<[f32; 3]>,
    /// Garment velocities, m/frame.
    pub velocity: Vec<[f32; 3]>,
    /// Pinned flags.
    pub pinned: Vec<bool>,
}

impl StepData {
    /// Builds the step's inputs as the runtime does (`Sim::advance`).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for inconsistent lengths; errors of the body queries and features.
    pub fn build(
        spec: &ModelSpec,
        garment: &Garment,
        graph: &Graph,
        state: &GarmentState<'_>,
        body: Option<&BodyFrames<'_>>,
        dt: f32,
    ) -> Result<StepData> {
        let n = garment.n_vertices();
        for (what, got) in [
            ("state positions", state.pos.len()),
            ("state velocities", state.velocity.len()),
            ("pinned flags", state.pinned.len()),
            ("pin targets", state.pin_targets.len()),
            ("graph vertices", graph.n_vertices()),
        ] {
            if got != n {
                return Err(Error::SizeMismatch { what, expected: n, got });
            }
        }
        let pos: Vec<[f32; 3]> =
            (0..n).map(|i| if state.pinned[i] { state.pin_targets[i] } else { state.pos[i] }).collect();
        let zero_type = [0.0; NODE_TYPES * NODE_TYPES];
        let zero_level = [0.0; LEVELS * LEVELS];
        let emb = Embeddings { node_type: &zero_type, level: &zero_level };
        let material: Vec<[f32; 3]> = garment.materials().iter().map(|m| m.network_inputs()).collect();
        let mut normals = vec![[0.0; 3]; n];
        vertex_normals(garment.faces(), &pos, &mut normals);
        let mut node_features = vec![0.0; n * NODE_WIDTH];
        let gn = GarmentNodes {
            velocity: state.velocity,
            normals: &normals,
            mass: garment.vertex_mass(),
            pinned: state.pinned,
            level: &graph.vertex_level,
            material: &material,
            dt,
        };
        features::garment_node_features(&gn, &emb, &mut node_features)?;
        let mut node_type: Vec<u8> =
            state.pinned.iter().map(|&p| if p { NodeType::Pinned } else { NodeType::Normal } as u8).collect();
        let mut node_level = graph.vertex_level.clone();

        let mut d = StepData {
            dt,
            n_garment: n,
            n_active: 0,
            node_features: Vec::new(),
            node_type: Vec::new(),
            node_level: Vec::new(),
            edge_features: [Vec::new(), Vec::new(), Vec::new(), Vec::new()],
            g2b_features: Vec::new(),
            b2g_features: Vec::new(),
            body_garment: Vec::new(),
            body_active: Vec::new(),
            active: Vec::new(),
            prefix: [0; 4],
            pos,
            velocity: state.velocity.to_vec(),
            pinned: state.pinned.to_vec(),
        };
        if let (Some(b), true) = (body, spec.effects.body) {
            let nb = b.mesh.n_vertices();
            b.mesh.check_positions(b.pos)?;
            let mut grid = PointGrid::new(nb, (8 * nb).max(64))?;
            grid.rebuild(b.pos)?;
            let mut nearest: Vec<Option<Nearest>> = vec![None; n];
            grid.nearest_within(&d.pos, BODY_EDGE_RADIUS, &mut nearest)?;
            b.mesh.keep_not_omitted(&mut nearest);
            let mut body_vertex = Vec::new();
            for &g in &graph.body_order {
                if let Some(near) = nearest[g as usize] {
                    d.body_garment.push(g);
                    body_vertex.push(near.index);
                    let lvl = graph.vertex_level[g as usize] as usize;
                    for p in d.prefix.iter_mut().take(lvl + 1) {
                        *p += 1;
                    }
                }
            }
            // Active body rows in ascending body vertex order.
            let mut active_of = vec![u32::MAX; nb];
            for &o in &body_vertex {
                active_of[o as usize] = 0;
            }
            for (o, a) in active_of.iter_mut().enumerate() {
                if *a == 0 {
                    *a = d.active.len() as u32;
                    d.active.push(o as u32);
                }
            }
            d.body_active = body_vertex.iter().map(|&o| active_of[o as usize]).collect();
            d.n_active = d.active.len();
            let mut bnormals = vec![[0.0; 3]; nb];
            vertex_normals(b.mesh.faces(), b.pos, &mut bnormals);
            let bn = BodyNodes { pos: b.pos, prev: b.prev, normals: &bnormals, omitted: b.mesh.omitted(), dt };
            let mut rows = vec![0.0; d.n_active * NODE_WIDTH];
            features::body_node_features(&bn, &d.active, &emb, &mut rows)?;
            node_features.extend_from_slice(&rows);
            for &o in &d.active {
                let omitted = b.mesh.omitted().get(o as usize).copied().unwrap_or(false);
                node_type.push(if omitted { NodeType::BodyOmitted } else { NodeType::Body } as u8);
                node_level.push(0);
            }
            let pairs: Vec<[u32; 2]> = d.body_garment.iter().zip(&body_vertex).map(|(&g, &o)| [g, o]).collect();
            let ne = pairs.len();
            d.g2b_features = vec![0.0; ne * BODY_EDGE_WIDTH];
            d.b2g_features = vec![0.0; ne * BODY_EDGE_WIDTH];
            features::body_edge_features(&pairs, &d.pos, b.pos, b.next, dt, &mut d.g2b_features, &mut d.b2g_features)?;
        }
        d.node_features = node_features;
        d.node_type = node_type;
        d.node_level = node_level;
        let rest = garment.rest();
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            if !spec.blocks.iter().any(|b| b.keys.contains(&key)) {
                continue;
            }
            let list = match key.coarse_level() {
                None => &graph.mesh,
                Some(l) => {
                    &graph
                        .coarse
                        .get(l)
                        .ok_or(Error::IncompatibleModel {
                            reason: "the model uses a coarse level the garment graph lacks",
                        })?
                        .edges
                }
            };
            let mut f = vec![0.0; list.global.len() * features::EDGE_WIDTH];
            features::edge_features(&list.global, &d.pos, rest, &material, dt, &mut f)?;
            d.edge_features[key as usize] = f;
        }
        Ok(d)
    }
}
