//! One step's network inputs for the trainer: the same features, body edges and orders as the
//! runtime's prediction (`sim/predict.rs`) builds, kept un-normalised (the normalisers and
//! embedding tables are applied by the differentiable forward, so that the embeddings can be
//! trained).

use crate::body::{BodyMesh, PointGrid};
use crate::error::{Error, Result};
use crate::exec::Serial;
use crate::features::{
    self, BodyNodes, Embeddings, GarmentNodes, NodeType, BODY_EDGE_WIDTH, LEVELS, NODE_TYPES, NODE_WIDTH,
};
use crate::mesh::{vertex_normals, Garment};
use crate::model::ModelSpec;
use crate::sim::inputs::{node_features, BodyInputs, BodyLinks, FeatureRows};
use crate::sim::Graph;
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
#[derive(Clone, Debug, PartialEq)]
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
    /// Raw edge features per [`EdgeKey`](crate::model::EdgeKey) (indexed `key as usize`), 12 wide, in the graph's edge
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

impl Default for StepData {
    fn default() -> Self {
        StepData {
            dt: 0.0,
            n_garment: 0,
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
            pos: Vec::new(),
            velocity: Vec::new(),
            pinned: Vec::new(),
        }
    }
}

impl StepData {
    /// Builds the step's inputs as the runtime does (`sim/predict.rs`). A training loop should
    /// keep an [`InputBuilder`] instead (same result, no fresh body grid and buffers per call).
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
        let mut d = StepData::default();
        InputBuilder::default().build(spec, garment, graph, state, body, dt, &mut d)?;
        Ok(d)
    }
}

/// Builds [`StepData`] step after step reusing its body grid and buffers (they only grow; the
/// grid is rebuilt in place, and it and the body-edge buffers are remade only when the garment's
/// or the body's vertex count changes). The body edges and features are those of the runtime
/// (`sim::inputs`).
#[derive(Clone, Debug, Default)]
pub struct InputBuilder {
    grid: Option<PointGrid>,
    links: Option<BodyLinks>,
    normals: Vec<[f32; 3]>,
    body_normals: Vec<[f32; 3]>,
    material: Vec<[f32; 3]>,
}

impl InputBuilder {
    /// Writes the step's inputs into `d` (every field replaced), as [`StepData::build`].
    ///
    /// # Errors
    /// As [`StepData::build`].
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        &mut self,
        spec: &ModelSpec,
        garment: &Garment,
        graph: &Graph,
        state: &GarmentState<'_>,
        body: Option<&BodyFrames<'_>>,
        dt: f32,
        d: &mut StepData,
    ) -> Result<()> {
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
        d.dt = dt;
        d.n_garment = n;
        d.n_active = 0;
        d.prefix = [0; 4];
        d.pos.clear();
        d.pos.extend((0..n).map(|i| if state.pinned[i] { state.pin_targets[i] } else { state.pos[i] }));
        d.velocity.clear();
        d.velocity.extend_from_slice(state.velocity);
        d.pinned.clear();
        d.pinned.extend_from_slice(state.pinned);
        let zero_type = [0.0; NODE_TYPES * NODE_TYPES];
        let zero_level = [0.0; LEVELS * LEVELS];
        let emb = Embeddings { node_type: &zero_type, level: &zero_level };
        self.material.clear();
        self.material.extend(garment.materials().iter().map(|m| m.network_inputs()));
        self.normals.clear();
        self.normals.resize(n, [0.0; 3]);
        vertex_normals(garment.faces(), &d.pos, &mut self.normals);
        let gn = GarmentNodes {
            velocity: state.velocity,
            normals: &self.normals,
            mass: garment.vertex_mass(),
            pinned: state.pinned,
            level: &graph.vertex_level,
            material: &self.material,
            dt,
        };
        d.node_type.clear();
        d.node_type.extend(state.pinned.iter().map(|&p| if p { NodeType::Pinned } else { NodeType::Normal } as u8));
        d.node_level.clear();
        d.node_level.extend_from_slice(&graph.vertex_level);
        for v in [&mut d.body_garment, &mut d.body_active, &mut d.active] {
            v.clear();
        }
        let mut seen = None;
        if let (Some(b), true) = (body, spec.effects.body) {
            let nb = b.mesh.n_vertices();
            b.mesh.check_positions(b.pos)?;
            if self.grid.as_ref().is_none_or(|g| g.capacity() != nb) {
                self.grid = Some(PointGrid::new(nb, (8 * nb).max(64))?);
            }
            let grid = self.grid.as_mut().ok_or(Error::Empty { what: "body grid" })?;
            grid.rebuild(b.pos)?;
            if !self.links.as_ref().is_some_and(|l| l.fits(n, nb)) {
                self.links = Some(BodyLinks::new(n, nb));
            }
            let links = self.links.as_mut().ok_or(Error::Empty { what: "body edges" })?;
            let counts = links.link(grid, &Serial, graph, b.mesh, &d.pos)?;
            d.prefix = counts.prefix;
            let edges = links.edges();
            d.body_garment.extend_from_slice(edges.garment);
            d.body_active.extend_from_slice(edges.body);
            d.active.extend_from_slice(links.active());
            d.n_active = d.active.len();
            for &o in &d.active {
                let omitted = b.mesh.omitted().get(o as usize).copied().unwrap_or(false);
                d.node_type.push(if omitted { NodeType::BodyOmitted } else { NodeType::Body } as u8);
                d.node_level.push(0);
            }
            self.body_normals.clear();
            self.body_normals.resize(nb, [0.0; 3]);
            vertex_normals(b.mesh.faces(), b.pos, &mut self.body_normals);
            let nodes =
                BodyNodes { pos: b.pos, prev: b.prev, normals: &self.body_normals, omitted: b.mesh.omitted(), dt };
            seen = Some(BodyInputs { nodes, next: b.next, active: links.active(), pairs: links.pairs() });
        }
        let ne = d.prefix[0];
        d.node_features.clear();
        d.node_features.resize((n + d.n_active) * NODE_WIDTH, 0.0);
        d.g2b_features.clear();
        d.g2b_features.resize(ne * BODY_EDGE_WIDTH, 0.0);
        d.b2g_features.clear();
        d.b2g_features.resize(ne * BODY_EDGE_WIDTH, 0.0);
        let rows = FeatureRows { nodes: &mut d.node_features, g2b: &mut d.g2b_features, b2g: &mut d.b2g_features };
        node_features(&gn, seen.as_ref(), &d.pos, &emb, rows)?;
        let rest = garment.rest();
        for f in &mut d.edge_features {
            f.clear();
        }
        // A model reading a coarse level the graph lacks is refused, not fed empty rows.
        for key in spec.blocks.iter().flat_map(|b| &b.keys) {
            graph.edges(*key)?;
        }
        for (key, list) in graph.edge_sets() {
            if !spec.blocks.iter().any(|b| b.keys.contains(&key)) {
                continue;
            }
            let f = &mut d.edge_features[key as usize];
            f.resize(list.global.len() * features::EDGE_WIDTH, 0.0);
            features::edge_features(&list.global, &d.pos, rest, &self.material, dt, f)?;
        }
        Ok(())
    }
}
