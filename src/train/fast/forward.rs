//! The fast forward pass ([`Network::forward_fast`]): transposed weights, normalised features,
//! encoders, message-passing blocks and decoder, with the tape kept for the backward.

use super::layers::{edge_fwd, EdgeSet, First};
use super::{fit, size, BlockTape, Ctx, EdgeTape, FastWorkspace, MAX_INPUTS};
use crate::error::{Error, Result};
use crate::exec::par::Disjoint;
use crate::exec::Executor;
use crate::features::{BODY_EDGE_WIDTH, EDGE_NORMALISED, EDGE_WIDTH, NODE_NORMALISED, NODE_WIDTH};
use crate::model::EdgeKey;
use crate::sim::Graph;
use crate::train::inputs::StepData;
use crate::train::network::{Network, Stats};
use alloc::vec::Vec;

fn normalise(rows: &mut [f32], stride: usize, (mean, std): &(Vec<f32>, Vec<f32>), width: usize) {
    for r in rows.chunks_exact_mut(stride) {
        for c in 0..width {
            r[c] = (r[c] - mean[c]) / std[c];
        }
    }
}

impl Network {
    /// Checks the spec fits the fast path's fixed-size tables.
    fn check_fast(&self) -> Result<()> {
        let too_deep = self.layout.mlps.iter().any(|m| m.layers.len() > 8);
        let too_wide = self.spec.blocks.iter().any(|b| self.spec.node_inputs(b) > MAX_INPUTS);
        // The LayerNorm backward reads gamma and beta as one block.
        let split_norm = self.layout.mlps.iter().any(|m| m.norm.is_some_and(|(g, b)| b != g + m.output()));
        if too_deep || too_wide || split_norm {
            return Err(Error::IncompatibleModel {
                reason: "the fast trainer path supports at most 8 layers and 8 node inputs",
            });
        }
        Ok(())
    }

    /// The fast f32 forward pass: the same result as [`Network::forward`] (up to summation
    /// order), its outputs in `ws.new_pos` / `ws.decoded` and its tape kept in `ws` for
    /// [`Network::backward_fast`]. Products run on `ws`'s [`Gemm`] path, loops split over `exec`.
    ///
    /// # Errors
    /// As [`Network::forward`].
    ///
    /// [`Gemm`]: crate::train::gemm::Gemm
    pub fn forward_fast(
        &self,
        ws: &mut FastWorkspace,
        exec: &dyn Executor,
        theta: &[f32],
        stats: &Stats<f32>,
        graph: &Graph,
        step: &StepData,
    ) -> Result<()> {
        let lay = &self.layout;
        if theta.len() != lay.len {
            return Err(Error::SizeMismatch { what: "parameter vector", expected: lay.len, got: theta.len() });
        }
        if ws.layout.as_ref() != Some(lay) {
            self.check_fast()?;
            ws.linears = lay.mlps.iter().flat_map(|m| m.layers.iter().copied()).collect();
            ws.layout = Some(lay.clone());
        }
        // Transposed weights of the current parameters, one layer per task.
        size(&mut ws.wt, lay.len);
        {
            let wts = Disjoint::new(&mut ws.wt);
            let linears = &ws.linears;
            exec.run(linears.len(), &|j| {
                let l = &linears[j];
                // SAFETY: every layer's weights occupy their own range of the layout.
                let wt = unsafe { wts.range(l.w..l.w + l.inp * l.out) };
                for o in 0..l.out {
                    for i in 0..l.inp {
                        wt[i * l.out + o] = theta[l.w + o * l.inp + i];
                    }
                }
            });
        }
        let FastWorkspace { gemm, wt, tape: t, tmp, parts, decoded, new_pos, .. } = ws;
        let c = Ctx { g: *gemm, exec, theta, wt, grad: None };
        let h = self.spec.latent;
        let (v, na) = (step.n_garment, step.n_active);
        let rows = v + na;
        let nb = step.prefix[0];
        // Node features: the embedding columns from the current tables, then normalise, encode.
        let nf = &mut t.node_in;
        nf.clear();
        nf.extend_from_slice(&step.node_features);
        lay.fill_embeddings(theta, &step.node_type, &step.node_level, nf);
        normalise(nf, NODE_WIDTH, &stats.node, NODE_NORMALISED);
        let x = &mut tmp.x;
        fit(x, rows * h);
        c.mlp_fwd(&lay.mlps.node_encoder, First::Parts(&[&t.node_in]), rows, &mut t.node_enc, x, false, parts);
        // Mesh and coarse edges.
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            let k = key as usize;
            t.edge_on[k] = !step.edge_features[k].is_empty();
            if !t.edge_on[k] {
                continue;
            }
            let enc = self
                .spec
                .encoder_index(key)
                .and_then(|i| lay.mlps.edge_encoders.get(i))
                .ok_or(Error::IncompatibleModel { reason: "the model has no encoder for an edge set it uses" })?;
            let ef = &mut t.edge_in[k];
            ef.clear();
            ef.extend_from_slice(&step.edge_features[k]);
            normalise(ef, EDGE_WIDTH, &stats.edge, EDGE_NORMALISED);
            let ne = ef.len() / EDGE_WIDTH;
            fit(&mut tmp.lat[k], ne * h);
            c.mlp_fwd(enc, First::Parts(&[&t.edge_in[k]]), ne, &mut t.edge_enc[k], &mut tmp.lat[k], false, parts);
        }
        // Body edges: both directions, one normaliser, one encoder.
        fit(&mut tmp.g2b, nb * h);
        fit(&mut tmp.b2g, nb * h);
        if nb > 0 {
            let enc = lay.mlps.body_encoder.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
            for (src, dst) in [(&step.g2b_features, &mut t.g2b_in), (&step.b2g_features, &mut t.b2g_in)] {
                dst.clear();
                dst.extend_from_slice(&src[..nb * BODY_EDGE_WIDTH]);
                normalise(dst, BODY_EDGE_WIDTH, &stats.body_edge, BODY_EDGE_WIDTH);
            }
            let [eg, eb] = &mut t.body_enc;
            c.mlp_fwd(enc, First::Parts(&[&t.g2b_in]), nb, eg, &mut tmp.g2b, false, parts);
            c.mlp_fwd(enc, First::Parts(&[&t.b2g_in]), nb, eb, &mut tmp.b2g, false, parts);
        }
        tmp.iota.clear();
        tmp.iota.extend(0..nb as u32);
        let has_body_slot = self.spec.effects.body;
        t.blocks.resize_with(self.spec.blocks.len(), BlockTape::default);
        for (bi, (bs, ba)) in self.spec.blocks.iter().zip(&lay.mlps.blocks).enumerate() {
            let n_slots = bs.keys.len() + usize::from(has_body_slot);
            let bt = &mut t.blocks[bi];
            bt.x_in.clear();
            bt.x_in.extend_from_slice(&tmp.x);
            bt.slots.resize_with(n_slots, Vec::new);
            bt.slots.iter_mut().for_each(|s| fit(s, rows * h));
            bt.edges.resize_with(bs.keys.len(), EdgeTape::default);
            for (ki, (&key, m)) in bs.keys.iter().zip(&ba.edges).enumerate() {
                let list = graph.edges(key)?;
                let k = key as usize;
                let et = &mut bt.edges[ki];
                match key.coarse_level() {
                    None => {
                        let xg = &bt.x_in[..v * h];
                        let es = EdgeSet { xt: xg, xs: xg, target: &list.target, source: &list.source };
                        let agg = &mut bt.slots[ki][..v * h];
                        edge_fwd(&c, m, h, es, &mut tmp.lat[k], agg, et, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
                    }
                    Some(l) => {
                        let nodes = &graph.coarse[l].nodes;
                        size(&mut tmp.gath, nodes.len() * h);
                        c.gather(&bt.x_in, nodes, h, None, &mut tmp.gath);
                        fit(&mut tmp.local, nodes.len() * h);
                        let es = EdgeSet { xt: &tmp.gath, xs: &tmp.gath, target: &list.target, source: &list.source };
                        let lat = &mut tmp.lat[k];
                        edge_fwd(&c, m, h, es, lat, &mut tmp.local, et, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
                        c.scatter_add(&tmp.local, nodes, h, &mut bt.slots[ki]);
                    }
                }
            }
            let n = self.body_rows(bi, step);
            bt.has_body = n > 0;
            if n > 0 {
                let m = ba.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                size(&mut tmp.gath, n * h);
                c.gather(&bt.x_in, &step.body_garment[..n], h, None, &mut tmp.gath);
                let xg = &tmp.gath;
                let xb = &bt.x_in[v * h..rows * h];
                let slot = &mut bt.slots[bs.keys.len()];
                let [tb, tg] = &mut bt.body;
                // body -> garment: per edge, then into the garment rows.
                fit(&mut tmp.local, n * h);
                let es = EdgeSet { xt: xg, xs: xb, target: &tmp.iota[..n], source: &step.body_active[..n] };
                let lat = &mut tmp.b2g;
                edge_fwd(&c, m, h, es, lat, &mut tmp.local, tb, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
                c.scatter_add(&tmp.local, &step.body_garment[..n], h, slot);
                // garment -> body: summed per active body node.
                let es = EdgeSet { xt: xb, xs: xg, target: &step.body_active[..n], source: &tmp.iota[..n] };
                let (lat, agg) = (&mut tmp.g2b, &mut slot[v * h..rows * h]);
                edge_fwd(&c, m, h, es, lat, agg, tg, &mut tmp.pt, &mut tmp.ps, &mut tmp.msg, parts);
            }
            let mut inputs: [&[f32]; MAX_INPUTS] = [&[]; MAX_INPUTS];
            inputs[0] = &bt.x_in;
            for (s, i) in bt.slots.iter().zip(&mut inputs[1..]) {
                *i = s;
            }
            let first = First::Parts(&inputs[..1 + n_slots]);
            c.mlp_fwd(&ba.node, first, rows, &mut bt.node, &mut tmp.x, true, parts);
        }
        fit(decoded, v * 3);
        t.x_final.clear();
        t.x_final.extend_from_slice(&tmp.x);
        c.mlp_fwd(&lay.mlps.decoder, First::Parts(&[&t.x_final[..v * h]]), v, &mut t.dec, decoded, false, parts);
        let (mean, std) = &stats.output;
        new_pos.clear();
        new_pos.extend((0..v).map(|i| {
            let p = step.pos[i];
            if step.pinned[i] {
                return p;
            }
            let vel = step.velocity[i];
            core::array::from_fn(|k| p[k] + vel[k] + (decoded[3 * i + k] * std[k] + mean[k]))
        }));
        Ok(())
    }
}
