//! Which tier runs each precision, chosen by measurement.
//!
//! **bf16.** On a CPU with AVX-512-BF16, bf16 weights run either natively, with `vdpbf16ps`
//! ([`Tier::Avx512Bf16`]) or on the AMX tiles where the CPU has them ([`Tier::Amx`]), or widened
//! to f32 once and run on the f32 FMAs ([`Tier::Avx512`]; a simulation keeps the widened copy,
//! and its activations stay f32). Which is faster depends on the core: where `vdpbf16ps` issues
//! at half the FMA rate (Intel server cores with two FMA units) the widened path wins, where it
//! issues at the FMA rate (AMD Zen 4) the native one does.
//!
//! **f32.** On a CPU with AVX-512, f32 runs on 512-bit vectors or on AVX2's 256-bit ones. The
//! wider path usually wins, but not on cores with a single 512-bit FMA unit, nor where 512-bit
//! code lowers the clock.
//!
//! So the first call for a precision times the edge MLP on both paths (about 10 ms, on thread
//! CPU time) and keeps the answer for the process. The less capable path must be faster by
//! [`SWITCH_MARGIN`], so that timing noise cannot flip the choice from run to run on a core
//! where the two are close. A tier cap (`HOOD_KERNEL_TIER`, [`force_tier`](super::force_tier))
//! skips the measurement: the capped tier runs, natively where it can.

use super::{detected_tier, tier_cap, Kernels, Tier};

/// How much faster (time ratio) the less capable path must be to be chosen.
pub const SWITCH_MARGIN: f64 = 1.2;

/// Why a precision runs on the tier it does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ChoiceReason {
    /// A tier cap is in force (`HOOD_KERNEL_TIER` or [`force_tier`](super::force_tier)).
    Capped,
    /// Nothing to choose: the CPU lacks the most capable path (bf16: AVX-512-BF16; f32:
    /// AVX-512), so the precision runs on its best tier.
    NoAlternative,
    /// Measured: best-of-runs microseconds of the same edge MLP on each path.
    Measured {
        /// On the CPU's most capable tier (bf16: `vdpbf16ps` or AMX; f32: AVX-512).
        best_us: f64,
        /// On the alternative (bf16: widened onto AVX-512's f32 FMAs; f32: AVX2).
        alternative_us: f64,
    },
    /// Not measured (a build without `std` has no clock): the most capable tier.
    Unmeasured,
}

/// The tier a precision runs on, and why.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TierChoice {
    /// The tier.
    pub tier: Tier,
    /// Why.
    pub reason: ChoiceReason,
    /// Whether this is the choice for bf16 weights (else for f32).
    pub bf16: bool,
}

impl TierChoice {
    /// Whether bf16 products use a native bf16 instruction on this tier.
    pub fn native(&self) -> bool {
        self.bf16 && self.tier.has_bf16_products()
    }

    /// One line for people: the tier and why.
    #[cfg(feature = "std")]
    pub fn describe(&self) -> std::string::String {
        let (precision, how) = match (self.bf16, self.tier) {
            (false, _) => ("f32", ""),
            (true, Tier::Amx) => ("bf16", " (AMX tiles)"),
            (true, Tier::Avx512Bf16) => ("bf16", " (vdpbf16ps)"),
            (true, Tier::Avx2Fma | Tier::Avx512) => ("bf16", " (widened once onto f32 FMAs)"),
            (true, Tier::Scalar | Tier::Portable) => ("bf16", " (widened once to f32)"),
        };
        let why = match self.reason {
            ChoiceReason::Capped => std::string::String::from("the tier cap (HOOD_KERNEL_TIER)"),
            ChoiceReason::NoAlternative if self.bf16 => std::string::String::from("no AVX-512-BF16 on this CPU"),
            ChoiceReason::NoAlternative => std::string::String::from("no AVX-512 on this CPU"),
            ChoiceReason::Measured { best_us, alternative_us } => {
                let (best, alternative) = match (self.bf16, detected_tier()) {
                    (true, Tier::Amx) => ("AMX", "widened"),
                    (true, _) => ("vdpbf16ps", "widened"),
                    (false, _) => ("avx512", "avx2"),
                };
                std::format!(
                    "measured on the edge MLP: {best} {best_us:.0} us, {alternative} {alternative_us:.0} us \
                     ({alternative} must win by {SWITCH_MARGIN}x)"
                )
            }
            ChoiceReason::Unmeasured => std::string::String::from("not measured (no clock)"),
        };
        std::format!("{precision} runs on {}{how}: {why}", self.tier.name())
    }
}

/// The tier for bf16 weights (measured once per process, see the module docs).
pub fn bf16_choice() -> TierChoice {
    choice(true, Tier::Avx512Bf16, Tier::Avx512)
}

/// The tier for f32 weights (measured once per process, see the module docs).
pub fn f32_choice() -> TierChoice {
    choice(false, Tier::Avx512, Tier::Avx2Fma)
}

/// The choice for one precision: the detected tier, or `alternative` where the detected tier is
/// at least `needs` and the alternative is measured faster by [`SWITCH_MARGIN`].
fn choice(bf16: bool, needs: Tier, alternative: Tier) -> TierChoice {
    if let Some(cap) = tier_cap() {
        return TierChoice { tier: detected_tier().min(cap), reason: ChoiceReason::Capped, bf16 };
    }
    if detected_tier() < needs {
        return TierChoice { tier: detected_tier(), reason: ChoiceReason::NoAlternative, bf16 };
    }
    measured(bf16, alternative)
}

#[cfg(not(feature = "std"))]
fn measured(bf16: bool, _alternative: Tier) -> TierChoice {
    TierChoice { tier: detected_tier(), reason: ChoiceReason::Unmeasured, bf16 }
}

#[cfg(feature = "std")]
fn measured(bf16: bool, alternative: Tier) -> TierChoice {
    static CHOICES: [std::sync::OnceLock<TierChoice>; 2] = [std::sync::OnceLock::new(), std::sync::OnceLock::new()];
    *CHOICES[usize::from(bf16)].get_or_init(|| {
        // bf16 natively on the best tier against widened (as f32) on the alternative; f32 as f32
        // on both.
        let time = |tier, widen| Kernels::with_tier(tier).and_then(|k| bench::edge_mlp_us(k, widen).ok());
        let best = detected_tier();
        match (time(best, !bf16), time(alternative, true)) {
            (Some(best_us), Some(alternative_us)) => {
                let tier = if alternative_us * SWITCH_MARGIN < best_us { alternative } else { best };
                TierChoice { tier, reason: ChoiceReason::Measured { best_us, alternative_us }, bf16 }
            }
            _ => TierChoice { tier: best, reason: ChoiceReason::Unmeasured, bf16 },
        }
    })
}

impl Kernels {
    /// The path for bf16 weights on this CPU ([`bf16_choice`]).
    pub fn best_bf16() -> Kernels {
        Kernels::with_tier(bf16_choice().tier).unwrap_or(Kernels::scalar())
    }

    /// The path for f32 weights on this CPU ([`f32_choice`]).
    pub fn best_f32() -> Kernels {
        Kernels::with_tier(f32_choice().tier).unwrap_or(Kernels::scalar())
    }
}

#[cfg(feature = "std")]
mod bench {
    use super::super::stopwatch::Stopwatch;
    use super::super::{
        edge_mlp_scratch_len, pack_bf16, packed_len_bf16, packed_len_f32, EdgeInputs, EdgeMlp, Kernels, LayerNorm,
        PackedBf16, Weights,
    };
    use crate::error::Result;
    use crate::rng::Rng;
    use half::bf16;
    use std::vec;
    use std::vec::Vec;

    /// Latent width of the calibration (the shipped medium model's).
    const H: usize = 64;
    /// Edges and nodes of the calibration: about 0.6 ms per run at 60 GFLOP/s.
    const EDGES: usize = 1536;
    const NODES: usize = 512;
    /// Timed runs after one warm-up; the fastest counts.
    const RUNS: usize = 7;

    fn weights(w: &[bf16]) -> Result<Weights<'_>> {
        PackedBf16::new(w, H, H).map(Weights::Bf16)
    }

    /// `w` widened to f32 once (as a simulation keeps it), or as it is.
    fn run_as<'a>(w: Weights<'a>, widened: &'a mut Vec<f32>, widen: bool) -> Result<Weights<'a>> {
        match w {
            Weights::Bf16(b) if widen => {
                *widened = vec![0.0; packed_len_f32(b.k(), b.n())];
                b.widen_into(widened).map(Weights::F32)
            }
            w => Ok(w),
        }
    }

    fn packed(rng: &mut Rng, k: usize, n: usize) -> Result<Vec<bf16>> {
        let w: Vec<f32> = (0..k * n).map(|_| rng.uniform(-1.0, 1.0) as f32 / (k as f32).sqrt()).collect();
        let mut b = vec![bf16::ZERO; packed_len_bf16(k, n)];
        pack_bf16(&w, n, k, 0..k, &mut b)?;
        Ok(b)
    }

    /// Fastest of [`RUNS`] edge-MLP runs (h = 64, bf16 weights, widened to f32 first when
    /// `widen`: the f32 path's work) on `k`, microseconds.
    pub(super) fn edge_mlp_us(k: Kernels, widen: bool) -> Result<f64> {
        let mut rng = Rng::new(7);
        let mut vec_of = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect() };
        let (b1, b2, b3, gamma, beta) = (vec_of(H), vec_of(H), vec_of(H), vec_of(H), vec_of(H));
        let (pt, ps) = (vec_of(NODES * H), vec_of(NODES * H));
        let latent0 = vec_of(EDGES * H);
        let mut rng = Rng::new(8);
        let (w1, w2, w3) = (packed(&mut rng, H, H)?, packed(&mut rng, H, H)?, packed(&mut rng, H, H)?);
        let (mut v1, mut v2, mut v3) = (Vec::new(), Vec::new(), Vec::new());
        let mlp = EdgeMlp {
            w1_edge: run_as(weights(&w1)?, &mut v1, widen)?,
            b1: &b1,
            w2: run_as(weights(&w2)?, &mut v2, widen)?,
            b2: &b2,
            w3: run_as(weights(&w3)?, &mut v3, widen)?,
            b3: &b3,
            layer_norm: Some(LayerNorm { gamma: &gamma, beta: &beta }),
        };
        let target: Vec<u32> = (0..EDGES).map(|e| (e * NODES / EDGES) as u32).collect();
        let source: Vec<u32> = (0..EDGES).map(|e| ((e * 7919) % NODES) as u32).collect();
        let inputs = EdgeInputs { p_target: &pt, p_source: &ps, target: &target, source: &source };
        let mut latent = latent0.clone();
        let mut aggregate = vec![0.0f32; NODES * H];
        let mut scratch = vec![0.0f32; edge_mlp_scratch_len(H, H)];
        let mut best = f64::INFINITY;
        for run in 0..=RUNS {
            latent.copy_from_slice(&latent0);
            let t = Stopwatch::start();
            k.edge_mlp(&mlp, &inputs, &mut latent, &mut aggregate, &mut scratch)?;
            let s = t.seconds();
            if run > 0 {
                best = best.min(s);
            }
        }
        Ok(best * 1e6)
    }

    #[cfg(test)]
    mod tests {
        use super::super::super::{detected_tier, Tier};
        use super::super::{bf16_choice, f32_choice, ChoiceReason, TierChoice, SWITCH_MARGIN};
        use super::*;

        /// A measured choice keeps the most capable tier unless the alternative won by the margin.
        fn check(c: TierChoice, needs: Tier, alternative: Tier) {
            std::println!("{}", c.describe());
            assert!(c.tier <= detected_tier());
            match c.reason {
                ChoiceReason::Measured { best_us, alternative_us } => {
                    assert!(detected_tier() >= needs);
                    assert!(best_us > 0.0 && alternative_us > 0.0);
                    let switched = alternative_us * SWITCH_MARGIN < best_us;
                    assert_eq!(c.tier, if switched { alternative } else { detected_tier() });
                }
                ChoiceReason::NoAlternative => assert!(c.tier < needs && !c.native()),
                ChoiceReason::Capped | ChoiceReason::Unmeasured => {}
            }
        }

        #[test]
        #[cfg_attr(miri, ignore = "times both paths, which an interpreter cannot do in useful time")]
        fn kernels_tier_choice_is_measured_where_both_paths_exist() {
            let (b, f) = (bf16_choice(), f32_choice());
            assert!(b.bf16 && !f.bf16);
            check(b, Tier::Avx512Bf16, Tier::Avx512);
            check(f, Tier::Avx512, Tier::Avx2Fma);
            assert_eq!((bf16_choice(), f32_choice()), (b, f), "measured once per process");
            assert_eq!((Kernels::best_bf16().tier(), Kernels::best_f32().tier()), (b.tier, f.tier));
            // The timing runs on every tier this CPU has (the scalar one too).
            for t in Tier::ALL.into_iter().filter(|t| *t <= detected_tier()) {
                for widen in [false, true] {
                    let us = edge_mlp_us(Kernels::with_tier(t).unwrap(), widen).unwrap();
                    assert!(us.is_finite() && us > 0.0, "{} widened {widen}: {us}", t.name());
                }
            }
        }
    }
}
