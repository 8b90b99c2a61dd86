//! The shape of a model: latent width, MLP depth, the block schedule, levels and effects
//! (MODEL.md section 4).

use super::skeleton::Mlps;
use crate::error::{Error, Result};
use alloc::vec::Vec;

/// The reference HOOD schedule: 15 blocks going down to c1 and back up.
pub const HOOD_SCHEDULE: &str =
    "f,c0 | f,c0 | f,c0 | d:c0,c1 | c0,c1 | c0,c1 | d:c1 | c1 | c1 | u:c0,c1 | c0,c1 | c0,c1 | u:f,c0 | f,c0 | f,c0";

/// An edge set of the garment graph that a block can pass messages over.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u8)]
pub enum EdgeKey {
    /// Coarse level 0 edges.
    C0 = 0,
    /// Coarse level 1 edges.
    C1 = 1,
    /// Coarse level 2 edges.
    C2 = 2,
    /// Mesh (fine) edges.
    Mesh = 3,
}

impl EdgeKey {
    /// The coarse level of this key, or `None` for mesh edges.
    pub fn coarse_level(self) -> Option<usize> {
        match self {
            EdgeKey::C0 => Some(0),
            EdgeKey::C1 => Some(1),
            EdgeKey::C2 => Some(2),
            EdgeKey::Mesh => None,
        }
    }

    /// The key of coarse level `l` (0..=2).
    pub fn coarse(l: usize) -> Option<EdgeKey> {
        [EdgeKey::C0, EdgeKey::C1, EdgeKey::C2].get(l).copied()
    }

    /// The reference implementation's name (used in checkpoint keys).
    pub fn reference_name(self) -> &'static str {
        match self {
            EdgeKey::C0 => "coarse_edge0",
            EdgeKey::C1 => "coarse_edge1",
            EdgeKey::C2 => "coarse_edge2",
            EdgeKey::Mesh => "mesh_edge",
        }
    }
}

/// A level change marked before a block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LevelChange {
    /// `d:` going down to a coarser level.
    Down,
    /// `u:` coming back up.
    Up,
}

/// One processor block: which garment edge sets pass messages (body edges always do when the
/// model has a body), in the sorted key order C0 < C1 < C2 < Mesh.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BlockSpec {
    /// Level change before this block, if any.
    pub change: Option<LevelChange>,
    /// Garment edge keys, sorted, no duplicates, non-empty.
    pub keys: Vec<EdgeKey>,
}

impl BlockSpec {
    /// The finest key of the block: its garment nodes are those of this edge set (all vertices
    /// for mesh edges), and body edges whose garment end lies outside are filtered out.
    pub fn finest(&self) -> EdgeKey {
        if self.keys.contains(&EdgeKey::Mesh) {
            EdgeKey::Mesh
        } else {
            self.keys[0]
        }
    }
}

/// Parses a schedule string: blocks separated by `|`, each a comma-separated list of `f`
/// (mesh), `c0`, `c1`, `c2`, optionally prefixed by `d:` or `u:`.
///
/// # Errors
/// [`Error::Parse`] (format `"schedule"`) naming the block.
pub fn parse_schedule(s: &str) -> Result<Vec<BlockSpec>> {
    let mut blocks = Vec::new();
    for (i, part) in s.split('|').enumerate() {
        let bad = |m: &str| Error::parse("schedule", 0, alloc::format!("block {}: {m}", i + 1));
        let mut p = part.trim();
        let change = if let Some(r) = p.strip_prefix("d:") {
            p = r;
            Some(LevelChange::Down)
        } else if let Some(r) = p.strip_prefix("u:") {
            p = r;
            Some(LevelChange::Up)
        } else {
            None
        };
        let mut keys = Vec::new();
        for k in p.split(',') {
            let key = match k.trim() {
                "f" => EdgeKey::Mesh,
                "c0" => EdgeKey::C0,
                "c1" => EdgeKey::C1,
                "c2" => EdgeKey::C2,
                "" => return Err(bad("empty edge key")),
                _ => return Err(bad("unknown edge key (use f, c0, c1, c2)")),
            };
            if keys.contains(&key) {
                return Err(bad("repeated edge key"));
            }
            keys.push(key);
        }
        keys.sort_unstable();
        blocks.push(BlockSpec { change, keys });
    }
    Ok(blocks)
}

/// Writes a schedule back in the string form [`parse_schedule`] reads.
pub fn format_schedule(blocks: &[BlockSpec]) -> alloc::string::String {
    let parts: Vec<alloc::string::String> = blocks
        .iter()
        .map(|b| {
            let mut s = alloc::string::String::from(match b.change {
                Some(LevelChange::Down) => "d:",
                Some(LevelChange::Up) => "u:",
                None => "",
            });
            let keys: Vec<&str> = b
                .keys
                .iter()
                .map(|k| match k {
                    EdgeKey::Mesh => "f",
                    EdgeKey::C0 => "c0",
                    EdgeKey::C1 => "c1",
                    EdgeKey::C2 => "c2",
                })
                .collect();
            s.push_str(&keys.join(","));
            s
        })
        .collect();
    parts.join(" | ")
}

/// Effects a model was trained with (a scene may use a subset).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelEffects {
    /// Body nodes and body edges (collision with the body).
    pub body: bool,
    /// Pinned vertices (node type 3 seen in training).
    pub pinning: bool,
    /// Per-vertex materials.
    pub local_materials: bool,
}

impl Default for ModelEffects {
    fn default() -> Self {
        ModelEffects { body: true, pinning: true, local_materials: true }
    }
}

/// The shape of a model.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelSpec {
    /// Latent width h.
    pub latent: usize,
    /// Hidden layers per MLP (HOOD: 2, i.e. Linear-ReLU-Linear-ReLU-Linear).
    pub hidden_layers: usize,
    /// Processor blocks.
    pub blocks: Vec<BlockSpec>,
    /// Coarse levels built and encoded (HOOD: 3; the blocks may use fewer).
    pub levels: usize,
    /// Effects trained with.
    pub effects: ModelEffects,
}

impl ModelSpec {
    /// The reference HOOD architecture at latent width `h`.
    pub fn hood(latent: usize) -> ModelSpec {
        ModelSpec {
            latent,
            hidden_layers: 2,
            blocks: parse_schedule(HOOD_SCHEDULE).unwrap_or_default(),
            levels: 3,
            effects: ModelEffects::default(),
        }
    }

    /// A spec with the given schedule string.
    ///
    /// # Errors
    /// See [`parse_schedule`] and [`ModelSpec::validate`].
    pub fn with_schedule(latent: usize, hidden_layers: usize, levels: usize, schedule: &str) -> Result<ModelSpec> {
        let s = ModelSpec {
            latent,
            hidden_layers,
            blocks: parse_schedule(schedule)?,
            levels,
            effects: ModelEffects::default(),
        };
        s.validate()?;
        Ok(s)
    }

    /// Checks widths, levels, that every block only uses levels that are built, and that the
    /// weights fit the memory budget.
    ///
    /// # Errors
    /// [`Error::IncompatibleModel`] with the reason; [`Error::CapacityExceeded`] when
    /// [`ModelSpec::weight_bytes`] is beyond [`crate::limits::MAX_MODEL_BYTES`].
    pub fn validate(&self) -> Result<()> {
        let bad = |reason| Err(Error::IncompatibleModel { reason });
        if self.latent == 0 || self.latent > 4096 {
            return bad("latent width must be in 1..=4096");
        }
        if self.hidden_layers > 8 {
            return bad("at most 8 hidden layers per MLP");
        }
        if self.blocks.is_empty() {
            return bad("a model needs at least one processor block");
        }
        if self.levels > 3 {
            return bad("at most 3 coarse levels");
        }
        for b in &self.blocks {
            if b.keys.is_empty() {
                return bad("a block without edge keys");
            }
            if b.keys.iter().any(|k| k.coarse_level().is_some_and(|l| l >= self.levels)) {
                return bad("a block uses a coarse level the model does not build");
            }
        }
        let bytes = usize::try_from(self.weight_bytes()).unwrap_or(usize::MAX);
        crate::limits::within("model weights (bytes, f32 and bf16)", bytes, crate::limits::MAX_MODEL_BYTES)
    }

    /// Edge keys whose encoders exist: mesh and every built coarse level.
    pub fn encoded_keys(&self) -> Vec<EdgeKey> {
        let mut k: Vec<EdgeKey> = (0..self.levels).filter_map(EdgeKey::coarse).collect();
        k.push(EdgeKey::Mesh);
        k
    }

    /// Position of `key`'s encoder in [`ModelSpec::encoded_keys`] order, without allocating.
    pub fn encoder_index(&self, key: EdgeKey) -> Option<usize> {
        match key.coarse_level() {
            Some(l) if l < self.levels => Some(l),
            Some(_) => None,
            None => Some(self.levels),
        }
    }

    /// Number of aggregated message slots of block `b` for garment nodes: its keys, plus body.
    pub fn node_inputs(&self, b: &BlockSpec) -> usize {
        1 + b.keys.len() + usize::from(self.effects.body)
    }

    /// Widths `(in, out)` of every Linear layer of an MLP from `input` to `output`.
    pub fn mlp_dims(&self, input: usize, output: usize) -> Vec<(usize, usize)> {
        let h = self.latent;
        let mut d = Vec::with_capacity(self.hidden_layers + 1);
        let mut i = input;
        for _ in 0..self.hidden_layers {
            d.push((i, h));
            i = h;
        }
        d.push((i, output));
        d
    }

    /// Trainable parameter count (embedding tables included); saturates at `usize::MAX`.
    pub fn parameter_count(&self) -> usize {
        usize::try_from(self.parameters()).unwrap_or(usize::MAX)
    }

    /// The parameter count in `u64`, saturating, so that a spec read from a damaged file cannot
    /// overflow it.
    fn parameters(&self) -> u64 {
        let w = |x: usize| x as u64;
        let h = w(self.latent);
        let mlp = |i: u64, o: u64, ln: bool| -> u64 {
            let mut n = if ln { o.saturating_mul(2) } else { 0 };
            let mut i = i;
            for _ in 0..self.hidden_layers {
                n = n.saturating_add(i.saturating_mul(h).saturating_add(h));
                i = h;
            }
            n.saturating_add(i.saturating_mul(o).saturating_add(o))
        };
        let mlps = Mlps::shapes(self);
        let n = mlps.iter().fold(0u64, |n, s| n.saturating_add(mlp(w(s.input), w(s.output), s.norm)));
        n.saturating_add(9 * 9 + 4 * 4)
    }

    /// Bytes of the weights this shape needs in a model file with bf16 copies (4 bytes of f32 and
    /// 2 of bf16 per parameter), saturating; at most [`crate::limits::MAX_MODEL_BYTES`] for a
    /// valid spec.
    pub fn weight_bytes(&self) -> u64 {
        self.parameters().saturating_mul(6)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec;

    #[test]
    fn model_spec_hood_parameter_count() {
        // MODEL.md section 4: 5,146,852 parameters at h = 128.
        assert_eq!(ModelSpec::hood(128).parameter_count(), 5_146_852);
        assert_eq!(ModelSpec::hood(128).blocks.len(), 15);
    }

    #[test]
    fn model_spec_beyond_the_memory_budget_is_refused() {
        // 5.1 M parameters at h = 128 (31 MB of f32 and bf16 weights); at h = 1024, 64 times that.
        assert_eq!(ModelSpec::hood(128).weight_bytes(), 6 * 5_146_852);
        assert!(ModelSpec::hood(512).validate().is_ok());
        let e = ModelSpec::hood(1024).validate().unwrap_err();
        assert!(matches!(e, Error::CapacityExceeded { capacity: crate::limits::MAX_MODEL_BYTES, .. }), "{e}");
    }

    #[test]
    fn model_spec_schedule_round_trip() {
        let b = parse_schedule(HOOD_SCHEDULE).unwrap();
        assert_eq!(b[3], BlockSpec { change: Some(LevelChange::Down), keys: vec![EdgeKey::C0, EdgeKey::C1] });
        assert_eq!(b[0].keys, vec![EdgeKey::C0, EdgeKey::Mesh]);
        assert_eq!(b[6].finest(), EdgeKey::C1);
        assert_eq!(b[0].finest(), EdgeKey::Mesh);
        assert_eq!(parse_schedule(&format_schedule(&b)).unwrap(), b);
        let flat = ["f"; 15].join("|");
        let s = ModelSpec::with_schedule(64, 2, 0, &flat).unwrap();
        assert_eq!(s.blocks.len(), 15);
        assert!(parse_schedule("f,x").is_err());
        assert!(parse_schedule("f,,c0").is_err());
        assert!(parse_schedule("f,f").is_err());
        assert!(ModelSpec::with_schedule(64, 2, 1, "f,c1").is_err());
    }
}
