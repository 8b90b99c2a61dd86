//! The forward pass over the workspace's buffers: edge encoders ([`Workspace::encode_edges`]),
//! then nodes, body edges, message-passing blocks and decoder ([`Workspace::forward`]).

use super::tasks::{Agg, BodyLinks, Gather, Input, Par, Projections};
use super::{BodyEdges, Net, Probe, Stage, Workspace};
use crate::error::{Error, Result};
use crate::exec::Executor;
use crate::features::{BODY_EDGE_WIDTH, EDGE_WIDTH, NODE_NORMALISED, NODE_WIDTH};
use crate::kernels::MAX_OPERANDS;
use crate::model::spec::EdgeKey;
use crate::normaliser::normalise_rows;
use crate::sim::graph::Graph;

impl Workspace {
    /// Normalises the first `n` edge feature rows and encodes them into the latents of `key`.
    pub fn encode_edges(&mut self, net: &Net<'_>, exec: &dyn Executor, key: EdgeKey, n: usize) -> Result<()> {
        let (mean, std) = net.model.edge_stats();
        let rows = &mut self.edge_features[..n * EDGE_WIDTH];
        normalise_rows(rows, EDGE_WIDTH, mean, std);
        let enc_i = net
            .model
            .spec()
            .encoder_index(key)
            .ok_or(Error::IncompatibleModel { reason: "the model has no encoder for an edge set it uses" })?;
        let out = match key.coarse_level() {
            Some(l) => &mut self.coarse_latents[l][..n * self.h],
            None => &mut self.mesh_latents[..n * self.h],
        };
        let mut p = Par { exec, tasks: &mut self.tasks, errors: &mut self.errors, flops: &mut self.flops };
        p.mlp(
            &net.encoders(),
            &net.model.mlps.edge_encoders[enc_i],
            &[Some(&self.edge_features[..n * EDGE_WIDTH])],
            n,
            out,
            None,
        )
    }

    /// The forward pass after the edge latents are encoded: nodes (features already in
    /// `node_features`, garment then active body rows), body edges (features in
    /// `g2b_features`/`b2g_features`), blocks, decoder into `decoded`.
    ///
    /// Without an `observer`, the last block leaves out what only the body's latents need (its
    /// garment -> body messages and the body rows of its node update): the decoder reads the
    /// garment's rows alone, so the prediction is bitwise the same, for about a fifth of a
    /// block less work. An observer sees every block whole.
    pub fn forward(
        &mut self,
        net: &Net<'_>,
        exec: &dyn Executor,
        graph: &Graph,
        body: &BodyEdges<'_>,
        mut observer: Option<&mut dyn FnMut(Probe<'_>)>,
    ) -> Result<()> {
        let observed = observer.is_some();
        let mut observe = |p: Probe<'_>| {
            if let Some(o) = observer.as_mut() {
                o(p)
            }
        };
        let (h, v) = (self.h, self.v);
        let a = body.n_active;
        if a > self.max_active {
            return Err(Error::CapacityExceeded { what: "active body nodes", capacity: self.max_active, needed: a });
        }
        let rows = v + a;
        let nb = body.prefix[0];
        let model = net.model;
        let mut par = Par { exec, tasks: &mut self.tasks, errors: &mut self.errors, flops: &mut self.flops };
        // Nodes: normalise the first 21 columns, encode.
        let (mean, std) = model.node_stats();
        let feats = &mut self.node_features[..rows * NODE_WIDTH];
        normalise_rows(feats, NODE_WIDTH, &mean[..NODE_NORMALISED], &std[..NODE_NORMALISED]);
        let encoders = net.encoders();
        par.mlp(
            &encoders,
            &model.mlps.node_encoder,
            &[Some(&self.node_features[..rows * NODE_WIDTH])],
            rows,
            &mut self.latents[..rows * h],
            None,
        )?;
        // Body edges: both directions, one normaliser, one encoder.
        if nb > 0 {
            let enc = model.mlps.body_encoder.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
            let (mean, std) = model.body_edge_stats();
            for (f, lat) in
                [(&mut self.g2b_features, &mut self.g2b_latents), (&mut self.b2g_features, &mut self.b2g_latents)]
            {
                normalise_rows(&mut f[..nb * BODY_EDGE_WIDTH], BODY_EDGE_WIDTH, mean, std);
                par.mlp(&encoders, enc, &[Some(&f[..nb * BODY_EDGE_WIDTH])], nb, &mut lat[..nb * h], None)?;
            }
        }
        observe(Probe { stage: Stage::Encoded, garment: &self.latents[..v * h], body: &self.latents[v * h..rows * h] });

        let blocks = model.spec().blocks.len();
        for (bi, (bspec, bview)) in model.spec().blocks.iter().zip(&model.mlps.blocks).enumerate() {
            // The rows this block's node update writes: the garment's alone in an unobserved
            // last block, whose body latents nothing reads.
            let garment_only = bi + 1 == blocks && !observed;
            let out_rows = if garment_only { v } else { rows };
            let n_slots = bspec.keys.len() + usize::from(nb > 0);
            par.fill_each(&mut self.slots[..n_slots], out_rows * h);
            for (ki, (&key, mlp)) in bspec.keys.iter().zip(&bview.edges).enumerate() {
                let slot = &mut self.slots[ki][..rows * h];
                let proj = (&mut self.proj_t[..], &mut self.proj_s[..]);
                match key.coarse_level() {
                    None => {
                        let e = &graph.mesh;
                        par.edge_mlp(
                            net,
                            mlp,
                            (Input::Rows(&self.latents[..v * h]), None),
                            (e, &self.mesh_split),
                            &mut self.mesh_latents[..e.target.len() * h],
                            Agg::Rows(&mut slot[..v * h]),
                            proj,
                        )?;
                    }
                    Some(l) => {
                        // The level's nodes are gathered by the projections' tasks, and their
                        // sums scattered into the slot by the edge kernel's.
                        let level = &graph.coarse[l];
                        let nl = level.nodes.len();
                        let gather = Gather {
                            src: &self.latents,
                            idx: &level.nodes,
                            width: h,
                            into: &mut self.gathered[..nl * h],
                        };
                        par.edge_mlp(
                            net,
                            mlp,
                            (Input::Gathered, Some(gather)),
                            (&level.edges, &self.coarse_split[l]),
                            &mut self.coarse_latents[l][..level.edges.target.len() * h],
                            Agg::Scattered { local: &mut self.local_agg[..nl * h], nodes: &level.nodes, slot },
                            proj,
                        )?;
                    }
                }
            }
            if nb > 0 {
                let mlp = bview.body.as_ref().ok_or(Error::UnsupportedEffect { effect: "body collision" })?;
                let depth = bspec.finest().coarse_level().map_or(0, |l| l + 1);
                let n = body.prefix[depth];
                let slot = &mut self.slots[bspec.keys.len()][..rows * h];
                if n > 0 {
                    let xb = &self.latents[v * h..rows * h];
                    // Both directions' node projections (the same weights on swapped ends) in
                    // one job, whose tasks gather the garment ends' rows first.
                    let gather = Gather {
                        src: &self.latents,
                        idx: &body.garment[..n],
                        width: h,
                        into: &mut self.gathered[..n * h],
                    };
                    let (b2g, g2b) = if garment_only {
                        let [t, s] = par.node_projections(
                            net,
                            mlp,
                            Some(gather),
                            [(Input::Gathered, 0, &mut self.proj_t[..]), (Input::Rows(xb), 1, &mut self.proj_s[..])],
                        )?;
                        (Projections { target: t, source: s }, None)
                    } else {
                        let [b2g_t, b2g_s, g2b_t, g2b_s] = par.node_projections(
                            net,
                            mlp,
                            Some(gather),
                            [
                                (Input::Gathered, 0, &mut self.proj_t[..]),
                                (Input::Rows(xb), 1, &mut self.proj_s[..]),
                                (Input::Rows(xb), 0, &mut self.g2b_proj_t[..]),
                                (Input::Gathered, 1, &mut self.g2b_proj_s[..]),
                            ],
                        )?;
                        let b2g = Projections { target: b2g_t, source: b2g_s };
                        (b2g, Some(Projections { target: g2b_t, source: g2b_s }))
                    };
                    let links = BodyLinks { garment: &body.garment[..n], body: &body.body[..n], iota: graph.iota() };
                    par.body_messages(
                        net,
                        mlp,
                        &links,
                        (b2g, g2b),
                        (&mut self.b2g_latents[..n * h], &mut self.g2b_latents[..n * h]),
                        &mut self.local_agg[..n * h],
                        &mut self.proj_edge,
                        &mut slot[..v * h],
                    )?;
                    if !garment_only {
                        // garment -> body: a sum per active body node in edge order (independent
                        // of the task split).
                        let offsets = &mut self.g2b_offsets[..a + 1];
                        let perm = &mut self.g2b_perm[..n];
                        counting_sort(&body.body[..n], offsets, perm);
                        par.reduce_rows(&self.local_agg[..n * h], offsets, perm, h, &mut slot[v * h..rows * h]);
                    }
                }
            }
            // Node update from the latents at the start of the block (the residual).
            let mut inputs: [Option<&[f32]>; MAX_OPERANDS] = [None; MAX_OPERANDS];
            inputs[0] = Some(&self.latents[..out_rows * h]);
            for s in 0..n_slots {
                inputs[1 + s] = Some(&self.slots[s][..out_rows * h]);
            }
            // A model trained with a body but run without one: the body slot is zero and skipped.
            let n_inputs = model.spec().node_inputs(bspec);
            let base = Some(&self.latents[..out_rows * h]);
            let next = &mut self.next_latents[..out_rows * h];
            par.mlp(net, &bview.node, &inputs[..n_inputs], out_rows, next, base)?;
            core::mem::swap(&mut self.latents, &mut self.next_latents);
            observe(Probe {
                stage: Stage::Block(bi),
                garment: &self.latents[..v * h],
                body: &self.latents[v * h..out_rows * h],
            });
        }
        par.mlp(net, &model.mlps.decoder, &[Some(&self.latents[..v * h])], v, &mut self.decoded, None)?;
        observe(Probe { stage: Stage::Decoded, garment: &self.decoded, body: &[] });
        Ok(())
    }
}

/// CSR of `keys` (values below `offsets.len() - 1`): `perm[offsets[k]..offsets[k+1]]` are the
/// positions holding `k`, ascending.
fn counting_sort(keys: &[u32], offsets: &mut [u32], perm: &mut [u32]) {
    offsets.fill(0);
    for &k in keys {
        offsets[k as usize + 1] += 1;
    }
    for i in 1..offsets.len() {
        offsets[i] += offsets[i - 1];
    }
    // Fill using the starts, then shift back.
    for (e, &k) in keys.iter().enumerate() {
        let slot = &mut offsets[k as usize];
        perm[*slot as usize] = e as u32;
        *slot += 1;
    }
    for i in (1..offsets.len()).rev() {
        offsets[i] = offsets[i - 1];
    }
    offsets[0] = 0;
}
