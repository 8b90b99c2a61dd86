//! Dense kernels of the inference runtime: packed linear layers with fused epilogues, the fused
//! edge MLP (split first layer: gathered node projections + edge product), and aggregation over
//! edges sorted by target.
//!
//! Paths ([`Tier`]): a scalar reference, a portable tiled path in plain Rust (the best tier off
//! x86-64, where the compiler vectorises it for the target), and on x86-64 AVX2+FMA, AVX-512F,
//! AVX-512-BF16 (bf16 weights and activations, f32 accumulation with `vdpbf16ps`) and AMX-BF16
//! (the same on the tile unit). Every path but the scalar one runs the same frame of register
//! tiles, row tails and partial panels, written once over a vector vocabulary. The CPU is probed
//! once ([`detected_tier`]); a [`Kernels`] value carries the chosen path as a capability token,
//! so hot code never probes. [`force_tier`] (or the environment variable
//! `HOOD_KERNEL_TIER=scalar|portable|avx2|avx512|avx512bf16|amx`, read once under `std`) caps the
//! tier, and [`Kernels::with_tier`] picks one explicitly, so one machine can test every path it
//! has.
//!
//! Each precision runs on the faster of two paths on the running CPU, measured once: bf16
//! weights on `vdpbf16ps` (or AMX) or widened onto f32 FMAs, f32 weights on AVX-512 or AVX2
//! ([`bf16_choice`], [`f32_choice`], [`Kernels::best_bf16`], [`Kernels::best_f32`]).
//!
//! bf16 weights on a tier without AVX-512-BF16 (the portable one included) run on f32
//! multiply-adds: the weights are widened once per call into caller scratch and the activations
//! rounded to bf16 first, so every tier computes the same products (exact in f32) and differs
//! only in summation order. A simulation does not take this path: it widens the weights once
//! ([`PackedBf16::widen_into`]) and runs them as f32 weights, with f32 activations.
//!
//! All kernels write into caller buffers and never allocate.

mod choose;
mod frame;

/// The vector vocabulary and the x86 tokens, for the trainer's products.
#[cfg(all(feature = "train", target_arch = "x86_64"))]
pub(crate) use frame::Simd;
/// Row statistics shared with the trainer, so both normalise with the same arithmetic.
#[cfg(feature = "train")]
pub(crate) use frame::{lane_dot, lane_sum, layer_norm_stats};
#[cfg(all(feature = "train", target_arch = "x86_64"))]
pub(crate) use x86::{Avx2Fma, Avx512};
/// The tile unit and bf16 rounding, for the trainer's split-bf16 products on AMX.
#[cfg(all(feature = "train", target_arch = "x86_64"))]
pub(crate) use {
    amx::{Emulator as TileModel, Hardware as TileHardware, TileUnit},
    frame::round_bf16,
    x86::{AmxBf16, Avx512Bf16},
};
#[cfg(target_arch = "x86_64")]
mod amx;
mod pack;
#[cfg(feature = "tools")]
pub mod peak;
mod portable;
mod scalar;
#[cfg(feature = "std")]
mod stopwatch;
#[cfg(test)]
mod tests;
#[cfg(target_arch = "x86_64")]
mod x86;

use core::sync::atomic::{AtomicU8, Ordering};

pub use choose::{bf16_choice, f32_choice, ChoiceReason, TierChoice, SWITCH_MARGIN};

pub use pack::{
    bf16_value, pack_bf16, pack_f32, packed_len_bf16, packed_len_f32, round_to_bf16, PackedBf16, PackedF32, Weights,
};
pub(crate) use pack::{padded_cols, PANEL};

use crate::error::{check_at_least, check_len};
use crate::{Error, Result};

/// LayerNorm epsilon (PyTorch's default).
pub const LN_EPS: f32 = 1e-5;

/// Rows processed per block by [`Kernels::linear`] (sizes its scratch).
pub(crate) const LINEAR_BLOCK_ROWS: usize = 96;

/// Edges processed per block by [`Kernels::edge_mlp`] (sizes its scratch).
pub(crate) const EDGE_BLOCK: usize = 96;

/// Most operands one [`Kernels::linear`] call sums.
pub const MAX_OPERANDS: usize = 6;

/// An instruction-set path, ordered from least to most capable: `Scalar < Portable < Avx2Fma <
/// Avx512 < Avx512Bf16 < Amx`.
///
/// The order is by capability (the declaration order), not by the numeric values, which are kept
/// stable for anything that stores them: [`Tier::Portable`] came later and is 6. Every tier from
/// [`Tier::Avx2Fma`] up is an x86-64 tier with at least AVX2 and FMA, so `tier >= Tier::Avx2Fma`
/// asks whether a path may use them; the portable tier is below that on every architecture.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Tier {
    /// Scalar code, one output at a time: the reference every other path is tested against.
    Scalar = 1,
    /// The register-tile frame in plain Rust on 8-lane arrays, which the compiler vectorises with
    /// the target's baseline features (NEON on aarch64, SSE2 on x86-64); bf16 weights are widened
    /// to f32 as on [`Tier::Avx2Fma`]. Available on every CPU; the best tier off x86-64.
    Portable = 6,
    /// AVX2 + FMA (256-bit).
    Avx2Fma = 2,
    /// AVX-512F (512-bit); bf16 weights are widened to f32 in registers.
    Avx512 = 3,
    /// AVX-512F + AVX-512-BF16: bf16 products with `vdpbf16ps`.
    Avx512Bf16 = 4,
    /// AVX-512-BF16 + AMX-BF16 (Linux): bf16 products on the tile unit; f32 as [`Tier::Avx512Bf16`]
    /// (the trainer's f32 products may run on the tiles too, split: `train::Gemm::tile_choice`).
    Amx = 5,
}

impl Tier {
    /// Every tier, lowest first.
    pub const ALL: [Tier; 6] = [Tier::Scalar, Tier::Portable, Tier::Avx2Fma, Tier::Avx512, Tier::Avx512Bf16, Tier::Amx];

    /// Short lowercase name (`scalar`, `portable`, `avx2`, `avx512`, `avx512bf16`, `amx`).
    pub fn name(self) -> &'static str {
        match self {
            Tier::Scalar => "scalar",
            Tier::Portable => "portable",
            Tier::Avx2Fma => "avx2",
            Tier::Avx512 => "avx512",
            Tier::Avx512Bf16 => "avx512bf16",
            Tier::Amx => "amx",
        }
    }

    /// Parses a [`Tier::name`].
    pub fn from_name(name: &str) -> Option<Tier> {
        Tier::ALL.into_iter().find(|t| t.name().eq_ignore_ascii_case(name.trim()))
    }

    /// Whether bf16 weights multiply natively on this tier (`vdpbf16ps` or AMX tiles); the
    /// others widen them to f32.
    pub fn has_bf16_products(self) -> bool {
        self >= Tier::Avx512Bf16
    }

    /// Position in the capability order (the index in [`Tier::ALL`]).
    const fn rank(self) -> u8 {
        match self {
            Tier::Scalar => 0,
            Tier::Portable => 1,
            Tier::Avx2Fma => 2,
            Tier::Avx512 => 3,
            Tier::Avx512Bf16 => 4,
            Tier::Amx => 5,
        }
    }

    fn from_u8(v: u8) -> Option<Tier> {
        Tier::ALL.into_iter().find(|t| *t as u8 == v)
    }
}

impl PartialOrd for Tier {
    fn partial_cmp(&self, other: &Tier) -> Option<core::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// The capability order (see [`Tier`]), not the numeric values.
impl Ord for Tier {
    fn cmp(&self, other: &Tier) -> core::cmp::Ordering {
        self.rank().cmp(&other.rank())
    }
}

/// Probed tier (0 = not yet probed).
static DETECTED: AtomicU8 = AtomicU8::new(0);
/// Cap set by [`force_tier`] or the environment (0 = probe the environment, 255 = no cap).
static CAP: AtomicU8 = AtomicU8::new(0);

/// The most capable tier this CPU supports (probed once, then cached): an x86-64 tier where the
/// CPU has AVX2 and FMA, else [`Tier::Portable`].
pub fn detected_tier() -> Tier {
    if let Some(t) = Tier::from_u8(DETECTED.load(Ordering::Relaxed)) {
        return t;
    }
    let t = probe();
    DETECTED.store(t as u8, Ordering::Relaxed);
    t
}

fn probe() -> Tier {
    #[cfg(target_arch = "x86_64")]
    {
        if x86::AmxBf16::<amx::Hardware>::new().is_some() {
            return Tier::Amx;
        }
        if x86::Avx512Bf16::new().is_some() {
            return Tier::Avx512Bf16;
        }
        if x86::Avx512::new().is_some() {
            return Tier::Avx512;
        }
        if x86::Avx2Fma::new().is_some() {
            return Tier::Avx2Fma;
        }
    }
    Tier::Portable
}

/// Caps the tier [`Kernels::best`] returns (`None` lifts the cap). Overrides
/// `HOOD_KERNEL_TIER`. Affects only `Kernels` values made afterwards.
pub fn force_tier(cap: Option<Tier>) {
    CAP.store(cap.map_or(255, |t| t as u8), Ordering::Relaxed);
}

/// Serialises the tests that set the process-wide cap and check what it selects.
#[cfg(test)]
pub(crate) static CAP_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The cap in force ([`force_tier`]'s, else `HOOD_KERNEL_TIER`'s), if any.
pub(crate) fn tier_cap() -> Option<Tier> {
    let v = CAP.load(Ordering::Relaxed);
    if v == 0 {
        #[cfg(feature = "std")]
        let from_env = std::env::var("HOOD_KERNEL_TIER").ok().and_then(|s| Tier::from_name(&s));
        #[cfg(not(feature = "std"))]
        let from_env: Option<Tier> = None;
        // A racing force_tier wins over the environment.
        let _ = CAP.compare_exchange(0, from_env.map_or(255, |t| t as u8), Ordering::Relaxed, Ordering::Relaxed);
        return Tier::from_u8(CAP.load(Ordering::Relaxed));
    }
    Tier::from_u8(v)
}

#[derive(Clone, Copy, Debug)]
enum Backend {
    Scalar,
    Portable(portable::Portable),
    #[cfg(target_arch = "x86_64")]
    Avx2(x86::Avx2Fma),
    #[cfg(target_arch = "x86_64")]
    Avx512(x86::Avx512),
    #[cfg(target_arch = "x86_64")]
    Avx512Bf16(x86::Avx512Bf16),
    #[cfg(target_arch = "x86_64")]
    Amx(x86::AmxBf16),
    /// The AMX path with the tiles modelled in software (tests on CPUs without AMX).
    #[cfg(all(test, target_arch = "x86_64"))]
    AmxEmulated(x86::AmxBf16<amx::Emulator>),
}

/// A chosen kernel path. Holding one proves the CPU supports it (its x86 variants are made only
/// by checked constructors; the scalar and portable paths run anywhere); copy it into the hot
/// code once.
#[derive(Clone, Copy, Debug)]
pub struct Kernels {
    backend: Backend,
}

/// One `x · Wᵀ` term of a [`Kernels::linear`] call: `x` is `rows × w.k()` row-major.
#[derive(Clone, Copy, Debug)]
pub struct Operand<'a> {
    /// Activations, `rows × k`.
    pub x: &'a [f32],
    /// Packed weights (`k` inputs, `n` outputs).
    pub w: Weights<'a>,
}

/// Affine LayerNorm parameters over an output row (eps [`LN_EPS`]).
#[derive(Clone, Copy, Debug)]
pub struct LayerNorm<'a> {
    /// Scale, one per output.
    pub gamma: &'a [f32],
    /// Shift, one per output.
    pub beta: &'a [f32],
}

/// What happens to `y = Σ x·Wᵀ + b` before it is written, in this order: ReLU, LayerNorm, then
/// either `out = y` or (residual) `out += y`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Epilogue<'a> {
    /// Apply `max(y, 0)`.
    pub relu: bool,
    /// Normalise each output row.
    pub layer_norm: Option<LayerNorm<'a>>,
    /// Add into `out` instead of overwriting it.
    pub residual: bool,
}

/// Weights of one edge MLP with its first layer split (MODEL.md section 4):
/// `z1 = P_t[target] + P_s[source] + e · W_eᵀ + b1`, `z2 = ReLU(z1) · W2ᵀ + b2`,
/// `m = LayerNorm(ReLU(z2) · W3ᵀ + b3)`. All three matrices must share one precision.
#[derive(Clone, Copy, Debug)]
pub struct EdgeMlp<'a> {
    /// Edge-latent part of the first layer (`k_e` inputs, `h` outputs).
    pub w1_edge: Weights<'a>,
    /// First-layer bias (`h`).
    pub b1: &'a [f32],
    /// Second layer (`h` → `h`).
    pub w2: Weights<'a>,
    /// Second-layer bias (`h`).
    pub b2: &'a [f32],
    /// Third layer (`h` → `k_e`, so the message can be added to the edge latent).
    pub w3: Weights<'a>,
    /// Third-layer bias (`k_e`).
    pub b3: &'a [f32],
    /// Final LayerNorm (`k_e`), if any.
    pub layer_norm: Option<LayerNorm<'a>>,
}

/// Per-edge inputs of [`Kernels::edge_mlp`].
#[derive(Clone, Copy, Debug)]
pub struct EdgeInputs<'a> {
    /// Target-node projections `P_t = H_t · W_tᵀ`, `n_targets × h`.
    pub p_target: &'a [f32],
    /// Source-node projections `P_s = H_s · W_sᵀ`, `n_sources × h`.
    pub p_source: &'a [f32],
    /// Target node of each edge (sorted ascending for a deterministic, streaming aggregate).
    pub target: &'a [u32],
    /// Source node of each edge.
    pub source: &'a [u32],
}

/// Scratch length (in `f32`) [`Kernels::linear`] needs for these operands and `n` outputs
/// (bf16 operands include room to widen their weights on tiers without bf16 dot products).
pub fn linear_scratch_len(ops: &[Operand<'_>], n: usize) -> usize {
    let kp: usize = ops.iter().map(|o| o.w.k().next_multiple_of(2)).sum();
    let wide: usize = ops.iter().filter(|o| o.w.is_bf16()).map(|o| packed_len_f32(o.w.k(), n)).sum();
    LINEAR_BLOCK_ROWS * (kp + padded_cols(n)) + wide
}

/// Scratch length (in `f32`) [`Kernels::edge_mlp`] needs for edge width `k_e` and hidden `h`
/// (three block buffers plus room to widen bf16 weights on tiers without bf16 dot products).
pub fn edge_mlp_scratch_len(k_e: usize, h: usize) -> usize {
    EDGE_BLOCK * (k_e.next_multiple_of(2).max(h.next_multiple_of(2)) + h.max(k_e) + h)
        + packed_len_f32(k_e, h)
        + packed_len_f32(h, h)
        + packed_len_f32(h, k_e)
}

impl Kernels {
    /// The best path for this CPU, capped by [`force_tier`] / `HOOD_KERNEL_TIER`.
    pub fn best() -> Kernels {
        let mut t = detected_tier();
        if let Some(cap) = tier_cap() {
            t = t.min(cap);
        }
        // Every tier at or below the detected one is available.
        Kernels::with_tier(t).unwrap_or(Kernels::scalar())
    }

    /// The scalar reference path (always available).
    pub fn scalar() -> Kernels {
        Kernels { backend: Backend::Scalar }
    }

    /// The given path, or `None` if this CPU (or build) lacks it.
    pub fn with_tier(tier: Tier) -> Option<Kernels> {
        let backend = match tier {
            Tier::Scalar => Backend::Scalar,
            Tier::Portable => Backend::Portable(portable::Portable::new()),
            #[cfg(target_arch = "x86_64")]
            Tier::Avx2Fma => Backend::Avx2(x86::Avx2Fma::new()?),
            #[cfg(target_arch = "x86_64")]
            Tier::Avx512 => Backend::Avx512(x86::Avx512::new()?),
            #[cfg(target_arch = "x86_64")]
            Tier::Avx512Bf16 => Backend::Avx512Bf16(x86::Avx512Bf16::new()?),
            #[cfg(target_arch = "x86_64")]
            Tier::Amx => Backend::Amx(x86::AmxBf16::new()?),
            #[cfg(not(target_arch = "x86_64"))]
            _ => return None,
        };
        Some(Kernels { backend })
    }

    /// The AMX path with its tiles modelled in software (`amx::Emulator`), where the CPU has
    /// AVX-512-BF16: the tile products' tiling, tails and layouts, checked without AMX.
    #[cfg(all(test, target_arch = "x86_64"))]
    pub(crate) fn amx_emulated() -> Option<Kernels> {
        Some(Kernels { backend: Backend::AmxEmulated(x86::AmxBf16::new()?) })
    }

    /// The path this value runs.
    pub fn tier(&self) -> Tier {
        match self.backend {
            Backend::Scalar => Tier::Scalar,
            Backend::Portable(_) => Tier::Portable,
            #[cfg(target_arch = "x86_64")]
            Backend::Avx2(_) => Tier::Avx2Fma,
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512(_) => Tier::Avx512,
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512Bf16(_) => Tier::Avx512Bf16,
            #[cfg(target_arch = "x86_64")]
            Backend::Amx(_) => Tier::Amx,
            #[cfg(all(test, target_arch = "x86_64"))]
            Backend::AmxEmulated(_) => Tier::Amx,
        }
    }

    /// `out (+)= epilogue(Σ_i ops[i].x · ops[i].wᵀ + bias)`, row by row. The operands are the
    /// parts of a concatenated input (never materialised); all must have the same `n` and
    /// precision. `rows = out.len() / n`.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for inconsistent lengths (operands, bias, LayerNorm parameters,
    /// `out`, or `scratch` shorter than [`linear_scratch_len`]); [`Error::IncompatibleModel`] for
    /// mixed precisions or widths; [`Error::CapacityExceeded`] for more than [`MAX_OPERANDS`].
    pub fn linear(
        &self,
        ops: &[Operand<'_>],
        bias: Option<&[f32]>,
        epilogue: &Epilogue<'_>,
        out: &mut [f32],
        scratch: &mut [f32],
    ) -> Result<()> {
        let first = ops.first().ok_or(Error::Empty { what: "linear operands" })?;
        if ops.len() > MAX_OPERANDS {
            return Err(Error::CapacityExceeded { what: "linear operands", capacity: MAX_OPERANDS, needed: ops.len() });
        }
        let n = first.w.n();
        if !out.len().is_multiple_of(n) {
            return Err(Error::SizeMismatch { what: "linear output (multiple of n)", expected: n, got: out.len() });
        }
        let rows = out.len() / n;
        for op in ops {
            if op.w.n() != n || op.w.is_bf16() != first.w.is_bf16() {
                return Err(Error::IncompatibleModel { reason: "linear operands differ in width or precision" });
            }
            let len = rows.checked_mul(op.w.k()).ok_or(Error::OutOfRange { what: "linear input size", index: rows })?;
            check_len("linear input", op.x.len(), len)?;
        }
        if let Some(b) = bias {
            check_len("linear bias", b.len(), n)?;
        }
        if let Some(ln) = &epilogue.layer_norm {
            check_len("layer norm gamma", ln.gamma.len(), n)?;
            check_len("layer norm beta", ln.beta.len(), n)?;
        }
        check_at_least("linear scratch", scratch.len(), linear_scratch_len(ops, n))?;
        match self.backend {
            Backend::Scalar => scalar::linear(ops, bias, epilogue, out, scratch),
            Backend::Portable(t) => t.linear(ops, bias, epilogue, out, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Avx2(t) => t.linear(ops, bias, epilogue, out, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512(t) => t.linear(ops, bias, epilogue, out, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512Bf16(t) => t.linear(ops, bias, epilogue, out, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Amx(t) => t.linear(ops, bias, epilogue, out, scratch),
            #[cfg(all(test, target_arch = "x86_64"))]
            Backend::AmxEmulated(t) => t.linear(ops, bias, epilogue, out, scratch),
        }
        Ok(())
    }

    /// The fused edge MLP over all edges: for each edge `e` (target `r`, source `s`), computes
    /// the message `m_e` of [`EdgeMlp`], then `latent[e] += m_e` and `aggregate[r] += m_e` (the
    /// caller zeroes `aggregate` when it starts a new sum). Edges are processed in order, in
    /// fixed blocks, so the aggregate sum order is the edge order: deterministic.
    ///
    /// Shapes: `latent` is `edges × k_e`, `aggregate` is `n_targets × k_e`, projections are
    /// `n × h`.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] for inconsistent shapes or short scratch
    /// ([`edge_mlp_scratch_len`]); [`Error::IndexOutOfRange`] for a node index past its
    /// projections; [`Error::IncompatibleModel`] for mixed precisions or widths.
    pub fn edge_mlp(
        &self,
        mlp: &EdgeMlp<'_>,
        edges: &EdgeInputs<'_>,
        latent: &mut [f32],
        aggregate: &mut [f32],
        scratch: &mut [f32],
    ) -> Result<()> {
        let k_e = mlp.w1_edge.k();
        let h = mlp.w1_edge.n();
        let bf = mlp.w1_edge.is_bf16();
        if h == 0 {
            return Err(Error::IncompatibleModel { reason: "edge MLP of width 0" });
        }
        if mlp.w2.k() != h || mlp.w2.n() != h || mlp.w3.k() != h || mlp.w3.n() != k_e {
            return Err(Error::IncompatibleModel { reason: "edge MLP layer widths do not chain" });
        }
        if mlp.w2.is_bf16() != bf || mlp.w3.is_bf16() != bf {
            return Err(Error::IncompatibleModel { reason: "edge MLP layers differ in precision" });
        }
        check_len("edge MLP bias 1", mlp.b1.len(), h)?;
        check_len("edge MLP bias 2", mlp.b2.len(), h)?;
        check_len("edge MLP bias 3", mlp.b3.len(), k_e)?;
        if let Some(ln) = &mlp.layer_norm {
            check_len("edge MLP layer norm gamma", ln.gamma.len(), k_e)?;
            check_len("edge MLP layer norm beta", ln.beta.len(), k_e)?;
        }
        let n_edges = edges.target.len();
        check_len("edge sources", edges.source.len(), n_edges)?;
        let size = |rows: usize, what| rows.checked_mul(k_e).ok_or(Error::OutOfRange { what, index: rows });
        check_len("edge latents", latent.len(), size(n_edges, "edge latent size")?)?;
        for (what, len) in [
            ("target-node projections (a multiple of h)", edges.p_target.len()),
            ("source-node projections (a multiple of h)", edges.p_source.len()),
        ] {
            check_len(what, len, len.next_multiple_of(h))?;
        }
        let n_t = edges.p_target.len() / h;
        let n_s = edges.p_source.len() / h;
        check_len("edge aggregate", aggregate.len(), size(n_t, "edge aggregate size")?)?;
        for (what, idx, len) in [("edge target", edges.target, n_t), ("edge source", edges.source, n_s)] {
            if let Some((at, &i)) = idx.iter().enumerate().find(|(_, &i)| i as usize >= len) {
                return Err(Error::IndexOutOfRange { what, at, index: i as usize, len });
            }
        }
        check_at_least("edge MLP scratch", scratch.len(), edge_mlp_scratch_len(k_e, h))?;
        match self.backend {
            Backend::Scalar => scalar::edge_mlp(mlp, edges, latent, aggregate, scratch),
            Backend::Portable(t) => t.edge_mlp(mlp, edges, latent, aggregate, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Avx2(t) => t.edge_mlp(mlp, edges, latent, aggregate, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512(t) => t.edge_mlp(mlp, edges, latent, aggregate, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512Bf16(t) => t.edge_mlp(mlp, edges, latent, aggregate, scratch),
            #[cfg(target_arch = "x86_64")]
            Backend::Amx(t) => t.edge_mlp(mlp, edges, latent, aggregate, scratch),
            #[cfg(all(test, target_arch = "x86_64"))]
            Backend::AmxEmulated(t) => t.edge_mlp(mlp, edges, latent, aggregate, scratch),
        }
        Ok(())
    }
}

/// Sums per-edge messages into their target nodes: `out[r] (+)= Σ messages[e]` for `e` in
/// `offsets[r]..offsets[r+1]` (edges sorted by target, CSR offsets, `offsets.len() = nodes + 1`).
/// A streaming sum in edge order: deterministic, no atomics. With `accumulate == false` rows
/// without edges become zero.
///
/// # Errors
/// [`Error::SizeMismatch`] for inconsistent lengths; [`Error::OutOfRange`] for offsets that
/// decrease or pass the last message.
pub fn aggregate(messages: &[f32], width: usize, offsets: &[u32], out: &mut [f32], accumulate: bool) -> Result<()> {
    let nodes = offsets.len().checked_sub(1).ok_or(Error::Empty { what: "aggregate offsets" })?;
    check_len("aggregate output", out.len(), nodes * width)?;
    if width == 0 {
        return Ok(());
    }
    check_len("aggregate messages (a multiple of width)", messages.len(), messages.len().next_multiple_of(width))?;
    let edges = messages.len() / width;
    for (r, w) in offsets.windows(2).enumerate() {
        if w[0] > w[1] || w[1] as usize > edges {
            return Err(Error::OutOfRange { what: "aggregate offsets", index: r });
        }
    }
    for (r, row) in out.chunks_exact_mut(width).enumerate() {
        if !accumulate {
            row.fill(0.0);
        }
        let (a, b) = (offsets[r] as usize, offsets[r + 1] as usize);
        for m in messages[a * width..b * width].chunks_exact(width) {
            for (o, v) in row.iter_mut().zip(m) {
                *o += v;
            }
        }
    }
    Ok(())
}
