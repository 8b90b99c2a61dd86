//! The fast backward pass ([`Network::backward_fast`]): from the position gradient back through
//! decoder, blocks (in reverse) and encoders to the parameter gradient, on the last forward's
//! tape.

use super::layers::{edge_bwd, EdgeSet};
use super::{fit, size, Ctx, FastWorkspace, MAX_INPUTS};
use crate::error::{Error, Result};
use crate::exec::par::Disjoint;
use crate::exec::Executor;
use crate::features::EDGE_WIDTH;
use crate::model::EdgeKey;
use crate::sim::Graph;
use crate::train::inputs::StepData;
use crate::train::network::{Network, Stats};
use alloc::vec::Vec;

impl Network {
    /// The fast backward pass of the last [`Network::forward_fast`] on `ws` (same `theta`,
    /// `stats`, `graph` and `step`) from `dpos = dL/d(new positions)`: adds `dL/dθ` into `grad`.
    /// One thread and several threads give bitwise the same gradient.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for buffers of the wrong length or a workspace whose last forward
    /// ran on another step.
    #[allow(clippy::too_many_arguments)] // the forward's inputs, its tape, the seed and the output
    pub fn backward_fast(
        &self,
        ws: &mut FastWorkspace,
        exec: &dyn Executor,
        theta: &[f32],
        stats: &Stats<f32>,
        graph: &Graph,
        step: &StepData,
        dpos: &[[f32; 3]],
        grad: &mut [f32],
    ) -> Result<()> {
        let lay = &self.layout;
        if grad.len() != lay.len || theta.len() != lay.len || ws.wt.len() != lay.len {
            return Err(Error::SizeMismatch { what: "gradient vector", expected: lay.len, got: grad.len() });
        }
        let (v, na) = (step.n_garment, step.n_active);
        if dpos.len() != v || ws.new_pos.len() != v || ws.tape.blocks.len() != self.spec.blocks.len() {
            return Err(Error::SizeMismatch { what: "position gradient", expected: ws.new_pos.len(), got: dpos.len() });
        }
        let FastWorkspace { gemm, wt, tape, tmp, parts, .. } = ws;
        let gs = Disjoint::new(grad);
        let c = Ctx { g: *gemm, exec, theta, wt, grad: Some(&gs) };
        let h = self.spec.latent;
        let rows = v + na;
        let nb = step.prefix[0];
        // Integration: new_pos = pos + vel + decoded * std + mean (pinned vertices are fixed).
        let std = &stats.output.1;
        fit(&mut tmp.ddec, v * 3);
        for i in 0..v {
            if !step.pinned[i] {
                for k in 0..3 {
                    tmp.ddec[3 * i + k] = dpos[i][k] * std[k];
                }
            }
        }
        fit(&mut tmp.dx, rows * h);
        let xf = &tape.x_final[..v * h];
        c.mlp_bwd(&lay.mlps.decoder, &[xf], &tape.dec, &tmp.ddec, &mut [Some(&mut tmp.dx[..v * h])], None, parts);
        for k in 0..4 {
            fit(&mut tmp.dlat[k], tape.edge_in[k].len() / EDGE_WIDTH * h);
        }
        fit(&mut tmp.dg2b, nb * h);
        fit(&mut tmp.db2g, nb * h);
        let iota = &tmp.iota;
        for (bi, (bs, ba)) in self.spec.blocks.iter().zip(&lay.mlps.blocks).enumerate().rev() {
            let bt = &tape.blocks[bi];
            // Node update x_out = x_in + MLP([x_in, slots]).
            tmp.dx_in.clear();
            tmp.dx_in.extend_from_slice(&tmp.dx);
            let ns = bt.slots.len();
            tmp.dslots.resize_with(ns, Vec::new);
            tmp.dslots.iter_mut().for_each(|s| fit(s, rows * h));
            {
                let mut inputs: [&[f32]; MAX_INPUTS] = [&[]; MAX_INPUTS];
                inputs[0] = &bt.x_in;
                for (s, i) in bt.slots.iter().zip(&mut inputs[1..]) {
                    *i = s;
                }
                let mut dins: [Option<&mut [f32]>; MAX_INPUTS] = Default::default();
                dins[0] = Some(&mut tmp.dx_in);
                for (s, d) in tmp.dslots.iter_mut().zip(&mut dins[1..]) {
                    *d = Some(s);
                }
                c.mlp_bwd(&ba.node, &inputs[..1 + ns], &bt.node, &tmp.dx, &mut dins[..1 + ns], None, parts);
            }
            core::mem::swap(&mut tmp.dx, &mut tmp.dx_in);
            let x = &bt.x_in;
            if bt.has_body {
                let m = ba.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let n = self.body_rows(bi, step);
                let (garm, act) = (&step.body_garment[..n], &step.body_active[..n]);
                let dslot = &tmp.dslots[bs.keys.len()];
                size(&mut tmp.gath, n * h);
                c.gather(x, garm, h, None, &mut tmp.gath);
                let xg = &tmp.gath;
                let xb = &x[v * h..rows * h];
                fit(&mut tmp.dxg, n * h);
                let (_, dxb) = tmp.dx.split_at_mut(v * h);
                // dm = dlat + dagg[target]
                size(&mut tmp.dm, n * h);
                c.gather(&dslot[v * h..], act, h, Some(&tmp.dg2b[..n * h]), &mut tmp.dm);
                let es = EdgeSet { xt: xb, xs: xg, target: act, source: &iota[..n] };
                let scratch = (&mut tmp.d0, &mut tmp.local, &mut tmp.msg);
                let dl = &mut tmp.dg2b[..n * h];
                edge_bwd(&c, m, h, &bt.body[1], es, &tmp.dm, dl, dxb, Some(&mut tmp.dxg), scratch, parts);
                c.gather(dslot, garm, h, Some(&tmp.db2g[..n * h]), &mut tmp.dm);
                let es = EdgeSet { xt: xg, xs: xb, target: &iota[..n], source: act };
                let scratch = (&mut tmp.d0, &mut tmp.local, &mut tmp.msg);
                let dl = &mut tmp.db2g[..n * h];
                edge_bwd(&c, m, h, &bt.body[0], es, &tmp.dm, dl, &mut tmp.dxg, Some(dxb), scratch, parts);
                c.scatter_add(&tmp.dxg, garm, h, &mut tmp.dx);
            }
            for (ki, (&key, m)) in bs.keys.iter().zip(&ba.edges).enumerate() {
                let list = graph.edges(key)?;
                let k = key as usize;
                let et = &bt.edges[ki];
                let scratch = (&mut tmp.d0, &mut tmp.local, &mut tmp.msg);
                match key.coarse_level() {
                    None => {
                        let xg = &x[..v * h];
                        size(&mut tmp.dm, list.target.len() * h);
                        c.gather(&tmp.dslots[ki], &list.target, h, Some(&tmp.dlat[k]), &mut tmp.dm);
                        let es = EdgeSet { xt: xg, xs: xg, target: &list.target, source: &list.source };
                        let dxv = &mut tmp.dx[..v * h];
                        edge_bwd(&c, m, h, et, es, &tmp.dm, &mut tmp.dlat[k], dxv, None, scratch, parts);
                    }
                    Some(l) => {
                        let nodes = &graph.coarse[l].nodes;
                        size(&mut tmp.gath, nodes.len() * h);
                        c.gather(x, nodes, h, None, &mut tmp.gath);
                        size(&mut tmp.gath2, nodes.len() * h);
                        c.gather(&tmp.dslots[ki], nodes, h, None, &mut tmp.gath2);
                        size(&mut tmp.dm, list.target.len() * h);
                        c.gather(&tmp.gath2, &list.target, h, Some(&tmp.dlat[k]), &mut tmp.dm);
                        fit(&mut tmp.dxl, nodes.len() * h);
                        let es = EdgeSet { xt: &tmp.gath, xs: &tmp.gath, target: &list.target, source: &list.source };
                        edge_bwd(&c, m, h, et, es, &tmp.dm, &mut tmp.dlat[k], &mut tmp.dxl, None, scratch, parts);
                        c.scatter_add(&tmp.dxl, nodes, h, &mut tmp.dx);
                    }
                }
            }
        }
        // Encoders (their inputs are constants, except the embedding columns of the nodes).
        for key in [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2, EdgeKey::Mesh] {
            let k = key as usize;
            if let (true, Some(enc)) =
                (tape.edge_on[k], self.spec.encoder_index(key).and_then(|i| lay.mlps.edge_encoders.get(i)))
            {
                c.mlp_bwd(enc, &[&tape.edge_in[k]], &tape.edge_enc[k], &tmp.dlat[k], &mut [None], None, parts);
            }
        }
        if let (true, Some(enc)) = (nb > 0, &lay.mlps.body_encoder) {
            c.mlp_bwd(enc, &[&tape.g2b_in], &tape.body_enc[0], &tmp.dg2b, &mut [None], None, parts);
            c.mlp_bwd(enc, &[&tape.b2g_in], &tape.body_enc[1], &tmp.db2g, &mut [None], None, parts);
        }
        fit(&mut tmp.dnf, tape.node_in.len());
        c.mlp_bwd(
            &lay.mlps.node_encoder,
            &[&tape.node_in],
            &tape.node_enc,
            &tmp.dx,
            &mut [Some(&mut tmp.dnf)],
            None,
            parts,
        );
        // The embeddings last (their columns of the node features).
        let nstd = &stats.node.1;
        lay.embedding_backward(&tmp.dnf, nstd, &step.node_type, &step.node_level, grad);
        Ok(())
    }
}
