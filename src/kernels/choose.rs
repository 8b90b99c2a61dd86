//! Which tier runs bf16 weights, chosen by measurement.
//!
//! On a CPU with AVX-512-BF16, bf16 weights run either natively, with `vdpbf16ps`
//! ([`Tier::Avx512Bf16`]) or on the AMX tiles where the CPU has them ([`Tier::Amx`]), or widened
//! to f32 once and run on the f32 FMAs ([`Tier::Avx512`]; a simulation keeps the widened copy,
//! and its activations stay f32). Which is faster depends on the core: where `vdpbf16ps` issues
//! at half the FMA rate (Intel server cores with two FMA units) the widened path wins, where it
//! issues at the FMA rate (AMD Zen 4) the native one does. So the first call times the edge MLP
//! both ways (about 20 ms, on thread CPU time) and keeps the answer for the process. The widened
//! path must be faster by [`WIDEN_MARGIN`], so that timing noise cannot flip the choice from run
//! to run on a core where the two are close. A tier cap (`HOOD_KERNEL_TIER`,
//! [`force_tier`](super::force_tier)) skips the measurement: the capped tier runs, natively where
//! it can.

use super::{detected_tier, tier_cap, Kernels, Tier};

/// How much faster (time ratio) the widened path must be for bf16 to leave `vdpbf16ps`.
pub const WIDEN_MARGIN: f64 = 1.2;

/// Why bf16 weights run on the tier they do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bf16Reason {
    /// A tier cap is in force (`HOOD_KERNEL_TIER` or [`force_tier`](super::force_tier)).
    Capped,
    /// The CPU has no AVX-512-BF16: bf16 runs on the f32 FMAs of the best tier.
    NoNativeBf16,
    /// Measured: best-of-runs microseconds of the same edge MLP on each path.
    Measured {
        /// With `vdpbf16ps`.
        native_us: f64,
        /// Widened onto f32 FMAs.
        widened_us: f64,
    },
    /// Not measured (a build without `std` has no clock): the most capable tier.
    Unmeasured,
}

/// The tier bf16 weights run on, and why.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bf16Choice {
    /// The tier.
    pub tier: Tier,
    /// Why.
    pub reason: Bf16Reason,
}

impl Bf16Choice {
    /// Whether bf16 products use a native bf16 instruction on this tier.
    pub fn native(&self) -> bool {
        self.tier.has_bf16_products()
    }

    /// One line for people: the tier and why.
    #[cfg(feature = "std")]
    pub fn describe(&self) -> std::string::String {
        let how = match self.tier {
            Tier::Amx => "AMX tiles",
            Tier::Avx512Bf16 => "vdpbf16ps",
            Tier::Avx2Fma | Tier::Avx512 => "widened once onto f32 FMAs",
            Tier::Scalar | Tier::Portable => "widened once to f32",
        };
        let why = match self.reason {
            Bf16Reason::Capped => std::string::String::from("the tier cap (HOOD_KERNEL_TIER)"),
            Bf16Reason::NoNativeBf16 => std::string::String::from("no AVX-512-BF16 on this CPU"),
            Bf16Reason::Measured { native_us, widened_us } => std::format!(
                "measured on the edge MLP: {} {native_us:.0} us, widened {widened_us:.0} us \
                 (widened must win by {WIDEN_MARGIN}x)",
                if detected_tier() == Tier::Amx { "AMX" } else { "vdpbf16ps" }
            ),
            Bf16Reason::Unmeasured => std::string::String::from("not measured (no clock)"),
        };
        std::format!("bf16 runs on {} ({how}): {why}", self.tier.name())
    }
}

/// The tier for bf16 weights (measured once per process, see the module docs).
pub fn bf16_choice() -> Bf16Choice {
    if let Some(cap) = tier_cap() {
        return Bf16Choice { tier: detected_tier().min(cap), reason: Bf16Reason::Capped };
    }
    if detected_tier() < Tier::Avx512Bf16 {
        return Bf16Choice { tier: detected_tier(), reason: Bf16Reason::NoNativeBf16 };
    }
    measured()
}

#[cfg(not(feature = "std"))]
fn measured() -> Bf16Choice {
    Bf16Choice { tier: detected_tier(), reason: Bf16Reason::Unmeasured }
}

#[cfg(feature = "std")]
fn measured() -> Bf16Choice {
    static CHOICE: std::sync::OnceLock<Bf16Choice> = std::sync::OnceLock::new();
    *CHOICE.get_or_init(|| {
        let time = |tier, widen| Kernels::with_tier(tier).and_then(|k| bench::edge_mlp_bf16_us(k, widen).ok());
        let native = detected_tier();
        match (time(native, false), time(Tier::Avx512, true)) {
            (Some(native_us), Some(widened_us)) => {
                let tier = if widened_us * WIDEN_MARGIN < native_us { Tier::Avx512 } else { native };
                Bf16Choice { tier, reason: Bf16Reason::Measured { native_us, widened_us } }
            }
            _ => Bf16Choice { tier: detected_tier(), reason: Bf16Reason::Unmeasured },
        }
    })
}

impl Kernels {
    /// The path for bf16 weights on this CPU ([`bf16_choice`]).
    pub fn best_bf16() -> Kernels {
        Kernels::with_tier(bf16_choice().tier).unwrap_or(Kernels::scalar())
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
    /// `widen`) on `k`, microseconds.
    pub(super) fn edge_mlp_bf16_us(k: Kernels, widen: bool) -> Result<f64> {
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
        use super::super::{bf16_choice, Bf16Reason, WIDEN_MARGIN};
        use super::*;

        #[test]
        #[cfg_attr(miri, ignore = "times both paths, which an interpreter cannot do in useful time")]
        fn kernels_bf16_choice_is_measured_where_both_paths_exist() {
            let c = bf16_choice();
            std::println!("{}", c.describe());
            assert!(c.tier <= detected_tier());
            assert_eq!(bf16_choice(), c, "measured once per process");
            match c.reason {
                Bf16Reason::Measured { native_us, widened_us } => {
                    assert!(detected_tier() >= Tier::Avx512Bf16);
                    assert!(native_us > 0.0 && widened_us > 0.0);
                    let widened = widened_us * WIDEN_MARGIN < native_us;
                    assert_eq!(c.tier, if widened { Tier::Avx512 } else { detected_tier() });
                }
                Bf16Reason::NoNativeBf16 => assert!(c.tier < Tier::Avx512Bf16 && !c.native()),
                Bf16Reason::Capped | Bf16Reason::Unmeasured => {}
            }
            // The timing runs on every tier this CPU has (the scalar one too).
            for t in Tier::ALL.into_iter().filter(|t| *t <= detected_tier()) {
                for widen in [false, true] {
                    let us = edge_mlp_bf16_us(Kernels::with_tier(t).unwrap(), widen).unwrap();
                    assert!(us.is_finite() && us > 0.0, "{} widened {widen}: {us}", t.name());
                }
            }
        }
    }
}
