//! (Feature `tools`.) Reading the reference implementation's (HOOD `postcvpr`) state dict, as
//! safetensors, into [`Params`]. Key names follow `Model.state_dict()`, with or without the
//! `model.` prefix that `Runner.state_dict()` (and so `checkpoint['training_module']`) adds.

use super::params::{LayerNorm, Linear, Mlp, Normalisers, Params};
use super::skeleton::{Mlps, Role};
use super::spec::ModelSpec;
use crate::error::{Error, Result};
use crate::features::{BODY_EDGE_WIDTH, EDGE_NORMALISED, NODE_NORMALISED};
use crate::io::safetensors::SafeTensors;
use crate::normaliser::Normaliser;
use std::format;
use std::string::String;
use std::vec::Vec;

struct Dict<'a> {
    st: &'a SafeTensors,
    prefix: &'static str,
}

impl Dict<'_> {
    fn tensor(&self, key: &str, shape: &[usize]) -> Result<Vec<f32>> {
        let name = format!("{}{key}", self.prefix);
        let t = self.st.f32(&name)?;
        if t.shape != shape {
            return Err(Error::parse("state dict", 0, format!("{name}: shape {:?}, expected {shape:?}", t.shape)));
        }
        Ok(t.data)
    }

    /// `<base>.0.layers.{0,2,4,..}` (+ LayerNorm `<base>.1`) or `<base>.layers.*` without norm.
    fn mlp(&self, spec: &ModelSpec, base: &str, input: usize, output: usize, norm: bool) -> Result<Mlp> {
        let seq = if norm { format!("{base}.0.layers") } else { format!("{base}.layers") };
        let mut layers = Vec::new();
        for (k, (i, o)) in spec.mlp_dims(input, output).into_iter().enumerate() {
            let l = format!("{seq}.{}", 2 * k);
            let weight = self.tensor(&format!("{l}.weight"), &[o, i])?;
            let bias = self.tensor(&format!("{l}.bias"), &[o])?;
            layers.push(Linear { inp: i, out: o, weight, bias });
        }
        let norm = if norm {
            Some(LayerNorm {
                gamma: self.tensor(&format!("{base}.1.weight"), &[output])?,
                beta: self.tensor(&format!("{base}.1.bias"), &[output])?,
            })
        } else {
            None
        };
        Ok(Mlp { layers, norm })
    }

    fn normaliser(&self, name: &str, width: usize) -> Result<Normaliser> {
        let read = |k: &str, shape: &[usize]| -> Result<Vec<f64>> {
            Ok(self.tensor(&format!("_{name}_normalizer.{k}"), shape)?.iter().map(|&x| x as f64).collect())
        };
        let sum = read("_acc_sum", &[1, width])?;
        let sq = read("_acc_sum_squared", &[1, width])?;
        let count = read("_acc_count", &[1])?[0];
        Ok(Normaliser::from_accumulators(&sum, &sq, count))
    }
}

/// Builds [`Params`] of shape `spec` from a reference state dict.
///
/// # Errors
/// [`Error::Parse`] naming a missing or mis-shaped tensor; [`Error::IncompatibleModel`] if the
/// result does not fit `spec`.
pub fn params_from_state_dict(st: &SafeTensors, spec: &ModelSpec) -> Result<Params> {
    spec.validate()?;
    let prefix = if st.info("model._learned_model.decoder.layers.0.weight").is_ok() { "model." } else { "" };
    let d = Dict { st, prefix };
    let mlps = Mlps::shapes(spec).try_map(|s| d.mlp(spec, &reference_name(s.role), s.input, s.output, s.norm))?;
    let node_type_embedding = d.tensor("nodetype_embedding.weight", &[9, 9])?;
    let level_embedding = d.tensor("vertexlevel_embedding.weight", &[4, 4])?;
    let normalisers = Normalisers {
        node: d.normaliser("node", NODE_NORMALISED)?,
        edge: d.normaliser("mesh_edge", EDGE_NORMALISED)?,
        body_edge: d.normaliser("world_edge", BODY_EDGE_WIDTH)?,
        output: d.normaliser("output", 3)?,
    };
    let p = Params { spec: spec.clone(), mlps, node_type_embedding, level_embedding, normalisers };
    p.validate()?;
    Ok(p)
}

/// The reference's name of an MLP. Block `k` (0-based) is `levels.{k / 3}.{k % 3}`, as the
/// reference's 5 x 3 layout has it.
fn reference_name(role: Role) -> String {
    let lm = "_learned_model";
    let block = |k: usize| format!("{lm}.levels.{}.{}", k / 3, k % 3);
    match role {
        Role::NodeEncoder => format!("{lm}.node_encoder"),
        Role::EdgeEncoder(key) => match key.coarse_level() {
            Some(l) => format!("{lm}.edgeset_encoders.coarse{l}"),
            None => format!("{lm}.edgeset_encoders.mesh"),
        },
        Role::BodyEncoder => format!("{lm}.edgeset_encoders.world"),
        Role::BlockEdge { block: k, key } => format!("{}.edge_processor_dict.{}", block(k), key.reference_name()),
        Role::BlockBody { block: k } => format!("{}.edge_processor_dict.world_edge", block(k)),
        Role::BlockNode { block: k } => format!("{}.node_processor_dict.node", block(k)),
        Role::Decoder => format!("{lm}.decoder"),
    }
}

/// Infers the latent width from a reference state dict (the decoder's first layer).
///
/// # Errors
/// [`Error::Parse`] when the decoder is missing.
pub fn latent_width(st: &SafeTensors) -> Result<usize> {
    for name in ["model._learned_model.decoder.layers.0.weight", "_learned_model.decoder.layers.0.weight"] {
        if let Ok(i) = st.info(name) {
            return Ok(i.shape[0]);
        }
    }
    Err(Error::parse("state dict", 0, "no decoder weight found"))
}
