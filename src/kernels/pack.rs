//! Packed weight layouts: what the micro-kernels read, written once (at model-file write time).
//!
//! A PyTorch `Linear(in, out)` stores `W` as `[out, in]` row-major and computes `y = x · Wᵀ + b`.
//! We pack a column range `cols` of `W` (so a split first layer packs its `[h_t | h_s | e]`
//! parts separately; `k = cols.len()`) into **panels of [`PANEL`] = 16 output columns**:
//!
//! * **f32** ([`pack_f32`]): `n_pad = round_up(out, 16)`, length `n_pad · k`. Panel `p` starts at
//!   `p · 16 · k`; inside it, element `(kk, j)` (input `kk`, output `p·16 + j`) is at
//!   `p·16·k + kk·16 + j`. K-major within a panel: one 64-byte line per input.
//! * **bf16** ([`pack_bf16`]): inputs are taken in pairs (`kp = round_up(k, 2)`), length
//!   `n_pad · kp`. Panel `p` starts at `p · 16 · kp`; element `(kk, j)` is at
//!   `p·16·kp + (kk/2)·32 + 2j + kk%2`: per input pair, 16 columns × (even, odd) input. This is
//!   the operand order of `vdpbf16ps`, so one 64-byte load feeds one instruction.
//!
//! Padding (columns `out..n_pad`, the odd input of an odd `k`) is zero. Both layouts are plain
//! slices of `f32` / `half::bf16`, so they can live inside a zero-copy model file.

use core::ops::Range;

use half::bf16;

use crate::{Error, Result};

/// Output columns per packed panel.
pub(crate) const PANEL: usize = 16;

/// `n` rounded up to whole panels.
pub(crate) const fn padded_cols(n: usize) -> usize {
    n.div_ceil(PANEL) * PANEL
}

/// Length in `f32` of a packed f32 matrix with `k` inputs and `n` outputs.
pub const fn packed_len_f32(k: usize, n: usize) -> usize {
    padded_cols(n) * k
}

/// Length in `bf16` of a packed bf16 matrix with `k` inputs and `n` outputs.
pub const fn packed_len_bf16(k: usize, n: usize) -> usize {
    padded_cols(n) * k.next_multiple_of(2)
}

/// `padded_cols(n) · kp`, refused where it overflows `usize` (a length no slice can have).
fn checked_packed_len(k: usize, n: usize, kp: usize) -> Result<usize> {
    n.checked_next_multiple_of(PANEL)
        .and_then(|cols| cols.checked_mul(kp))
        .ok_or(Error::OutOfRange { what: "packed weight size (inputs times outputs overflows)", index: k })
}

fn check_source(w: &[f32], n_out: usize, n_in: usize, cols: &Range<usize>) -> Result<()> {
    if w.len() != n_out * n_in {
        return Err(Error::SizeMismatch { what: "weight matrix [out, in]", expected: n_out * n_in, got: w.len() });
    }
    if cols.start > cols.end || cols.end > n_in {
        return Err(Error::OutOfRange { what: "packed column range", index: cols.end });
    }
    if n_out == 0 {
        return Err(Error::Empty { what: "weight matrix outputs" });
    }
    Ok(())
}

/// Packs columns `cols` of `w` (`[n_out, n_in]` row-major, PyTorch's `Linear.weight`) into the
/// f32 panel layout described in the module docs.
///
/// # Errors
/// [`Error::SizeMismatch`] if `w` is not `n_out · n_in` long or `dst` is not
/// [`packed_len_f32`]`(cols.len(), n_out)` long; [`Error::OutOfRange`] for a bad column range.
pub fn pack_f32(w: &[f32], n_out: usize, n_in: usize, cols: Range<usize>, dst: &mut [f32]) -> Result<()> {
    check_source(w, n_out, n_in, &cols)?;
    let k = cols.len();
    let len = packed_len_f32(k, n_out);
    if dst.len() != len {
        return Err(Error::SizeMismatch { what: "packed f32 weights", expected: len, got: dst.len() });
    }
    for (p, panel) in dst.chunks_exact_mut(PANEL * k.max(1)).enumerate().take(padded_cols(n_out) / PANEL) {
        for kk in 0..k {
            for j in 0..PANEL {
                let o = p * PANEL + j;
                panel[kk * PANEL + j] = if o < n_out { w[o * n_in + cols.start + kk] } else { 0.0 };
            }
        }
    }
    Ok(())
}

/// `x` rounded to the nearest bf16 (ties to even), kept in f32: the value the bf16 weights of
/// [`pack_bf16`] hold for it.
pub fn bf16_value(x: f32) -> f32 {
    bf16::from_f32(x).to_f32()
}

/// Rounds every value as [`bf16_value`] does.
pub fn round_to_bf16(values: &mut [f32]) {
    for v in values {
        *v = bf16_value(*v);
    }
}

/// Packs columns `cols` of `w` (`[n_out, n_in]` row-major) into the bf16 pair-panel layout
/// described in the module docs, rounding each weight to nearest-even bf16.
///
/// # Errors
/// As [`pack_f32`], with [`packed_len_bf16`] for `dst`.
pub fn pack_bf16(w: &[f32], n_out: usize, n_in: usize, cols: Range<usize>, dst: &mut [bf16]) -> Result<()> {
    check_source(w, n_out, n_in, &cols)?;
    let k = cols.len();
    let kp = k.next_multiple_of(2);
    let len = packed_len_bf16(k, n_out);
    if dst.len() != len {
        return Err(Error::SizeMismatch { what: "packed bf16 weights", expected: len, got: dst.len() });
    }
    if kp == 0 {
        return Ok(());
    }
    for (p, panel) in dst.chunks_exact_mut(PANEL * kp).enumerate() {
        for kk in 0..kp {
            for j in 0..PANEL {
                let o = p * PANEL + j;
                let v = if o < n_out && kk < k { w[o * n_in + cols.start + kk] } else { 0.0 };
                panel[(kk / 2) * 2 * PANEL + 2 * j + kk % 2] = bf16::from_f32(v);
            }
        }
    }
    Ok(())
}

/// A packed f32 weight matrix (a view; see the module docs for the layout).
#[derive(Clone, Copy, Debug)]
pub struct PackedF32<'a> {
    data: &'a [f32],
    k: usize,
    n: usize,
}

impl<'a> PackedF32<'a> {
    /// Wraps packed data with `k` inputs and `n` outputs.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] unless `data.len() == packed_len_f32(k, n)`; [`Error::Empty`] if
    /// `n == 0`.
    pub fn new(data: &'a [f32], k: usize, n: usize) -> Result<Self> {
        if n == 0 {
            return Err(Error::Empty { what: "packed weight outputs" });
        }
        let len = checked_packed_len(k, n, k)?;
        if data.len() != len {
            return Err(Error::SizeMismatch { what: "packed f32 weights", expected: len, got: data.len() });
        }
        Ok(Self { data, k, n })
    }
    /// Number of inputs.
    pub fn k(&self) -> usize {
        self.k
    }
    /// Number of outputs.
    pub fn n(&self) -> usize {
        self.n
    }
    /// The packed data.
    pub fn data(&self) -> &'a [f32] {
        self.data
    }
    /// Weight for input `kk`, output `o` (slow; for reference code and tests).
    ///
    /// # Panics
    /// For an index past the packed data; `kk < k()` and `o < n()` are not checked (past them it
    /// reads padding or another weight).
    pub fn get(&self, kk: usize, o: usize) -> f32 {
        self.data[(o / PANEL) * PANEL * self.k + kk * PANEL + o % PANEL]
    }
}

/// A packed bf16 weight matrix (a view; see the module docs for the layout).
#[derive(Clone, Copy, Debug)]
pub struct PackedBf16<'a> {
    data: &'a [bf16],
    k: usize,
    n: usize,
}

impl<'a> PackedBf16<'a> {
    /// Wraps packed data with `k` inputs and `n` outputs.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] unless `data.len() == packed_len_bf16(k, n)`; [`Error::Empty`] if
    /// `n == 0`.
    pub fn new(data: &'a [bf16], k: usize, n: usize) -> Result<Self> {
        if n == 0 {
            return Err(Error::Empty { what: "packed weight outputs" });
        }
        let len = checked_packed_len(k, n, k.next_multiple_of(2))?;
        if data.len() != len {
            return Err(Error::SizeMismatch { what: "packed bf16 weights", expected: len, got: data.len() });
        }
        Ok(Self { data, k, n })
    }
    /// Number of inputs.
    pub fn k(&self) -> usize {
        self.k
    }
    /// Number of inputs rounded up to a pair.
    pub fn k_pairs(&self) -> usize {
        self.k.div_ceil(2)
    }
    /// Number of outputs.
    pub fn n(&self) -> usize {
        self.n
    }
    /// The packed data.
    pub fn data(&self) -> &'a [bf16] {
        self.data
    }
    /// Widens these weights into `dst` in the f32 layout (same `k` and `n`): every weight is
    /// exact in f32, so the f32 kernels then compute with bf16-exact weights. For CPUs without
    /// bf16 products, which would otherwise widen them on every call.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] unless `dst.len() == packed_len_f32(k, n)`.
    pub fn widen_into<'d>(&self, dst: &'d mut [f32]) -> Result<PackedF32<'d>> {
        let len = packed_len_f32(self.k, self.n);
        if dst.len() != len {
            return Err(Error::SizeMismatch { what: "widened bf16 weights", expected: len, got: dst.len() });
        }
        super::frame::widen_bf16(self, dst);
        PackedF32::new(dst, self.k, self.n)
    }
    /// Weight for input `kk`, output `o` (slow; for reference code and tests).
    ///
    /// # Panics
    /// For an index past the packed data; `kk < k()` and `o < n()` are not checked (past them it
    /// reads padding or another weight).
    pub fn get(&self, kk: usize, o: usize) -> f32 {
        let kp = self.k.next_multiple_of(2);
        self.data[(o / PANEL) * PANEL * kp + (kk / 2) * 2 * PANEL + 2 * (o % PANEL) + kk % 2].to_f32()
    }
}

/// A packed weight matrix in either precision.
#[derive(Clone, Copy, Debug)]
pub enum Weights<'a> {
    /// f32 weights, f32 activations.
    F32(PackedF32<'a>),
    /// bf16 weights and bf16 activations, f32 accumulation.
    Bf16(PackedBf16<'a>),
}

impl Weights<'_> {
    /// Number of inputs.
    pub fn k(&self) -> usize {
        match self {
            Weights::F32(w) => w.k(),
            Weights::Bf16(w) => w.k(),
        }
    }
    /// Number of outputs.
    pub fn n(&self) -> usize {
        match self {
            Weights::F32(w) => w.n(),
            Weights::Bf16(w) => w.n(),
        }
    }
    /// Whether these are bf16 weights.
    pub fn is_bf16(&self) -> bool {
        matches!(self, Weights::Bf16(_))
    }
}
