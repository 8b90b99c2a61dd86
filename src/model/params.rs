//! The model's parameters in their master form: every Linear layer as PyTorch stores it
//! (`weight` is `[out, in]` row-major, `y = x W^T + b`), LayerNorms, embedding tables and the four
//! normalisers. The trainer updates this form; model files hold it packed for the kernels.

use super::skeleton::{MlpShape, Mlps, Role};
use super::spec::{EdgeKey, ModelSpec};
use crate::error::{Error, Result};
use crate::features::{BODY_EDGE_WIDTH, EDGE_NORMALISED, LEVELS, NODE_NORMALISED, NODE_TYPES};
use crate::normaliser::Normaliser;
use crate::rng::Rng;
use alloc::vec;
use alloc::vec::Vec;

/// A fully connected layer `y = x W^T + b`.
#[derive(Clone, Debug, PartialEq)]
pub struct Linear {
    /// Input width.
    pub inp: usize,
    /// Output width.
    pub out: usize,
    /// `[out, in]`, row-major.
    pub weight: Vec<f32>,
    /// `[out]`.
    pub bias: Vec<f32>,
}

impl Linear {
    /// PyTorch's default initialisation: weight and bias uniform in `±1/sqrt(in)`.
    pub fn init(inp: usize, out: usize, rng: &mut Rng) -> Linear {
        let bound = 1.0 / crate::math::sqrt_f64(inp.max(1) as f64);
        let weight = (0..inp * out).map(|_| rng.uniform(-bound, bound) as f32).collect();
        let bias = (0..out).map(|_| rng.uniform(-bound, bound) as f32).collect();
        Linear { inp, out, weight, bias }
    }
}

/// LayerNorm's affine parameters (eps 1e-5).
#[derive(Clone, Debug, PartialEq)]
pub struct LayerNorm {
    /// Scale.
    pub gamma: Vec<f32>,
    /// Shift.
    pub beta: Vec<f32>,
}

/// LayerNorm's epsilon (PyTorch default): the kernels' [`crate::kernels::LN_EPS`].
pub const LAYER_NORM_EPS: f32 = crate::kernels::LN_EPS;

/// Linear-ReLU-...-Linear, optionally followed by LayerNorm.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    /// The Linear layers; ReLU between consecutive ones.
    pub layers: Vec<Linear>,
    /// The final LayerNorm (all MLPs but the decoder).
    pub norm: Option<LayerNorm>,
}

impl Mlp {
    /// A freshly initialised MLP of `spec`'s depth.
    pub fn init(spec: &ModelSpec, input: usize, output: usize, norm: bool, rng: &mut Rng) -> Mlp {
        let layers = spec.mlp_dims(input, output).iter().map(|&(i, o)| Linear::init(i, o, rng)).collect();
        let norm = norm.then(|| LayerNorm { gamma: vec![1.0; output], beta: vec![0.0; output] });
        Mlp { layers, norm }
    }

    /// Input width.
    pub fn input(&self) -> usize {
        self.layers.first().map_or(0, |l| l.inp)
    }

    /// Output width.
    pub fn output(&self) -> usize {
        self.layers.last().map_or(0, |l| l.out)
    }
}

/// The four normalisers.
#[derive(Clone, Debug, PartialEq)]
pub struct Normalisers {
    /// Node features (21 columns).
    pub node: Normaliser,
    /// Mesh and coarse edge features (9 columns).
    pub edge: Normaliser,
    /// Body edge features (9 columns).
    pub body_edge: Normaliser,
    /// Output accelerations (3 columns).
    pub output: Normaliser,
}

impl Normalisers {
    /// Empty statistics.
    pub fn new() -> Self {
        Normalisers {
            node: Normaliser::new(NODE_NORMALISED),
            edge: Normaliser::new(EDGE_NORMALISED),
            body_edge: Normaliser::new(BODY_EDGE_WIDTH),
            output: Normaliser::new(3),
        }
    }
}

impl Normalisers {
    /// Statistics of seeded random unit-scale data (nodes ~1, edges ~5 cm, body edges ~2 cm,
    /// outputs ~1 mm/frame^2): what an untrained model needs so that its features and outputs
    /// stay in a sensible range, for timing and for tests.
    pub fn unit_scale(seed: u64) -> Normalisers {
        let mut n = Normalisers::new();
        let mut rng = Rng::new(seed ^ 0x5eed);
        let mut fill = |norm: &mut Normaliser, w: usize, scale: f64| {
            let rows: Vec<f32> = (0..64 * w).map(|_| (rng.normal() * scale) as f32).collect();
            norm.accumulate(&rows, w);
        };
        fill(&mut n.node, NODE_NORMALISED, 1.0);
        fill(&mut n.edge, EDGE_NORMALISED, 0.05);
        fill(&mut n.body_edge, BODY_EDGE_WIDTH, 0.02);
        fill(&mut n.output, 3, 1e-3);
        n
    }
}

impl Default for Normalisers {
    fn default() -> Self {
        Self::new()
    }
}

/// Every parameter of a model.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// The shape.
    pub spec: ModelSpec,
    /// Every MLP, as [`Mlps::shapes`] of the spec describes them.
    pub mlps: Mlps<Mlp>,
    /// Node-type embedding, 9 x 9 row-major.
    pub node_type_embedding: Vec<f32>,
    /// Vertex-level embedding, 4 x 4 row-major.
    pub level_embedding: Vec<f32>,
    /// Normaliser statistics.
    pub normalisers: Normalisers,
}

impl Params {
    /// Random initialisation as PyTorch does it (embeddings standard normal), seeded.
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] for an invalid spec.
    pub fn init(spec: &ModelSpec, seed: u64) -> Result<Params> {
        spec.validate()?;
        let mut rng = Rng::new(seed);
        let mlps = Mlps::shapes(spec).map(|s| Mlp::init(spec, s.input, s.output, s.norm, &mut rng));
        let node_type_embedding = (0..NODE_TYPES * NODE_TYPES).map(|_| rng.normal() as f32).collect();
        let level_embedding = (0..LEVELS * LEVELS).map(|_| rng.normal() as f32).collect();
        Ok(Params { spec: spec.clone(), mlps, node_type_embedding, level_embedding, normalisers: Normalisers::new() })
    }

    /// The edge encoder of `key`, if the model encodes it.
    pub fn edge_encoder(&self, key: EdgeKey) -> Option<&Mlp> {
        self.mlps.edge_encoders.get(self.spec.encoder_index(key)?)
    }

    /// Every trainable tensor, mutable, in the skeleton's order of MLPs ([`Mlps::iter`];
    /// each layer's weight then bias, then the LayerNorm), followed by the two embedding tables.
    pub fn tensors_mut(&mut self) -> Vec<&mut [f32]> {
        let mlps = self.mlps.iter_mut();
        let mut out: Vec<&mut [f32]> = Vec::new();
        for m in mlps {
            for l in &mut m.layers {
                out.push(&mut l.weight);
                out.push(&mut l.bias);
            }
            if let Some(n) = &mut m.norm {
                out.push(&mut n.gamma);
                out.push(&mut n.beta);
            }
        }
        out.push(&mut self.node_type_embedding);
        out.push(&mut self.level_embedding);
        out
    }

    /// The element-wise mean of several models of one spec (weight averaging of training
    /// snapshots: the snapshots of one run sit in one basin, and their mean is usually smoother
    /// than any of them). The normaliser statistics are those of the last model, which has
    /// seen the most data.
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] when `models` is empty or the specs differ.
    pub fn average(models: &[Params]) -> Result<Params> {
        let Some(last) = models.last() else {
            return Err(Error::IncompatibleModel { reason: "no models to average" });
        };
        if models.iter().any(|m| m.spec != last.spec) {
            return Err(Error::IncompatibleModel { reason: "averaged models differ in shape" });
        }
        let mut mean = last.clone();
        let mut sums: Vec<Vec<f64>> = mean.tensors_mut().iter().map(|t| vec![0.0; t.len()]).collect();
        for m in models {
            let mut m = m.clone();
            for (sum, t) in sums.iter_mut().zip(m.tensors_mut()) {
                for (s, &x) in sum.iter_mut().zip(t.iter()) {
                    *s += f64::from(x);
                }
            }
        }
        let n = models.len() as f64;
        for (sum, t) in sums.iter().zip(mean.tensors_mut()) {
            for (x, &s) in t.iter_mut().zip(sum) {
                *x = (s / n) as f32;
            }
        }
        Ok(mean)
    }

    /// Trainable parameter count (must equal [`ModelSpec::parameter_count`]).
    pub fn count(&self) -> usize {
        let mlp: usize = self
            .mlps
            .iter()
            .map(|m| {
                m.layers.iter().map(|l| l.weight.len() + l.bias.len()).sum::<usize>()
                    + m.norm.as_ref().map_or(0, |n| n.gamma.len() + n.beta.len())
            })
            .sum();
        mlp + self.node_type_embedding.len() + self.level_embedding.len()
    }

    /// Checks every tensor's size against the spec.
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] naming the first inconsistency.
    pub fn validate(&self) -> Result<()> {
        self.spec.validate()?;
        let bad = |reason| Err(Error::IncompatibleModel { reason });
        let check_mlp = |m: &Mlp, s: &MlpShape| -> bool {
            let dims = self.spec.mlp_dims(s.input, s.output);
            m.layers.len() == dims.len()
                && m.layers
                    .iter()
                    .zip(&dims)
                    .all(|(l, &(a, b))| l.inp == a && l.out == b && l.weight.len() == a * b && l.bias.len() == b)
                && match (&m.norm, s.norm) {
                    (Some(n), true) => n.gamma.len() == s.output && n.beta.len() == s.output,
                    (None, false) => true,
                    _ => false,
                }
        };
        let shapes = Mlps::shapes(&self.spec);
        if !self.mlps.same_structure(&shapes) {
            return bad("the MLPs disagree with the spec's structure");
        }
        if let Some(s) = self.mlps.iter().zip(shapes.iter()).find_map(|(m, s)| (!check_mlp(m, s)).then_some(s)) {
            return bad(shape_error(s.role));
        }
        if self.node_type_embedding.len() != NODE_TYPES * NODE_TYPES || self.level_embedding.len() != LEVELS * LEVELS {
            return bad("embedding table shape");
        }
        let n = &self.normalisers;
        if n.node.width() != NODE_NORMALISED
            || n.edge.width() != EDGE_NORMALISED
            || n.body_edge.width() != BODY_EDGE_WIDTH
            || n.output.width() != 3
        {
            return bad("normaliser widths");
        }
        Ok(())
    }
}

/// The message of [`Params::validate`] for an MLP of the wrong shape.
fn shape_error(role: Role) -> &'static str {
    match role {
        Role::NodeEncoder => "node encoder shape",
        Role::EdgeEncoder(_) => "edge encoder shapes",
        Role::BodyEncoder => "body encoder shape",
        Role::BlockEdge { .. } | Role::BlockBody { .. } | Role::BlockNode { .. } => "processor block shape",
        Role::Decoder => "decoder shape",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_params_average_is_the_elementwise_mean() {
        let spec = ModelSpec::hood(16);
        let a = Params::init(&spec, 1).unwrap();
        let mut b = Params::init(&spec, 2).unwrap();
        b.normalisers = Normalisers::unit_scale(9);
        let mean = Params::average(&[a.clone(), b.clone()]).unwrap();
        mean.validate().unwrap();
        let (mut a, mut b, mut m) = (a, b.clone(), mean.clone());
        let (ta, tb, tm) = (a.tensors_mut(), b.tensors_mut(), m.tensors_mut());
        assert_eq!(tm.iter().map(|t| t.len()).sum::<usize>(), spec.parameter_count());
        for ((x, y), z) in ta.iter().zip(&tb).zip(&tm) {
            for ((x, y), z) in x.iter().zip(y.iter()).zip(z.iter()) {
                assert!((z - 0.5 * (x + y)).abs() <= 1e-6 * (1.0 + x.abs() + y.abs()), "{z} vs {x}, {y}");
            }
        }
        assert_eq!(mean.normalisers, b.normalisers);
        assert_eq!(Params::average(&[a.clone()]).unwrap(), a);
        assert!(Params::average(&[]).is_err());
        assert!(Params::average(&[a, Params::init(&ModelSpec::hood(32), 1).unwrap()]).is_err());
    }

    #[test]
    fn model_params_init_matches_spec() {
        for h in [16, 32, 128] {
            let spec = ModelSpec::hood(h);
            let p = Params::init(&spec, 3).unwrap();
            assert_eq!(p.count(), spec.parameter_count());
            p.validate().unwrap();
        }
        let p = Params::init(&ModelSpec::hood(128), 3).unwrap();
        // PyTorch's bound for a 384-wide input.
        let w = &p.mlps.blocks[0].edges[0].layers[0].weight;
        let bound = 1.0 / 384f32.sqrt();
        assert!(w.iter().all(|x| x.abs() <= bound));
        assert!(w.iter().any(|x| x.abs() > 0.9 * bound));
        assert_ne!(Params::init(&ModelSpec::hood(16), 4).unwrap(), Params::init(&ModelSpec::hood(16), 3).unwrap());
    }
}
