//! The trainer's parameter form: every trainable tensor of a [`Params`] laid out in one flat
//! vector (Adam, clipping and gradients then work on plain slices), with the offsets of each
//! tensor.

use crate::features::{LEVELS, NODE_TYPES, NODE_WIDTH};
use crate::math::Real;
use crate::model::{Mlp, Mlps, ModelSpec, Params};
use alloc::format;
use alloc::string::String;
use alloc::vec::Vec;
use core::ops::Range;

/// Where one Linear layer lives in the flat vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinearAt {
    /// Offset of the `[out, in]` row-major weight.
    pub w: usize,
    /// Offset of the `[out]` bias.
    pub b: usize,
    /// Input width.
    pub inp: usize,
    /// Output width.
    pub out: usize,
}

/// Where one MLP lives in the flat vector.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MlpAt {
    /// Its Linear layers (ReLU between consecutive ones).
    pub layers: Vec<LinearAt>,
    /// Offsets of the final LayerNorm's gamma and beta, if any.
    pub norm: Option<(usize, usize)>,
}

impl MlpAt {
    /// Output width.
    pub fn output(&self) -> usize {
        self.layers.last().map_or(0, |l| l.out)
    }
}

/// Offsets of every trainable tensor of a model of one [`ModelSpec`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Every MLP, in the skeleton's structure.
    pub mlps: Mlps<MlpAt>,
    /// Offset of the 9 x 9 node-type embedding.
    pub node_type_embedding: usize,
    /// Offset of the 4 x 4 vertex-level embedding.
    pub level_embedding: usize,
    /// Total length.
    pub len: usize,
}

impl Layout {
    /// Writes the embedding columns (3..12: node type, 12..16: vertex level) of every node row
    /// (`NODE_WIDTH` wide) from the current tables in `theta`.
    pub fn fill_embeddings<R: Real>(&self, theta: &[R], types: &[u8], levels: &[u8], rows: &mut [R]) {
        for (r, row) in rows.chunks_exact_mut(NODE_WIDTH).enumerate() {
            let ty = self.node_type_embedding + types[r] as usize * NODE_TYPES;
            row[3..3 + NODE_TYPES].copy_from_slice(&theta[ty..ty + NODE_TYPES]);
            let lv = self.level_embedding + levels[r] as usize * LEVELS;
            row[12..12 + LEVELS].copy_from_slice(&theta[lv..lv + LEVELS]);
        }
    }

    /// The backward of [`fill_embeddings`](Self::fill_embeddings) followed by normalisation
    /// with standard deviations `std`: adds each row's gradient of the (normalised) embedding
    /// columns in `d_rows` to its table rows in `grad`.
    pub fn embedding_backward<R: Real>(&self, d_rows: &[R], std: &[R], types: &[u8], levels: &[u8], grad: &mut [R]) {
        for (r, row) in d_rows.chunks_exact(NODE_WIDTH).enumerate() {
            let ty = self.node_type_embedding + types[r] as usize * NODE_TYPES;
            for j in 0..NODE_TYPES {
                grad[ty + j] += row[3 + j] / std[3 + j];
            }
            let lv = self.level_embedding + levels[r] as usize * LEVELS;
            for j in 0..LEVELS {
                grad[lv + j] += row[12 + j] / std[12 + j];
            }
        }
    }
}

struct Alloc(usize);

impl Alloc {
    fn take(&mut self, n: usize) -> usize {
        let at = self.0;
        self.0 += n;
        at
    }

    fn mlp(&mut self, m: &Mlp) -> MlpAt {
        let layers = m
            .layers
            .iter()
            .map(|l| LinearAt { w: self.take(l.inp * l.out), b: self.take(l.out), inp: l.inp, out: l.out })
            .collect();
        let norm = m.norm.as_ref().map(|n| (self.take(n.gamma.len()), self.take(n.beta.len())));
        MlpAt { layers, norm }
    }
}

impl Layout {
    /// The layout of `p` (its spec and tensor sizes): its MLPs in the skeleton's order
    /// ([`Mlps::iter`]), then the two embedding tables.
    pub fn new(p: &Params) -> Layout {
        let mut a = Alloc(0);
        let mlps = p.mlps.map(|m| a.mlp(m));
        let node_type_embedding = a.take(NODE_TYPES * NODE_TYPES);
        let level_embedding = a.take(LEVELS * LEVELS);
        Layout { mlps, node_type_embedding, level_embedding, len: a.0 }
    }

    /// The flat vector of `p`'s parameters in precision `R`.
    pub fn flatten<R: Real>(&self, p: &Params) -> Vec<R> {
        let mut out = alloc::vec![R::ZERO; self.len];
        let mut put = |at: usize, src: &[f32]| {
            for (d, &s) in out[at..at + src.len()].iter_mut().zip(src) {
                *d = R::from_f32(s);
            }
        };
        for (m, at) in p.mlps.iter().zip(self.mlps.iter()) {
            for (l, la) in m.layers.iter().zip(&at.layers) {
                put(la.w, &l.weight);
                put(la.b, &l.bias);
            }
            if let (Some(n), Some((g, b))) = (&m.norm, at.norm) {
                put(g, &n.gamma);
                put(b, &n.beta);
            }
        }
        put(self.node_type_embedding, &p.node_type_embedding);
        put(self.level_embedding, &p.level_embedding);
        out
    }

    /// Writes a flat vector (parameters or gradients) back into a `Params` of this layout
    /// (normalisers untouched).
    pub fn unflatten<R: Real>(&self, flat: &[R], p: &mut Params) {
        let get = |at: usize, dst: &mut [f32]| {
            for (d, s) in dst.iter_mut().zip(&flat[at..]) {
                *d = s.to_f64() as f32;
            }
        };
        for (m, at) in p.mlps.iter_mut().zip(self.mlps.iter()) {
            for (l, la) in m.layers.iter_mut().zip(&at.layers) {
                get(la.w, &mut l.weight);
                get(la.b, &mut l.bias);
            }
            if let (Some(n), Some((g, b))) = (&mut m.norm, at.norm) {
                get(g, &mut n.gamma);
                get(b, &mut n.beta);
            }
        }
        get(self.node_type_embedding, &mut p.node_type_embedding);
        get(self.level_embedding, &mut p.level_embedding);
    }

    /// The weight matrices that bf16 precision runs in bf16: every Linear weight outside the
    /// encoders (the runtime encodes in f32 under bf16 too, [`crate::sim::Precision::Bf16`]).
    /// Biases, LayerNorms and embeddings are f32 in both precisions.
    pub fn bf16_weights(&self) -> impl Iterator<Item = Range<usize>> + '_ {
        self.mlps.after_encoders().flat_map(|m| m.layers.iter().map(|l| l.w..l.w + l.inp * l.out))
    }

    /// Rounds the [`bf16_weights`](Self::bf16_weights) of a flat vector to bf16 values (in f32),
    /// as a model file's bf16 copies round them.
    pub fn round_bf16_weights(&self, flat: &mut [f32]) {
        for r in self.bf16_weights() {
            crate::kernels::round_to_bf16(&mut flat[r]);
        }
    }

    /// Every tensor as `(name, range in the flat vector)`, e.g. `block3.mesh_edge.layer0.weight`,
    /// `block3.body_edge.norm.gamma`, `node_encoder.layer2.bias`, `node_type_embedding` (MLP
    /// names: [`Role::name`](crate::model::Role::name)).
    pub fn tensors(&self, spec: &ModelSpec) -> Vec<(String, Range<usize>)> {
        let mut out = Vec::new();
        let mut mlp = |name: String, m: &MlpAt| {
            for (i, l) in m.layers.iter().enumerate() {
                out.push((format!("{name}.layer{i}.weight"), l.w..l.w + l.inp * l.out));
                out.push((format!("{name}.layer{i}.bias"), l.b..l.b + l.out));
            }
            if let Some((g, b)) = m.norm {
                let n = m.output();
                out.push((format!("{name}.norm.gamma"), g..g + n));
                out.push((format!("{name}.norm.beta"), b..b + n));
            }
        };
        for (shape, m) in Mlps::shapes(spec).iter().zip(self.mlps.iter()) {
            mlp(shape.role.name(), m);
        }
        out.push(("node_type_embedding".into(), self.node_type_embedding..self.node_type_embedding + 81));
        out.push(("level_embedding".into(), self.level_embedding..self.level_embedding + 16));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn train_layout_round_trip_and_cover() {
        let spec = ModelSpec::with_schedule(8, 2, 2, "f,c0 | d:c0,c1 | u:f,c0").unwrap();
        let p = Params::init(&spec, 9).unwrap();
        let lay = Layout::new(&p);
        assert_eq!(lay.len, p.count());
        let flat = lay.flatten::<f32>(&p);
        // Every tensor once, no overlap, no gap.
        let mut ranges: Vec<Range<usize>> = lay.tensors(&spec).into_iter().map(|(_, r)| r).collect();
        ranges.sort_by_key(|r| r.start);
        let mut at = 0;
        for r in &ranges {
            assert_eq!(r.start, at);
            at = r.end;
        }
        assert_eq!(at, lay.len);
        // Back into a Params: identical; a changed entry lands in the tensor the layout names.
        let mut q = Params::init(&spec, 10).unwrap();
        lay.unflatten(&flat, &mut q);
        assert_eq!(q.mlps.node_encoder, p.mlps.node_encoder);
        assert_eq!(q.mlps.blocks, p.mlps.blocks);
        assert_eq!(q.level_embedding, p.level_embedding);
        let mut f2 = flat.clone();
        let b = &lay.mlps.blocks[1].edges[1].layers[0];
        f2[b.w + 3 * b.inp + 5] = 42.0;
        lay.unflatten(&f2, &mut q);
        assert_eq!(q.mlps.blocks[1].edges[1].layers[0].weight[3 * b.inp + 5], 42.0);
        assert_eq!(lay.flatten::<f32>(&q), f2);
        // The bf16 weights: every weight matrix but the encoders', and nothing else.
        let names = lay.tensors(&spec);
        let bf16: Vec<Range<usize>> = lay.bf16_weights().collect();
        let expected: Vec<Range<usize>> = names
            .iter()
            .filter(|(n, _)| n.ends_with(".weight") && !n.contains("encoder"))
            .map(|(_, r)| r.clone())
            .collect();
        assert_eq!(bf16, expected);
        assert!(names.iter().any(|(n, _)| n.starts_with("node_encoder")));
        let mut rounded = flat.clone();
        lay.round_bf16_weights(&mut rounded);
        for (name, r) in &names {
            let changed = rounded[r.clone()] != flat[r.clone()];
            assert_eq!(changed, bf16.contains(r), "{name}");
        }
    }
}
