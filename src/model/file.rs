//! The `.hood` model file: a 16-byte header (magic `HOODMDL\0`, format version, the CRC-32 of
//! the archive) and an rkyv archive of the model with every layer already packed for the kernels, in f32 and
//! (optionally) bf16, plus the shape, the normalisers and provenance.
//!
//! Loading ([`Model::from_bytes`]) validates the header, the archive's checksum (so that a
//! damaged file is refused, not run with wrong weights), the archive (bounds, pointers, UTF-8)
//! and every array size against the spec, then reads the weights **in place**: no copy, no
//! repacking, so a buffer the engine memory-maps can be used directly. It must be 16-byte
//! aligned and outlive the [`Model`]. Files are little-endian; a big-endian CPU is refused.
//!
//! Every packed weight array starts on a [`WEIGHT_ALIGN`]-byte boundary of a buffer aligned to
//! [`WEIGHT_ALIGN`] (as [`ModelBytes`] is), so no vector load of a weight spans two cache lines.
//!
//! Layers: the first layer of every processor MLP is stored in parts of `h` input columns (edge
//! MLPs: target, source, edge; node MLPs: the node latent, then one part per aggregate), so the
//! kernels can apply the split first layer and the never-materialised concatenation; all other
//! layers are one part.

use super::params::{LayerNorm, Linear, Mlp, Normalisers, Params};
use super::skeleton::{Block, MlpShape, Mlps};
use super::spec::{parse_schedule, ModelEffects, ModelSpec};
use crate::error::{Error, Result};
use crate::features::{BODY_EDGE_WIDTH, EDGE_NORMALISED, LEVELS, NODE_NORMALISED, NODE_TYPES};
use crate::kernels::{self, PackedBf16, PackedF32, Weights};
use crate::normaliser::{NormStats, Normaliser};
use alloc::string::{String, ToString};
use alloc::vec;
use alloc::vec::Vec;
use half::bf16;
use rkyv::{Archive, Deserialize, Serialize};

/// First eight bytes of every `.hood` file.
pub const MAGIC: [u8; 8] = *b"HOODMDL\0";
/// The format version this build writes: 2, whose header's last word is the CRC-32 of the
/// archive. Version 1 (that word zero, no checksum) is still read.
pub const FORMAT_VERSION: u32 = 2;
/// Bytes before the archive.
pub const HEADER_LEN: usize = 16;
/// Required alignment of a model buffer.
pub const ALIGN: usize = 16;
/// Alignment, from the start of the file, at which the writer places every packed weight array:
/// one cache line. A buffer aligned to it (as [`ModelBytes`] is) has its weights cache-line
/// aligned; one aligned only to [`ALIGN`] still loads, at the cost of split loads.
pub const WEIGHT_ALIGN: usize = 64;

/// rkyv wrapper for the packed weight arrays of a [`PartRec`]: the same archived vector, preceded
/// by the padding that starts its data at a [`WEIGHT_ALIGN`] file offset (archive positions are
/// [`HEADER_LEN`] bytes short of file offsets). Readers see an ordinary `ArchivedVec`, so files
/// written before it still load.
struct CacheLineAligned;

impl<T: Archive> rkyv::with::ArchiveWith<Vec<T>> for CacheLineAligned {
    type Archived = rkyv::vec::ArchivedVec<T::Archived>;
    type Resolver = rkyv::vec::VecResolver;

    fn resolve_with(field: &Vec<T>, resolver: Self::Resolver, out: rkyv::Place<Self::Archived>) {
        rkyv::vec::ArchivedVec::resolve_from_len(field.len(), resolver, out);
    }
}

impl<T, S> rkyv::with::SerializeWith<Vec<T>, S> for CacheLineAligned
where
    T: Serialize<S>,
    S: rkyv::rancor::Fallible + rkyv::ser::Allocator + rkyv::ser::Writer + ?Sized,
{
    fn serialize_with(field: &Vec<T>, serializer: &mut S) -> core::result::Result<Self::Resolver, S::Error> {
        // The elements of a weight array own no out-of-line data, so nothing is written
        // between this padding and the array. (rkyv's own `pad` takes at most 31 bytes.)
        if !field.is_empty() {
            let file_pos = HEADER_LEN + serializer.pos();
            let padding = (WEIGHT_ALIGN - file_pos % WEIGHT_ALIGN) % WEIGHT_ALIGN;
            serializer.write(&[0; WEIGHT_ALIGN][..padding])?;
        }
        rkyv::vec::ArchivedVec::serialize_from_slice(field.as_slice(), serializer)
    }
}

impl<T, D> rkyv::with::DeserializeWith<rkyv::vec::ArchivedVec<T::Archived>, Vec<T>, D> for CacheLineAligned
where
    T: Archive,
    T::Archived: Deserialize<T, D>,
    D: rkyv::rancor::Fallible + ?Sized,
{
    fn deserialize_with(
        field: &rkyv::vec::ArchivedVec<T::Archived>,
        deserializer: &mut D,
    ) -> core::result::Result<Vec<T>, D::Error> {
        field.iter().map(|x| x.deserialize(deserializer)).collect()
    }
}

#[derive(Archive, Serialize, Deserialize, Debug)]
#[rkyv(derive(Debug))]
struct PartRec {
    /// First input column of `W` in this part.
    col: u32,
    /// Input columns in this part.
    k: u32,
    #[rkyv(with = CacheLineAligned)]
    f32: Vec<f32>,
    /// bf16 bit patterns (empty when the file has no bf16 weights).
    #[rkyv(with = CacheLineAligned)]
    bf16: Vec<u16>,
}

#[derive(Archive, Serialize, Deserialize, Debug)]
#[rkyv(derive(Debug))]
struct LinearRec {
    inp: u32,
    out: u32,
    bias: Vec<f32>,
    parts: Vec<PartRec>,
}

#[derive(Archive, Serialize, Deserialize, Debug)]
#[rkyv(derive(Debug))]
struct MlpRec {
    layers: Vec<LinearRec>,
    /// LayerNorm scale and shift; empty without LayerNorm.
    gamma: Vec<f32>,
    beta: Vec<f32>,
}

#[derive(Archive, Serialize, Deserialize, Debug)]
#[rkyv(derive(Debug))]
struct BlockRec {
    edges: Vec<MlpRec>,
    body: Option<MlpRec>,
    node: MlpRec,
}

#[derive(Archive, Serialize, Deserialize, Debug)]
#[rkyv(derive(Debug))]
struct NormRec {
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    count: f64,
    mean: Vec<f32>,
    std: Vec<f32>,
}

#[derive(Archive, Serialize, Deserialize, Debug)]
#[rkyv(derive(Debug))]
struct ModelRec {
    latent: u32,
    hidden_layers: u32,
    levels: u32,
    schedule: String,
    /// Bit 0 body, bit 1 pinning, bit 2 local materials.
    effects: u8,
    has_bf16: bool,
    node_encoder: MlpRec,
    edge_encoders: Vec<MlpRec>,
    body_encoder: Option<MlpRec>,
    blocks: Vec<BlockRec>,
    decoder: MlpRec,
    node_type_embedding: Vec<f32>,
    level_embedding: Vec<f32>,
    /// node, edge, body edge, output.
    normalisers: Vec<NormRec>,
    provenance: Vec<(String, String)>,
}

fn rkyv_err<E>(_: E) -> Error {
    Error::CorruptData { reason: "model file: the archive failed validation" }
}

/// The column parts of layer `index` of an MLP (see the module docs).
fn split_of(first_layer_parts: Option<usize>, index: usize, inp: usize) -> Vec<(usize, usize)> {
    match first_layer_parts {
        Some(n) if index == 0 && n > 1 && inp.is_multiple_of(n) => (0..n).map(|i| (i * inp / n, inp / n)).collect(),
        _ => vec![(0, inp)],
    }
}

fn pack_linear(l: &Linear, parts: &[(usize, usize)], with_bf16: bool) -> Result<LinearRec> {
    let mut recs = Vec::with_capacity(parts.len());
    for &(col, k) in parts {
        let mut f = vec![0.0f32; kernels::packed_len_f32(k, l.out)];
        kernels::pack_f32(&l.weight, l.out, l.inp, col..col + k, &mut f)?;
        let b = if with_bf16 {
            let mut b = vec![bf16::ZERO; kernels::packed_len_bf16(k, l.out)];
            kernels::pack_bf16(&l.weight, l.out, l.inp, col..col + k, &mut b)?;
            b.iter().map(|x| x.to_bits()).collect()
        } else {
            Vec::new()
        };
        recs.push(PartRec { col: col as u32, k: k as u32, f32: f, bf16: b });
    }
    Ok(LinearRec { inp: l.inp as u32, out: l.out as u32, bias: l.bias.clone(), parts: recs })
}

fn pack_mlp(m: &Mlp, first_layer_parts: Option<usize>, with_bf16: bool) -> Result<MlpRec> {
    let layers = m
        .layers
        .iter()
        .enumerate()
        .map(|(i, l)| pack_linear(l, &split_of(first_layer_parts, i, l.inp), with_bf16))
        .collect::<Result<Vec<_>>>()?;
    let (gamma, beta) = m.norm.as_ref().map_or((Vec::new(), Vec::new()), |n| (n.gamma.clone(), n.beta.clone()));
    Ok(MlpRec { layers, gamma, beta })
}

fn norm_rec(n: &Normaliser) -> NormRec {
    let (sum, sum_sq, count) = n.accumulators();
    let NormStats { mean, std } = n.stats();
    NormRec { sum: sum.to_vec(), sum_sq: sum_sq.to_vec(), count, mean, std }
}

/// Serialises `params` into `.hood` bytes (header + archive), with bf16 copies of every layer
/// when `with_bf16`. `provenance` is free-form key/value text (training config, data,
/// iterations, metrics, commit).
///
/// # Errors
/// [`Error::IncompatibleModel`] if `params` is inconsistent.
pub fn write_model(params: &Params, with_bf16: bool, provenance: &[(&str, &str)]) -> Result<Vec<u8>> {
    params.validate()?;
    let spec = &params.spec;
    let effects = u8::from(spec.effects.body)
        | (u8::from(spec.effects.pinning) << 1)
        | (u8::from(spec.effects.local_materials) << 2);
    let packed = params.mlps.try_zip_map(
        &Mlps::shapes(spec),
        || Error::IncompatibleModel { reason: "the MLPs disagree with the spec's structure" },
        |m, s| pack_mlp(m, s.first_layer_parts, with_bf16),
    )?;
    let blocks = packed.blocks.into_iter().map(|b| BlockRec { edges: b.edges, body: b.body, node: b.node }).collect();
    let n = &params.normalisers;
    let rec = ModelRec {
        latent: spec.latent as u32,
        hidden_layers: spec.hidden_layers as u32,
        levels: spec.levels as u32,
        schedule: super::spec::format_schedule(&spec.blocks),
        effects,
        has_bf16: with_bf16,
        node_encoder: packed.node_encoder,
        edge_encoders: packed.edge_encoders,
        body_encoder: packed.body_encoder,
        blocks,
        decoder: packed.decoder,
        node_type_embedding: params.node_type_embedding.clone(),
        level_embedding: params.level_embedding.clone(),
        normalisers: vec![norm_rec(&n.node), norm_rec(&n.edge), norm_rec(&n.body_edge), norm_rec(&n.output)],
        provenance: provenance.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect(),
    };
    let archive = rkyv::to_bytes::<rkyv::rancor::Error>(&rec).map_err(rkyv_err)?;
    Ok(with_header(&archive))
}

/// The header of the current version (magic, version, the archive's CRC-32) followed by
/// `archive`.
fn with_header(archive: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + archive.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&crate::checksum::crc32(archive).to_le_bytes());
    out.extend_from_slice(archive);
    out
}

/// One layer of a loaded model: bias and the packed parts of `W`, in f32 and (if present) bf16,
/// all borrowed from the model buffer.
#[derive(Clone, Debug)]
pub struct LinearView<'a> {
    /// Position among the model's layers (MLPs in [`Mlps::iter`] order, layers in order), so
    /// that per-layer data can be kept beside the model.
    pub index: usize,
    /// Input width.
    pub inp: usize,
    /// Output width.
    pub out: usize,
    /// Bias, `out`.
    pub bias: &'a [f32],
    /// Column parts in f32, in input order.
    pub f32: Vec<Weights<'a>>,
    /// Column parts in bf16 (empty when the file has none).
    pub bf16: Vec<Weights<'a>>,
}

impl<'a> LinearView<'a> {
    /// The parts in the requested precision.
    pub fn parts(&self, bf16: bool) -> &[Weights<'a>] {
        if bf16 {
            &self.bf16
        } else {
            &self.f32
        }
    }
}

/// One MLP of a loaded model.
#[derive(Clone, Debug)]
pub struct MlpView<'a> {
    /// Linear layers (ReLU between consecutive ones).
    pub layers: Vec<LinearView<'a>>,
    /// Final LayerNorm, if any.
    pub layer_norm: Option<kernels::LayerNorm<'a>>,
}

/// A loaded, validated model whose weights live in the caller's buffer.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    spec: ModelSpec,
    has_bf16: bool,
    /// Every MLP, in the skeleton's structure (read-only outside the crate: checked against the
    /// spec when the file is viewed, and the step relies on that).
    pub(crate) mlps: Mlps<MlpView<'a>>,
    /// Node-type embedding, 9 x 9.
    pub(crate) node_type_embedding: &'a [f32],
    /// Vertex-level embedding, 4 x 4.
    pub(crate) level_embedding: &'a [f32],
    norm: [(&'a [f32], &'a [f32]); 4],
    rec: &'a ArchivedModelRec,
}

fn floats(v: &rkyv::vec::ArchivedVec<rend::f32_le>) -> &[f32] {
    bytemuck::cast_slice(v.as_slice())
}

fn corrupt(reason: &'static str) -> Error {
    Error::CorruptData { reason }
}

fn view_mlp<'a>(m: &'a ArchivedMlpRec, spec: &ModelSpec, shape: &MlpShape, has_bf16: bool) -> Result<MlpView<'a>> {
    let MlpShape { input, output, norm, first_layer_parts, .. } = *shape;
    let dims = spec.mlp_dims(input, output);
    if m.layers.len() != dims.len() {
        return Err(corrupt("model file: an MLP has the wrong number of layers"));
    }
    let mut layers = Vec::with_capacity(dims.len());
    for (i, (l, &(inp, out))) in m.layers.iter().zip(&dims).enumerate() {
        if l.inp.to_native() as usize != inp || l.out.to_native() as usize != out || l.bias.len() != out {
            return Err(corrupt("model file: a layer's width disagrees with the spec"));
        }
        let split = split_of(first_layer_parts, i, inp);
        if l.parts.len() != split.len() {
            return Err(corrupt("model file: a layer has the wrong number of parts"));
        }
        let mut f = Vec::with_capacity(split.len());
        let mut b = Vec::with_capacity(split.len());
        for (p, &(col, k)) in l.parts.iter().zip(&split) {
            if p.col.to_native() as usize != col || p.k.to_native() as usize != k {
                return Err(corrupt("model file: a layer part has the wrong columns"));
            }
            let w = PackedF32::new(floats(&p.f32), k, out).map_err(|_| corrupt("model file: packed f32 size"))?;
            f.push(Weights::F32(w));
            if has_bf16 {
                let bits: &[u16] = bytemuck::cast_slice(p.bf16.as_slice());
                let data: &[bf16] = bytemuck::cast_slice(bits);
                let w = PackedBf16::new(data, k, out).map_err(|_| corrupt("model file: packed bf16 size"))?;
                b.push(Weights::Bf16(w));
            }
        }
        // Numbered by the caller, once every MLP is viewed.
        layers.push(LinearView { index: 0, inp, out, bias: floats(&l.bias), f32: f, bf16: b });
    }
    let layer_norm = match (norm, m.gamma.len(), m.beta.len()) {
        (true, g, b) if g == output && b == output => {
            Some(kernels::LayerNorm { gamma: floats(&m.gamma), beta: floats(&m.beta) })
        }
        (false, 0, 0) => None,
        _ => return Err(corrupt("model file: LayerNorm parameters disagree with the spec")),
    };
    Ok(MlpView { layers, layer_norm })
}

/// The MLP records of an archived model in the skeleton's structure (checked against the spec
/// by the caller).
fn records(rec: &ArchivedModelRec) -> Mlps<&ArchivedMlpRec> {
    Mlps {
        node_encoder: &rec.node_encoder,
        edge_encoders: rec.edge_encoders.iter().collect(),
        body_encoder: rec.body_encoder.as_ref(),
        blocks: rec
            .blocks
            .iter()
            .map(|b| Block { edges: b.edges.iter().collect(), body: b.body.as_ref(), node: &b.node })
            .collect(),
        decoder: &rec.decoder,
    }
}

impl<'a> Model<'a> {
    /// Validates `bytes` and views the model in place.
    ///
    /// # Errors
    /// [`Error::CorruptData`] for a wrong magic, another format version, a misaligned buffer
    /// (see [`ALIGN`]), a truncated or corrupt archive, or arrays that disagree with the spec;
    /// [`Error::IncompatibleModel`] for an invalid spec; [`Error::CapacityExceeded`] for a
    /// buffer, or a spec's weights, beyond [`crate::limits::MAX_MODEL_BYTES`] (checked before
    /// any layer is viewed).
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Model<'a>> {
        if cfg!(target_endian = "big") {
            return Err(corrupt("model files are little-endian; this CPU is big-endian"));
        }
        if bytes.len() < HEADER_LEN || bytes[..8] != MAGIC {
            return Err(corrupt("not a .hood model file (bad magic)"));
        }
        crate::limits::within("model file bytes", bytes.len(), crate::limits::MAX_MODEL_BYTES)?;
        let word = |k: usize| u32::from_le_bytes([bytes[k], bytes[k + 1], bytes[k + 2], bytes[k + 3]]);
        let version = word(8);
        if version != FORMAT_VERSION && version != 1 {
            return Err(corrupt("unsupported .hood format version"));
        }
        if !(bytes.as_ptr() as usize).is_multiple_of(ALIGN) {
            return Err(corrupt("model buffer is not 16-byte aligned"));
        }
        if version == 1 && word(12) != 0 {
            return Err(corrupt("version-1 header with a non-zero reserved word"));
        }
        if version == FORMAT_VERSION && crate::checksum::crc32(&bytes[HEADER_LEN..]) != word(12) {
            return Err(corrupt("checksum mismatch: the file is damaged"));
        }
        let rec = rkyv::access::<ArchivedModelRec, rkyv::rancor::Error>(&bytes[HEADER_LEN..]).map_err(rkyv_err)?;
        let e = rec.effects;
        let spec = ModelSpec {
            latent: rec.latent.to_native() as usize,
            hidden_layers: rec.hidden_layers.to_native() as usize,
            blocks: parse_schedule(rec.schedule.as_str())?,
            levels: rec.levels.to_native() as usize,
            effects: ModelEffects { body: e & 1 != 0, pinning: e & 2 != 0, local_materials: e & 4 != 0 },
        };
        spec.validate()?;
        let has_bf16 = rec.has_bf16;
        let mismatch = || corrupt("model file: the MLPs disagree with the spec");
        let mut mlps =
            records(rec).try_zip_map(&Mlps::shapes(&spec), mismatch, |m, s| view_mlp(m, &spec, s, has_bf16))?;
        for (index, layer) in mlps.iter_mut().flat_map(|m| &mut m.layers).enumerate() {
            layer.index = index;
        }
        let node_type_embedding = floats(&rec.node_type_embedding);
        let level_embedding = floats(&rec.level_embedding);
        if node_type_embedding.len() != NODE_TYPES * NODE_TYPES || level_embedding.len() != LEVELS * LEVELS {
            return Err(corrupt("model file: embedding table size"));
        }
        let widths = [NODE_NORMALISED, EDGE_NORMALISED, BODY_EDGE_WIDTH, 3];
        if rec.normalisers.len() != 4 {
            return Err(corrupt("model file: wrong number of normalisers"));
        }
        let mut norm = [(&[][..], &[][..]); 4];
        for (i, (n, w)) in rec.normalisers.iter().zip(widths).enumerate() {
            let (mean, std) = (floats(&n.mean), floats(&n.std));
            if mean.len() != w || std.len() != w || n.sum.len() != w || n.sum_sq.len() != w {
                return Err(corrupt("model file: normaliser width"));
            }
            if mean.iter().chain(std).any(|x| !x.is_finite()) || std.iter().any(|&s| s <= 0.0) {
                return Err(corrupt("model file: non-finite or non-positive normaliser statistics"));
            }
            norm[i] = (mean, std);
        }
        Ok(Model { spec, has_bf16, mlps, node_type_embedding, level_embedding, norm, rec })
    }

    /// The model's shape.
    pub fn spec(&self) -> &ModelSpec {
        &self.spec
    }

    /// Every MLP, in the skeleton's structure.
    pub fn mlps(&self) -> &Mlps<MlpView<'a>> {
        &self.mlps
    }

    /// Node-type embedding, 9 x 9.
    pub fn node_type_embedding(&self) -> &'a [f32] {
        self.node_type_embedding
    }

    /// Vertex-level embedding, 4 x 4.
    pub fn level_embedding(&self) -> &'a [f32] {
        self.level_embedding
    }

    /// True when the file carries bf16 weights.
    pub fn has_bf16(&self) -> bool {
        self.has_bf16
    }

    /// True when the file carries bf16 weights whose f32 copies are the same values (every layer
    /// after the encoders, as a model trained with bf16-exact weights has them): f32 and bf16
    /// precision then run the same weights and differ only where bf16 products round the
    /// activations. Reads every weight once.
    pub fn bf16_exact(&self) -> bool {
        self.has_bf16
            && self
                .to_params()
                .mlps
                .after_encoders()
                .all(|m| m.layers.iter().all(|l| l.weight.iter().all(|&w| kernels::bf16_value(w) == w)))
    }

    /// Frozen `(mean, std)` of the node normaliser (21 columns).
    pub fn node_stats(&self) -> (&'a [f32], &'a [f32]) {
        self.norm[0]
    }
    /// Frozen `(mean, std)` of the mesh/coarse edge normaliser (9 columns).
    pub fn edge_stats(&self) -> (&'a [f32], &'a [f32]) {
        self.norm[1]
    }
    /// Frozen `(mean, std)` of the body edge normaliser (9 columns).
    pub fn body_edge_stats(&self) -> (&'a [f32], &'a [f32]) {
        self.norm[2]
    }
    /// Frozen `(mean, std)` of the output normaliser (3 columns, m/frame^2).
    pub fn output_stats(&self) -> (&'a [f32], &'a [f32]) {
        self.norm[3]
    }

    /// Provenance entries (training config, data, iterations, metrics, commit).
    pub fn provenance(&self) -> impl Iterator<Item = (&'a str, &'a str)> + 'a {
        self.rec.provenance.iter().map(|t| (t.0.as_str(), t.1.as_str()))
    }

    /// Recovers the master parameters (weights unpacked from the f32 copy, normaliser
    /// accumulators), e.g. to resume training from an exported model.
    pub fn to_params(&self) -> Params {
        fn unpack(m: &MlpView<'_>) -> Mlp {
            let layers = m
                .layers
                .iter()
                .map(|l| {
                    let mut weight = vec![0.0f32; l.out * l.inp];
                    let mut col = 0;
                    for part in &l.f32 {
                        if let Weights::F32(p) = part {
                            for o in 0..l.out {
                                for kk in 0..p.k() {
                                    weight[o * l.inp + col + kk] = p.get(kk, o);
                                }
                            }
                            col += p.k();
                        }
                    }
                    Linear { inp: l.inp, out: l.out, weight, bias: l.bias.to_vec() }
                })
                .collect();
            let norm = m.layer_norm.map(|n| LayerNorm { gamma: n.gamma.to_vec(), beta: n.beta.to_vec() });
            Mlp { layers, norm }
        }
        let n = |i: usize| {
            let r = &self.rec.normalisers[i];
            let v = |a: &rkyv::vec::ArchivedVec<rend::f64_le>| a.iter().map(|x| x.to_native()).collect::<Vec<_>>();
            Normaliser::from_accumulators(&v(&r.sum), &v(&r.sum_sq), r.count.to_native())
        };
        Params {
            spec: self.spec.clone(),
            mlps: self.mlps.map(unpack),
            node_type_embedding: self.node_type_embedding.to_vec(),
            level_embedding: self.level_embedding.to_vec(),
            normalisers: Normalisers { node: n(0), edge: n(1), body_edge: n(2), output: n(3) },
        }
    }
}

/// An owned, aligned copy of model bytes, for callers that do not manage alignment themselves
/// (e.g. a model read from disk).
///
/// # Examples
///
/// ```
/// use hood::model::ModelBytes;
///
/// // From a file, or from bytes already in memory (an engine's asset system): either way the
/// // copy is aligned, and `model()` validates it once and then reads the weights in place.
/// let path = concat!(env!("CARGO_MANIFEST_DIR"), "/models/compact.hood");
/// let from_file = ModelBytes::read(path)?;
/// let in_memory = std::fs::read(path).map_err(|e| hood::Error::io(std::path::Path::new(path), e))?;
/// let from_memory = ModelBytes::new(&in_memory);
/// let model = from_memory.model()?;
/// assert_eq!(model.spec(), from_file.model()?.spec());
/// assert_eq!(model.spec().latent, 32); // the compact model
/// # Ok::<(), hood::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct ModelBytes {
    buf: rkyv::util::AlignedVec<WEIGHT_ALIGN>,
}

impl ModelBytes {
    /// Copies `bytes` into a buffer aligned to [`WEIGHT_ALIGN`].
    pub fn new(bytes: &[u8]) -> ModelBytes {
        let mut buf = rkyv::util::AlignedVec::<WEIGHT_ALIGN>::with_capacity(bytes.len());
        buf.extend_from_slice(bytes);
        ModelBytes { buf }
    }

    /// Reads a `.hood` file.
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read; [`Error::CapacityExceeded`] for a file beyond
    /// [`crate::limits::MAX_MODEL_BYTES`] (before it is read).
    #[cfg(feature = "std")]
    pub fn read(path: impl AsRef<std::path::Path>) -> Result<ModelBytes> {
        let path = path.as_ref();
        let len = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
        let len = usize::try_from(len).unwrap_or(usize::MAX);
        crate::limits::within("model file bytes", len, crate::limits::MAX_MODEL_BYTES)?;
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Ok(ModelBytes::new(&bytes))
    }

    /// The aligned bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.as_slice()
    }

    /// Validates and views the model.
    ///
    /// # Errors
    /// See [`Model::from_bytes`].
    pub fn model(&self) -> Result<Model<'_>> {
        Model::from_bytes(self.as_bytes())
    }
}

#[cfg(test)]
mod tests;
