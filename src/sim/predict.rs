//! The network's prediction of a pass (HOOD, [`StepMode::Network`](super::StepMode::Network)),
//! as stages: the body's frames as the network sees them under the speed limit, the body edges,
//! the features, the edge encoders, the forward pass and the integration of its accelerations.
//!
//! Every stage works in the speed limit's frame of reference, translated to coincide with the
//! world at the current frame (see [`Pass`]); positions are in metres, velocities in m/frame.

use super::body_query::BodyQuery;
use super::graph::Graph;
use super::inputs::{node_features, BodyInputs, BodyLinks, FeatureRows};
use super::network::{BodyEdges, Net, Probe, Workspace};
use super::stages::Pass;
use super::{body_query, BodyState, Sim, SimState};
use crate::error::{Error, Result};
use crate::exec::Executor;
use crate::features::{self, BodyNodes, Embeddings, GarmentNodes, BODY_EDGE_WIDTH, NODE_WIDTH};
use crate::math::finite3;
use crate::mesh::vertex_normals;
use alloc::vec;
use alloc::vec::Vec;

/// What the network's prediction keeps of the body between passes, sized at creation: its
/// body edges and the body's frames in the speed limit's frame of reference.
pub(super) struct NetBody {
    /// The pass's body edges and active body nodes.
    links: BodyLinks,
    /// The body's previous and next frames as the network sees them under the speed limit, in
    /// the frame of reference that follows the carried motion, m (empty without the limit).
    carried_prev: Vec<[f32; 3]>,
    carried_next: Vec<[f32; 3]>,
}

impl NetBody {
    /// Buffers for `n` garment vertices on a body of `nb` vertices (`carried`: with the speed
    /// limit).
    pub(super) fn new(n: usize, nb: usize, carried: bool) -> NetBody {
        NetBody {
            links: BodyLinks::new(n, nb),
            carried_prev: if carried { vec![[0.0; 3]; nb] } else { Vec::new() },
            carried_next: if carried { vec![[0.0; 3]; nb] } else { Vec::new() },
        }
    }

    /// Most active body nodes of a pass.
    pub(super) fn max_active(&self) -> usize {
        self.links.max_active()
    }
}

impl Sim<'_> {
    /// The network's prediction of the pass into `new_pos` / `new_vel`: pinned vertices are
    /// already at their targets in `new_pos`, free ones at their current positions.
    pub(super) fn predict(
        &mut self,
        query: Option<&mut BodyQuery>,
        pass: &Pass<'_>,
        observer: Option<&mut dyn FnMut(Probe<'_>)>,
    ) -> Result<()> {
        let Sim {
            net,
            garment,
            graph,
            material_in,
            pinned,
            body,
            state,
            garment_normals,
            new_pos,
            new_vel,
            ws,
            widened,
            query: own,
            ..
        } = self;
        let net = &Net { widened: widened.as_ref(), ..*net };
        let exec = &*self.exec;
        // The body: its frames as the network sees them, its edges to the garment.
        let seen = match body {
            Some(b) => {
                carry_frames(&mut b.net, &state.body_prev, pass);
                let (grid, normals) = body_query(query, own)?.vertices(&b.mesh, &state.body_pos)?;
                b.net.links.link(grid, exec, graph, &b.mesh, new_pos)?;
                Some(SeenBody::new(b, state, normals, pass))
            }
            None => None,
        };
        // Features and edge encoders at the pass's start, the forward pass, the integration.
        vertex_normals(garment.faces(), new_pos, garment_normals);
        let nodes = GarmentNodes {
            velocity: &state.velocity,
            normals: garment_normals,
            mass: garment.vertex_mass(),
            pinned,
            level: &graph.vertex_level,
            material: material_in,
            dt: pass.dt,
        };
        let model = net.model;
        let emb = Embeddings { node_type: model.node_type_embedding, level: model.level_embedding };
        let inputs = seen.as_ref().map(|s| &s.inputs);
        let n_edges = inputs.map_or(0, |b| b.pairs.len());
        let rows = FeatureRows {
            nodes: &mut ws.node_features[..(new_pos.len() + inputs.map_or(0, |b| b.active.len())) * NODE_WIDTH],
            g2b: &mut ws.g2b_features[..n_edges * BODY_EDGE_WIDTH],
            b2g: &mut ws.b2g_features[..n_edges * BODY_EDGE_WIDTH],
        };
        node_features(&nodes, inputs, new_pos, &emb, rows)?;
        let edges = GarmentEdges { graph, pos: new_pos, rest: garment.rest(), material: material_in, dt: pass.dt };
        encode(&edges, net, exec, ws)?;
        let body_edges = seen.map_or(NO_BODY_EDGES, |s| s.edges);
        ws.forward(net, exec, graph, &body_edges, observer)?;
        self.last_body = (body_edges.prefix[0], body_edges.n_active);
        integrate(model.output_stats(), &ws.decoded, &state.velocity, pinned, new_pos, new_vel)
    }
}

/// The body edges of a pass without a body.
const NO_BODY_EDGES: BodyEdges<'static> = BodyEdges { garment: &[], body: &[], n_active: 0, prefix: [0; 4] };

/// The body's frames in the speed limit's frame of reference: the previous one (`prev`) moved
/// by the last step's carry, the next one moved back by this pass's (only when either carry is
/// not zero, and with a next frame).
fn carry_frames(net: &mut NetBody, prev: &[[f32; 3]], pass: &Pass<'_>) {
    let (Some(next), true) = (pass.body_next, pass.shifted()) else { return };
    let shift = |out: &mut [[f32; 3]], src: &[[f32; 3]], by: [f32; 3]| {
        for (o, p) in out.iter_mut().zip(src) {
            *o = [p[0] + by[0], p[1] + by[1], p[2] + by[2]];
        }
    };
    shift(&mut net.carried_prev, prev, pass.last_carry);
    shift(&mut net.carried_next, next, pass.carry.map(|c| -c));
}

/// The body as one pass of the network sees it.
struct SeenBody<'a> {
    /// The body's inputs: the current frame, the previous one in the speed limit's frame (the
    /// current one in the start-up pass: a static body), normals, omitted flags, the next frame
    /// in the speed limit's frame (the current one for a static body), the body edges.
    inputs: BodyInputs<'a>,
    /// The body edges as the forward pass reads them.
    edges: BodyEdges<'a>,
}

impl<'a> SeenBody<'a> {
    fn new(b: &'a BodyState, state: &'a SimState, normals: &'a [[f32; 3]], pass: &Pass<'a>) -> SeenBody<'a> {
        let (net, pos) = (&b.net, &state.body_pos[..]);
        let prev = match (pass.startup(), pass.shifted()) {
            (true, _) => pos,
            (false, true) => &net.carried_prev,
            (false, false) => &state.body_prev,
        };
        let next = match (pass.shifted(), pass.body_next) {
            (true, Some(_)) => &net.carried_next,
            _ => pass.body_next.unwrap_or(pos),
        };
        SeenBody {
            inputs: BodyInputs {
                nodes: BodyNodes { pos, prev, normals, omitted: b.mesh.omitted(), dt: pass.dt },
                next,
                active: net.links.active(),
                pairs: net.links.pairs(),
            },
            edges: net.links.edges(),
        }
    }
}

/// The garment's mesh and coarse edges at the pass's start, as their features read them.
struct GarmentEdges<'a> {
    graph: &'a Graph,
    /// Positions, m (pinned vertices at their targets).
    pos: &'a [[f32; 3]],
    /// Rest positions, m.
    rest: &'a [[f32; 3]],
    /// Each vertex's material as the network reads it.
    material: &'a [[f32; 3]],
    /// Time step, s.
    dt: f32,
}

/// The edge encoders: the features of each edge set the model uses (mesh, then coarse levels),
/// normalised and encoded into the workspace's latents. The network's work starts here: the
/// workspace's count of floating-point operations restarts at zero.
fn encode(edges: &GarmentEdges<'_>, net: &Net<'_>, exec: &dyn Executor, ws: &mut Workspace) -> Result<()> {
    ws.flops = 0;
    let (pos, rest, material, dt) = (edges.pos, edges.rest, edges.material, edges.dt);
    for (key, list) in edges.graph.edge_sets() {
        if !ws.uses(key) {
            continue;
        }
        let e = &list.global;
        features::edge_features(e, pos, rest, material, dt, ws.edge_feature_rows(e.len()))?;
        ws.encode_edges(net, exec, key, e.len())?;
    }
    Ok(())
}

/// Integration of the decoded accelerations (`decoded`, normalised; `stats`: the output
/// normaliser's mean and standard deviation): for each free vertex, `a = decoded · std + mean`
/// (m/frame²), `v' = v + a` into `new_vel`, `x' = x + v + a` into `new_pos` (which holds `x`);
/// pinned vertices stay at their targets with no velocity.
///
/// # Errors
/// [`Error::NonFinite`] for the first vertex whose new position or velocity is not finite.
fn integrate(
    stats: (&[f32], &[f32]),
    decoded: &[f32],
    velocity: &[[f32; 3]],
    pinned: &[bool],
    new_pos: &mut [[f32; 3]],
    new_vel: &mut [[f32; 3]],
) -> Result<()> {
    let (mean, std) = stats;
    for i in 0..new_pos.len() {
        if pinned[i] {
            new_vel[i] = [0.0; 3];
            continue;
        }
        let d = &decoded[3 * i..3 * i + 3];
        let v = velocity[i];
        let mut nv = [0.0; 3];
        let mut np = [0.0; 3];
        for k in 0..3 {
            let acc = d[k] * std[k] + mean[k];
            nv[k] = v[k] + acc;
            np[k] = new_pos[i][k] + v[k] + acc;
        }
        if !finite3(np) || !finite3(nv) {
            return Err(Error::NonFinite { what: "network output for garment vertex", index: i });
        }
        new_vel[i] = nv;
        new_pos[i] = np;
    }
    Ok(())
}
