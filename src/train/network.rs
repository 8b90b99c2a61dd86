//! The whole network, differentiable: a forward pass that follows the runtime's data path
//! (`sim::network`) and keeps its activations in a [`Tape`], and the backward pass from
//! `dL/d(new positions)` to the gradient of every parameter (flat, see [`super::layout`]).

use super::inputs::StepData;
use super::layout::{Layout, MlpAt};
use super::ops::{self, MlpCache, Part};
use crate::error::{Error, Result};
use crate::features::{BODY_EDGE_WIDTH, EDGE_NORMALISED, EDGE_WIDTH, NODE_NORMALISED, NODE_WIDTH};
use crate::math::Real;
use crate::model::{EdgeKey, ModelSpec, Params};
use crate::sim::Graph;
use alloc::vec;
use alloc::vec::Vec;

/// Frozen normaliser statistics in precision `R`.
#[derive(Clone, Debug)]
pub struct Stats<R> {
    /// Node features (21 columns): mean, std.
    pub node: (Vec<R>, Vec<R>),
    /// Mesh and coarse edge features (9 columns).
    pub edge: (Vec<R>, Vec<R>),
    /// Body edge features (9 columns).
    pub body_edge: (Vec<R>, Vec<R>),
    /// Output accelerations (3 columns), m/frame².
    pub output: (Vec<R>, Vec<R>),
}

impl<R: Real> Stats<R> {
    /// The current statistics of `p`'s normalisers.
    pub fn of(p: &Params) -> Stats<R> {
        let conv = |n: &crate::normaliser::Normaliser| {
            let s = n.stats();
            (s.mean.iter().map(|&x| R::from_f32(x)).collect(), s.std.iter().map(|&x| R::from_f32(x)).collect())
        };
        let n = &p.normalisers;
        Stats { node: conv(&n.node), edge: conv(&n.edge), body_edge: conv(&n.body_edge), output: conv(&n.output) }
    }
}

/// A model's shape and parameter layout: what the forward and backward passes read besides
/// the flat parameter vector.
#[derive(Clone, Debug)]
pub struct Network {
    /// The shape.
    pub spec: ModelSpec,
    /// Offsets of every tensor in the flat vector.
    pub layout: Layout,
}

impl Network {
    /// The network of `p` (its spec and layout).
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] when `p` is inconsistent.
    pub fn of(p: &Params) -> Result<Network> {
        p.validate()?;
        Ok(Network { spec: p.spec.clone(), layout: Layout::new(p) })
    }
}

/// One edge set's pass through an edge MLP in one block.
#[derive(Clone, Debug, Default)]
struct EdgeTape<R> {
    /// Edge latents before the block.
    lat_in: Vec<R>,
    cache: MlpCache<R>,
}

#[derive(Clone, Debug, Default)]
struct BlockTape<R> {
    /// Node latents at the start of the block (garment then active body rows).
    x_in: Vec<R>,
    /// Per garment key of the block.
    edges: Vec<EdgeTape<R>>,
    /// Body edges: (body->garment, garment->body), when any.
    body: Option<(EdgeTape<R>, EdgeTape<R>)>,
    /// Aggregated messages per slot (keys, then body when the model has one).
    slots: Vec<Vec<R>>,
    node: MlpCache<R>,
}

/// The activations of one forward pass, and its outputs.
#[derive(Clone, Debug, Default)]
pub struct Tape<R> {
    node_in: Vec<R>,
    node_enc: MlpCache<R>,
    edge_in: [Vec<R>; 4],
    edge_enc: [Option<MlpCache<R>>; 4],
    g2b_in: Vec<R>,
    b2g_in: Vec<R>,
    body_enc: Option<(MlpCache<R>, MlpCache<R>)>,
    blocks: Vec<BlockTape<R>>,
    x_final: Vec<R>,
    dec: MlpCache<R>,
    /// Decoder output (normalised accelerations), `n_garment × 3`.
    pub decoded: Vec<R>,
    /// Predicted positions at the next frame, m.
    pub new_pos: Vec<[R; 3]>,
}

fn to_real<R: Real>(x: &[f32]) -> Vec<R> {
    x.iter().map(|&v| R::from_f32(v)).collect()
}

fn normalise<R: Real>(rows: &mut [R], stride: usize, (mean, std): &(Vec<R>, Vec<R>), width: usize) {
    for r in rows.chunks_exact_mut(stride) {
        for c in 0..width {
            r[c] = (r[c] - mean[c]) / std[c];
        }
    }
}

fn gather<R: Real>(src: &[R], idx: &[u32], h: usize) -> Vec<R> {
    let mut out = Vec::with_capacity(idx.len() * h);
    for &i in idx {
        out.extend_from_slice(&src[i as usize * h..(i as usize + 1) * h]);
    }
    out
}

fn scatter_add<R: Real>(src: &[R], idx: &[u32], h: usize, dst: &mut [R]) {
    for (s, &i) in src.chunks_exact(h).zip(idx) {
        for (d, v) in dst[i as usize * h..(i as usize + 1) * h].iter_mut().zip(s) {
            *d += *v;
        }
    }
}

/// The edges of one edge-MLP pass: target-side rows `xt`, source-side rows `xs` (`h` wide) and
/// per edge its target row (in `xt`, also the aggregate row) and source row (in `xs`).
#[derive(Clone, Copy)]
struct EdgeSet<'a, R> {
    xt: &'a [R],
    xs: &'a [R],
    target: &'a [u32],
    source: &'a [u32],
}

/// Edge MLP over `[x_t, x_s, e]` with the first layer split into its three column parts; the
/// message `m` is added to the edge latents `lat` and summed into `agg` at the targets.
fn edge_forward<R: Real>(
    theta: &[R],
    m: &MlpAt,
    h: usize,
    es: EdgeSet<'_, R>,
    lat: &mut [R],
    agg: &mut [R],
) -> EdgeTape<R> {
    let l0 = &m.layers[0];
    let w = l0.out;
    let ne = es.target.len();
    let mut pt = vec![R::ZERO; es.xt.len() / h * w];
    ops::matmul_acc(theta, Part::cols(l0, 0, h), es.xt, &mut pt);
    let mut ps = vec![R::ZERO; es.xs.len() / h * w];
    ops::matmul_acc(theta, Part::cols(l0, h, h), es.xs, &mut ps);
    let mut a0 = vec![R::ZERO; ne * w];
    ops::fill_bias(theta, l0, &mut a0);
    ops::matmul_acc(theta, Part::cols(l0, 2 * h, h), lat, &mut a0);
    for (e, row) in a0.chunks_exact_mut(w).enumerate() {
        let (t, s) = (es.target[e] as usize, es.source[e] as usize);
        for o in 0..w {
            row[o] += pt[t * w + o] + ps[s * w + o];
        }
    }
    let mut msg = vec![R::ZERO; ne * h];
    let cache = ops::mlp_from_first(theta, m, a0, ne, &mut msg, false);
    let lat_in = lat.to_vec();
    for (l, v) in lat.iter_mut().zip(&msg) {
        *l += *v;
    }
    scatter_add(&msg, es.target, h, agg);
    EdgeTape { lat_in, cache }
}

/// Backward of [`edge_forward`] given `dm`, the gradient of the messages (aggregate and edge
/// latent paths summed). Adds into `dlat` (edge latents before the block), `dxt` and `dxs`
/// (`None`: the source rows are the target rows, add into `dxt`).
#[allow(clippy::too_many_arguments)]
fn edge_backward<R: Real>(
    theta: &[R],
    grad: &mut [R],
    m: &MlpAt,
    h: usize,
    tape: &EdgeTape<R>,
    es: EdgeSet<'_, R>,
    dm: &[R],
    dlat: &mut [R],
    dxt: &mut [R],
    dxs: Option<&mut [R]>,
) {
    let l0 = &m.layers[0];
    let w = l0.out;
    let d0 = ops::mlp_backward_to_first(theta, grad, m, &tape.cache, dm);
    ops::matmul_backward(theta, grad, Part::cols(l0, 2 * h, h), &tape.lat_in, &d0, Some(dlat));
    let mut dpt = vec![R::ZERO; es.xt.len() / h * w];
    let mut dps = vec![R::ZERO; es.xs.len() / h * w];
    for (e, row) in d0.chunks_exact(w).enumerate() {
        let (t, s) = (es.target[e] as usize, es.source[e] as usize);
        for o in 0..w {
            dpt[t * w + o] += row[o];
            dps[s * w + o] += row[o];
        }
    }
    ops::matmul_backward(theta, grad, Part::cols(l0, 0, h), es.xt, &dpt, Some(&mut *dxt));
    match dxs {
        Some(dxs) => ops::matmul_backward(theta, grad, Part::cols(l0, h, h), es.xs, &dps, Some(dxs)),
        None => ops::matmul_backward(theta, grad, Part::cols(l0, h, h), es.xs, &dps, Some(dxt)),
    }
}

/// Gradient of the messages: the latent path `dlat` plus the aggregate path `dagg[target]`.
fn message_grad<R: Real>(dlat: &[R], dagg: &[R], target: &[u32], h: usize) -> Vec<R> {
    let mut dm = dlat.to_vec();
    for (row, &t) in dm.chunks_exact_mut(h).zip(target) {
        for (d, a) in row.iter_mut().zip(&dagg[t as usize * h..(t as usize + 1) * h]) {
            *d += *a;
        }
    }
    dm
}

impl Network {
    /// Rows of body edges a block uses (those whose garment end is among its finest nodes).
    pub(super) fn body_rows(&self, bi: usize, step: &StepData) -> usize {
        let depth = self.spec.blocks[bi].finest().coarse_level().map_or(0, |l| l + 1);
        step.prefix[depth]
    }

    /// The forward pass: predicted positions in `tape.new_pos` (pinned vertices at their
    /// targets), every activation the backward needs in the tape.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for a parameter vector of the wrong length;
    /// [`Error::IncompatibleModel`] when the graph lacks a level the model uses.
    pub fn forward<R: Real>(&self, theta: &[R], stats: &Stats<R>, graph: &Graph, step: &StepData) -> Result<Tape<R>> {
        let lay = &self.layout;
        if theta.len() != lay.len {
            return Err(Error::SizeMismatch { what: "parameter vector", expected: lay.len, got: theta.len() });
        }
        let h = self.spec.latent;
        let (v, na) = (step.n_garment, step.n_active);
        let rows = v + na;
        let nb = step.prefix[0];
        let mut t = Tape::<R>::default();
        // Node features: the embedding columns from the current tables, then normalise, encode.
        let mut nf = to_real::<R>(&step.node_features);
        lay.fill_embeddings(theta, &step.node_type, &step.node_level, &mut nf);
        normalise(&mut nf, NODE_WIDTH, &stats.node, NODE_NORMALISED);
        let mut x = vec![R::ZERO; rows * h];
        t.node_enc = ops::mlp_forward(theta, &lay.mlps.node_encoder, &[&nf], rows, &mut x, false);
        t.node_in = nf;
        // Mesh and coarse edges.
        let mut lat: [Vec<R>; 4] = Default::default();
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            let k = key as usize;
            if step.edge_features[k].is_empty() {
                continue;
            }
            let enc = self
                .spec
                .encoder_index(key)
                .and_then(|i| lay.mlps.edge_encoders.get(i))
                .ok_or(Error::IncompatibleModel { reason: "the model has no encoder for an edge set it uses" })?;
            let mut ef = to_real::<R>(&step.edge_features[k]);
            normalise(&mut ef, EDGE_WIDTH, &stats.edge, EDGE_NORMALISED);
            let ne = ef.len() / EDGE_WIDTH;
            lat[k] = vec![R::ZERO; ne * h];
            t.edge_enc[k] = Some(ops::mlp_forward(theta, enc, &[&ef], ne, &mut lat[k], false));
            t.edge_in[k] = ef;
        }
        // Body edges: both directions, one normaliser, one encoder.
        let (mut g2b, mut b2g) = (vec![R::ZERO; nb * h], vec![R::ZERO; nb * h]);
        if nb > 0 {
            let enc = lay.mlps.body_encoder.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
            let mut fg = to_real::<R>(&step.g2b_features[..nb * BODY_EDGE_WIDTH]);
            let mut fb = to_real::<R>(&step.b2g_features[..nb * BODY_EDGE_WIDTH]);
            normalise(&mut fg, BODY_EDGE_WIDTH, &stats.body_edge, BODY_EDGE_WIDTH);
            normalise(&mut fb, BODY_EDGE_WIDTH, &stats.body_edge, BODY_EDGE_WIDTH);
            let cg = ops::mlp_forward(theta, enc, &[&fg], nb, &mut g2b, false);
            let cb = ops::mlp_forward(theta, enc, &[&fb], nb, &mut b2g, false);
            t.body_enc = Some((cg, cb));
            t.g2b_in = fg;
            t.b2g_in = fb;
        }
        let iota: Vec<u32> = (0..nb as u32).collect();
        let has_body_slot = self.spec.effects.body;
        for (bi, (bs, ba)) in self.spec.blocks.iter().zip(&lay.mlps.blocks).enumerate() {
            let n_slots = bs.keys.len() + usize::from(has_body_slot);
            let mut bt =
                BlockTape { x_in: x.clone(), slots: vec![vec![R::ZERO; rows * h]; n_slots], ..BlockTape::default() };
            for (ki, (&key, m)) in bs.keys.iter().zip(&ba.edges).enumerate() {
                let list = graph.edges(key)?;
                let k = key as usize;
                let et = match key.coarse_level() {
                    None => {
                        let xg = &x[..v * h];
                        let es = EdgeSet { xt: xg, xs: xg, target: &list.target, source: &list.source };
                        edge_forward(theta, m, h, es, &mut lat[k], &mut bt.slots[ki][..v * h])
                    }
                    Some(l) => {
                        let nodes = &graph.coarse[l].nodes;
                        let xl = gather(&x, nodes, h);
                        let mut local = vec![R::ZERO; nodes.len() * h];
                        let es = EdgeSet { xt: &xl, xs: &xl, target: &list.target, source: &list.source };
                        let et = edge_forward(theta, m, h, es, &mut lat[k], &mut local);
                        scatter_add(&local, nodes, h, &mut bt.slots[ki]);
                        et
                    }
                };
                bt.edges.push(et);
            }
            let n = self.body_rows(bi, step);
            if n > 0 {
                let m = ba.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let xg = gather(&x, &step.body_garment[..n], h);
                let xb = &x[v * h..rows * h];
                let slot = &mut bt.slots[bs.keys.len()];
                // body -> garment: per edge, then into the garment rows.
                let mut msgs = vec![R::ZERO; n * h];
                let es = EdgeSet { xt: &xg, xs: xb, target: &iota[..n], source: &step.body_active[..n] };
                let tb = edge_forward(theta, m, h, es, &mut b2g[..n * h], &mut msgs);
                scatter_add(&msgs, &step.body_garment[..n], h, slot);
                // garment -> body: summed per active body node.
                let es = EdgeSet { xt: xb, xs: &xg, target: &step.body_active[..n], source: &iota[..n] };
                let tg = edge_forward(theta, m, h, es, &mut g2b[..n * h], &mut slot[v * h..rows * h]);
                bt.body = Some((tb, tg));
            }
            let mut inputs: Vec<&[R]> = vec![&bt.x_in];
            inputs.extend(bt.slots.iter().map(|s| s.as_slice()));
            bt.node = ops::mlp_forward(theta, &ba.node, &inputs, rows, &mut x, true);
            t.blocks.push(bt);
        }
        let mut dec = vec![R::ZERO; v * 3];
        t.dec = ops::mlp_forward(theta, &lay.mlps.decoder, &[&x[..v * h]], v, &mut dec, false);
        t.x_final = x;
        let (mean, std) = &stats.output;
        t.new_pos = (0..v)
            .map(|i| {
                let p = step.pos[i].map(R::from_f32);
                if step.pinned[i] {
                    return p;
                }
                let vel = step.velocity[i];
                core::array::from_fn(|k| p[k] + R::from_f32(vel[k]) + (dec[3 * i + k] * std[k] + mean[k]))
            })
            .collect();
        t.decoded = dec;
        Ok(t)
    }

    /// The backward pass of [`Network::forward`] from `dpos = dL/d(new positions)`: adds
    /// `dL/dθ` into `grad` (same layout as the parameters).
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for buffers of the wrong length.
    #[allow(clippy::too_many_arguments)] // the forward's inputs, its tape, the seed and the output
    pub fn backward<R: Real>(
        &self,
        theta: &[R],
        stats: &Stats<R>,
        graph: &Graph,
        step: &StepData,
        tape: &Tape<R>,
        dpos: &[[R; 3]],
        grad: &mut [R],
    ) -> Result<()> {
        let lay = &self.layout;
        if grad.len() != lay.len || theta.len() != lay.len {
            return Err(Error::SizeMismatch { what: "gradient vector", expected: lay.len, got: grad.len() });
        }
        let (v, na) = (step.n_garment, step.n_active);
        if dpos.len() != v {
            return Err(Error::SizeMismatch { what: "position gradient", expected: v, got: dpos.len() });
        }
        let h = self.spec.latent;
        let rows = v + na;
        let nb = step.prefix[0];
        // Integration: new_pos = pos + vel + decoded * std + mean (pinned vertices are fixed).
        let std = &stats.output.1;
        let mut ddec = vec![R::ZERO; v * 3];
        for i in 0..v {
            if !step.pinned[i] {
                for k in 0..3 {
                    ddec[3 * i + k] = dpos[i][k] * std[k];
                }
            }
        }
        let mut dx = vec![R::ZERO; rows * h];
        ops::mlp_backward(
            theta,
            grad,
            &lay.mlps.decoder,
            &tape.dec,
            &[&tape.x_final[..v * h]],
            &ddec,
            &mut [Some(&mut dx[..v * h])],
        );
        let mut dlat: [Vec<R>; 4] = core::array::from_fn(|k| vec![R::ZERO; tape.edge_in[k].len() / EDGE_WIDTH * h]);
        let (mut dg2b, mut db2g) = (vec![R::ZERO; nb * h], vec![R::ZERO; nb * h]);
        let iota: Vec<u32> = (0..nb as u32).collect();
        for (bi, (bs, ba)) in self.spec.blocks.iter().zip(&lay.mlps.blocks).enumerate().rev() {
            let bt = &tape.blocks[bi];
            // Node update x_out = x_in + MLP([x_in, slots]).
            let mut dx_in = dx.clone();
            let mut dslots: Vec<Vec<R>> = vec![vec![R::ZERO; rows * h]; bt.slots.len()];
            {
                let mut inputs: Vec<&[R]> = vec![&bt.x_in];
                inputs.extend(bt.slots.iter().map(|s| s.as_slice()));
                let mut dins: Vec<Option<&mut [R]>> = vec![Some(&mut dx_in)];
                dins.extend(dslots.iter_mut().map(|s| Some(s.as_mut_slice())));
                ops::mlp_backward(theta, grad, &ba.node, &bt.node, &inputs, &dx, &mut dins);
            }
            dx = dx_in;
            let x = &bt.x_in;
            if let Some((tb, tg)) = &bt.body {
                let m = ba.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let n = self.body_rows(bi, step);
                let (garm, act) = (&step.body_garment[..n], &step.body_active[..n]);
                let dslot = &dslots[bs.keys.len()];
                let xg = gather(x, garm, h);
                let xb = &x[v * h..rows * h];
                let mut dxg = vec![R::ZERO; n * h];
                let (_, dxb) = dx.split_at_mut(v * h);
                let dm = message_grad(&dg2b[..n * h], &dslot[v * h..], act, h);
                let es = EdgeSet { xt: xb, xs: &xg, target: act, source: &iota[..n] };
                edge_backward(theta, grad, m, h, tg, es, &dm, &mut dg2b[..n * h], dxb, Some(&mut dxg));
                let dm = message_grad(&db2g[..n * h], &gather(dslot, garm, h), &iota[..n], h);
                let es = EdgeSet { xt: &xg, xs: xb, target: &iota[..n], source: act };
                edge_backward(theta, grad, m, h, tb, es, &dm, &mut db2g[..n * h], &mut dxg, Some(dxb));
                scatter_add(&dxg, garm, h, &mut dx);
            }
            for (ki, (&key, m)) in bs.keys.iter().zip(&ba.edges).enumerate() {
                let list = graph.edges(key)?;
                let k = key as usize;
                let et = &bt.edges[ki];
                match key.coarse_level() {
                    None => {
                        let xg = &x[..v * h];
                        let dm = message_grad(&dlat[k], &dslots[ki], &list.target, h);
                        let es = EdgeSet { xt: xg, xs: xg, target: &list.target, source: &list.source };
                        edge_backward(theta, grad, m, h, et, es, &dm, &mut dlat[k], &mut dx[..v * h], None);
                    }
                    Some(l) => {
                        let nodes = &graph.coarse[l].nodes;
                        let xl = gather(x, nodes, h);
                        let dm = message_grad(&dlat[k], &gather(&dslots[ki], nodes, h), &list.target, h);
                        let mut dxl = vec![R::ZERO; xl.len()];
                        let es = EdgeSet { xt: &xl, xs: &xl, target: &list.target, source: &list.source };
                        edge_backward(theta, grad, m, h, et, es, &dm, &mut dlat[k], &mut dxl, None);
                        scatter_add(&dxl, nodes, h, &mut dx);
                    }
                }
            }
        }
        // Encoders (their inputs are constants, except the embedding columns of the nodes).
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            let k = key as usize;
            if let (Some(c), Some(enc)) =
                (&tape.edge_enc[k], self.spec.encoder_index(key).and_then(|i| lay.mlps.edge_encoders.get(i)))
            {
                ops::mlp_backward(theta, grad, enc, c, &[&tape.edge_in[k]], &dlat[k], &mut [None]);
            }
        }
        if let (Some((cg, cb)), Some(enc)) = (&tape.body_enc, &lay.mlps.body_encoder) {
            ops::mlp_backward(theta, grad, enc, cg, &[&tape.g2b_in], &dg2b, &mut [None]);
            ops::mlp_backward(theta, grad, enc, cb, &[&tape.b2g_in], &db2g, &mut [None]);
        }
        let mut dnf = vec![R::ZERO; tape.node_in.len()];
        ops::mlp_backward(
            theta,
            grad,
            &lay.mlps.node_encoder,
            &tape.node_enc,
            &[&tape.node_in],
            &dx,
            &mut [Some(&mut dnf)],
        );
        let nstd = &stats.node.1;
        lay.embedding_backward(&dnf, nstd, &step.node_type, &step.node_level, grad);
        Ok(())
    }
}
