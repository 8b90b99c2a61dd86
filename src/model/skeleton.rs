//! The network's skeleton, described once: which MLPs a model of a [`ModelSpec`] has, in what
//! order, with what widths. The parameters ([`Params`](super::Params)), the model file (its
//! writer and its in-place views), the trainer's flat layout and the reference converter all
//! hold their MLPs in an [`Mlps`] and visit them in its one order (MODEL.md section 4):
//! node encoder, edge encoders ([`ModelSpec::encoded_keys`] order), body-edge encoder, then per
//! processor block its edge MLPs (the block's key order), its body-edge MLP and its node MLP,
//! then the decoder.

use super::spec::{EdgeKey, ModelSpec};
use crate::features::{BODY_EDGE_WIDTH, EDGE_WIDTH, NODE_WIDTH};
use alloc::format;
use alloc::string::String;
use alloc::vec::Vec;
use core::iter::once;

/// Which MLP of the network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Node encoder (node features -> latent).
    NodeEncoder,
    /// Edge encoder of one edge set (edge features -> latent).
    EdgeEncoder(EdgeKey),
    /// Body-edge encoder (both directions).
    BodyEncoder,
    /// Processor block `block`'s edge MLP of edge set `key`.
    BlockEdge {
        /// Block index.
        block: usize,
        /// Its edge set.
        key: EdgeKey,
    },
    /// Processor block `block`'s body-edge MLP.
    BlockBody {
        /// Block index.
        block: usize,
    },
    /// Processor block `block`'s node MLP.
    BlockNode {
        /// Block index.
        block: usize,
    },
    /// Decoder (latent -> acceleration, no LayerNorm).
    Decoder,
}

impl Role {
    /// The name of the MLP's tensors in training checkpoints (`node_encoder`,
    /// `edge_encoder.mesh_edge`, `body_encoder`, `block3.coarse_edge0`, `block3.body_edge`,
    /// `block3.node`, `decoder`).
    pub fn name(self) -> String {
        match self {
            Role::NodeEncoder => "node_encoder".into(),
            Role::EdgeEncoder(k) => format!("edge_encoder.{}", k.reference_name()),
            Role::BodyEncoder => "body_encoder".into(),
            Role::BlockEdge { block, key } => format!("block{block}.{}", key.reference_name()),
            Role::BlockBody { block } => format!("block{block}.body_edge"),
            Role::BlockNode { block } => format!("block{block}.node"),
            Role::Decoder => "decoder".into(),
        }
    }
}

/// One MLP's place and widths.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MlpShape {
    /// Which MLP.
    pub role: Role,
    /// Input width.
    pub input: usize,
    /// Output width.
    pub output: usize,
    /// Whether a LayerNorm follows the last layer (all MLPs but the decoder).
    pub norm: bool,
    /// The first layer's input as equal column parts, each multiplied on its own by the kernels
    /// (the gathered node projections of an edge MLP, the aggregated messages of a node MLP);
    /// `None` for one part.
    pub first_layer_parts: Option<usize>,
}

/// One processor block's MLPs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Block<M> {
    /// One edge MLP per edge set of the block, in the block's key order.
    pub edges: Vec<M>,
    /// The body-edge MLP (both directions), when the model has a body.
    pub body: Option<M>,
    /// The node MLP (garment and body nodes).
    pub node: M,
}

/// Something per MLP of the network (its parameters, shape, offsets, or view), in the
/// skeleton's structure.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mlps<M> {
    /// Node encoder.
    pub node_encoder: M,
    /// Edge encoders in [`ModelSpec::encoded_keys`] order.
    pub edge_encoders: Vec<M>,
    /// Body-edge encoder, when the model has a body.
    pub body_encoder: Option<M>,
    /// Processor blocks.
    pub blocks: Vec<Block<M>>,
    /// Decoder.
    pub decoder: M,
}

impl Mlps<MlpShape> {
    /// The skeleton of `spec`: every MLP's role and widths. Widths saturate, so that a spec read
    /// from a damaged file cannot overflow them (such a spec fails [`ModelSpec::validate`]).
    pub fn shapes(spec: &ModelSpec) -> Mlps<MlpShape> {
        let h = spec.latent;
        let latent =
            |role, input, first_layer_parts| MlpShape { role, input, output: h, norm: true, first_layer_parts };
        let body = spec.effects.body;
        Mlps {
            node_encoder: latent(Role::NodeEncoder, NODE_WIDTH, None),
            edge_encoders: spec
                .encoded_keys()
                .into_iter()
                .map(|k| latent(Role::EdgeEncoder(k), EDGE_WIDTH, None))
                .collect(),
            body_encoder: body.then(|| latent(Role::BodyEncoder, BODY_EDGE_WIDTH, None)),
            blocks: spec
                .blocks
                .iter()
                .enumerate()
                .map(|(block, b)| {
                    let k = spec.node_inputs(b);
                    Block {
                        edges: b
                            .keys
                            .iter()
                            .map(|&key| latent(Role::BlockEdge { block, key }, h.saturating_mul(3), Some(3)))
                            .collect(),
                        body: body.then(|| latent(Role::BlockBody { block }, h.saturating_mul(3), Some(3))),
                        node: latent(Role::BlockNode { block }, h.saturating_mul(k), Some(k)),
                    }
                })
                .collect(),
            decoder: MlpShape { role: Role::Decoder, input: h, output: 3, norm: false, first_layer_parts: None },
        }
    }
}

impl<M> Mlps<M> {
    /// Every MLP in the skeleton's order.
    pub fn iter(&self) -> impl Iterator<Item = &M> + '_ {
        let blocks = self.blocks.iter().flat_map(|b| b.edges.iter().chain(b.body.iter()).chain(once(&b.node)));
        self.encoders().chain(blocks).chain(once(&self.decoder))
    }

    /// The encoders (node, edges, body edges): the first MLPs of [`iter`](Self::iter).
    pub fn encoders(&self) -> impl Iterator<Item = &M> + '_ {
        once(&self.node_encoder).chain(self.edge_encoders.iter()).chain(self.body_encoder.iter())
    }

    /// The MLPs after the encoders (the blocks' and the decoder), in the skeleton's order: those
    /// bf16 precision runs on bf16 weights.
    pub fn after_encoders(&self) -> impl Iterator<Item = &M> + '_ {
        self.iter().skip(self.encoders().count())
    }

    /// Every MLP in the skeleton's order, mutable.
    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut M> + '_ {
        let blocks =
            self.blocks.iter_mut().flat_map(|b| b.edges.iter_mut().chain(b.body.iter_mut()).chain(once(&mut b.node)));
        once(&mut self.node_encoder)
            .chain(self.edge_encoders.iter_mut())
            .chain(self.body_encoder.iter_mut())
            .chain(blocks)
            .chain(once(&mut self.decoder))
    }

    /// The same structure with `f` of every MLP, called in the skeleton's order; the first
    /// error stops it.
    ///
    /// # Errors
    /// The first error of `f`.
    pub fn try_map<N, E>(&self, mut f: impl FnMut(&M) -> Result<N, E>) -> Result<Mlps<N>, E> {
        self.zip_map(self, |m, _| f(m))
    }

    /// The same structure with `f` of every MLP, called in the skeleton's order.
    pub fn map<N>(&self, mut f: impl FnMut(&M) -> N) -> Mlps<N> {
        let mapped: Result<Mlps<N>, core::convert::Infallible> = self.try_map(|m| Ok(f(m)));
        match mapped {
            Ok(n) => n,
            Err(e) => match e {},
        }
    }

    /// Whether `other` has the same structure (edge encoders, body encoder, blocks with their
    /// edge and body MLPs).
    pub fn same_structure<N>(&self, other: &Mlps<N>) -> bool {
        self.edge_encoders.len() == other.edge_encoders.len()
            && self.body_encoder.is_some() == other.body_encoder.is_some()
            && self.blocks.len() == other.blocks.len()
            && self
                .blocks
                .iter()
                .zip(&other.blocks)
                .all(|(a, b)| a.edges.len() == b.edges.len() && a.body.is_some() == b.body.is_some())
    }

    /// The same structure with `f` of every MLP and its counterpart in `other`, called in the
    /// skeleton's order.
    ///
    /// # Errors
    /// `mismatch()` when the structures differ ([`same_structure`](Self::same_structure));
    /// otherwise the first error of `f`.
    pub fn try_zip_map<N, O, E>(
        &self,
        other: &Mlps<O>,
        mismatch: impl FnOnce() -> E,
        f: impl FnMut(&M, &O) -> Result<N, E>,
    ) -> Result<Mlps<N>, E> {
        if !self.same_structure(other) {
            return Err(mismatch());
        }
        self.zip_map(other, f)
    }

    /// [`try_zip_map`](Self::try_zip_map) for structures known to be the same (any surplus of
    /// either side is skipped).
    fn zip_map<N, O, E>(&self, other: &Mlps<O>, mut f: impl FnMut(&M, &O) -> Result<N, E>) -> Result<Mlps<N>, E> {
        let node_encoder = f(&self.node_encoder, &other.node_encoder)?;
        let mut edge_encoders = Vec::with_capacity(self.edge_encoders.len());
        for (a, b) in self.edge_encoders.iter().zip(&other.edge_encoders) {
            edge_encoders.push(f(a, b)?);
        }
        let body_encoder = match (&self.body_encoder, &other.body_encoder) {
            (Some(a), Some(b)) => Some(f(a, b)?),
            _ => None,
        };
        let mut blocks = Vec::with_capacity(self.blocks.len());
        for (a, b) in self.blocks.iter().zip(&other.blocks) {
            let mut edges = Vec::with_capacity(a.edges.len());
            for (x, y) in a.edges.iter().zip(&b.edges) {
                edges.push(f(x, y)?);
            }
            let body = match (&a.body, &b.body) {
                (Some(x), Some(y)) => Some(f(x, y)?),
                _ => None,
            };
            blocks.push(Block { edges, body, node: f(&a.node, &b.node)? });
        }
        let decoder = f(&self.decoder, &other.decoder)?;
        Ok(Mlps { node_encoder, edge_encoders, body_encoder, blocks, decoder })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skeleton_order_and_parameter_count() {
        let spec = ModelSpec::hood(16);
        let shapes = Mlps::shapes(&spec);
        let roles: Vec<Role> = shapes.iter().map(|s| s.role).collect();
        assert_eq!(roles.first(), Some(&Role::NodeEncoder));
        assert_eq!(roles.last(), Some(&Role::Decoder));
        assert_eq!(
            roles[1..1 + spec.encoded_keys().len()],
            spec.encoded_keys().iter().map(|&k| Role::EdgeEncoder(k)).collect::<Vec<_>>()[..]
        );
        assert_eq!(roles.iter().filter(|r| matches!(r, Role::BlockNode { .. })).count(), spec.blocks.len());
        let mlp = |s: &MlpShape| -> usize {
            let layers: usize = spec.mlp_dims(s.input, s.output).iter().map(|&(i, o)| i * o + o).sum();
            layers + if s.norm { 2 * s.output } else { 0 }
        };
        let total: usize = shapes.iter().map(mlp).sum();
        assert_eq!(total + 9 * 9 + 4 * 4, spec.parameter_count());
        let mut seen = 0;
        let indices = shapes.map(|_| {
            seen += 1;
            seen
        });
        assert!(indices.iter().copied().eq(1..=roles.len()), "map visits in the skeleton's order");
        assert!(indices.same_structure(&shapes));
        let mut other = shapes.clone();
        other.blocks[2].edges.pop();
        assert!(!other.same_structure(&shapes));
        assert_eq!(shapes.try_zip_map(&other, || "mismatch", |_, _| Ok(())).err(), Some("mismatch"));
    }
}
