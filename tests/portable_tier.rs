//! Whole steps on the portable kernel tier, selected as a user selects it (the process-wide cap
//! that `HOOD_KERNEL_TIER=portable` also sets), against the scalar reference. The cap is
//! process-wide, so this binary holds this one test only.

mod common;
use common::*;
use hood::kernels::{force_tier, Kernels, Tier};
use hood::sim::{Precision, SimConfig};

/// The tier a sim of the procedural scene ran on, and how far each cloth coordinate moved in
/// three steps (m).
fn rollout(bytes: &hood::model::ModelBytes, precision: Precision, tier: Option<Tier>) -> (Tier, Vec<f32>) {
    let scene = Scene::new(12, 10);
    let model = bytes.model().unwrap();
    let mut sim = scene.sim(&model, SimConfig::network().with_precision(precision).with_tier(tier)).unwrap();
    let start = sim.positions().as_flattened().to_vec();
    for t in 1..=3 {
        sim.step(&scene.body_at(t)).unwrap();
    }
    (sim.tier(), sim.positions().as_flattened().iter().zip(&start).map(|(p, s)| p - s).collect())
}

#[test]
fn portable_tier_steps_like_scalar() {
    force_tier(Some(Tier::Portable));
    assert_eq!(Kernels::best().tier(), Tier::Portable);
    // Under the portable cap the trainer's products leave AVX2 too.
    #[cfg(feature = "train")]
    assert!(!hood::train::gemm::Gemm::best().is_simd());
    let bytes = random_model(32, 4, true);
    // bf16 on these tiers runs its weights widened to f32 once, with f32 activations: as close
    // to the scalar tier as f32 is.
    for (precision, tol) in [(Precision::F32, 1e-5), (Precision::Bf16, 1e-5)] {
        // No tier in the config: the step takes the capped best (for bf16, `Kernels::best_bf16`).
        let (tier, got) = rollout(&bytes, precision, None);
        assert_eq!(tier, Tier::Portable, "{precision:?}");
        let (tier, want) = rollout(&bytes, precision, Some(Tier::Scalar));
        assert_eq!(tier, Tier::Scalar);
        let rel = rel_err(&got, &want);
        println!(
            "{precision:?}: portable against scalar, displacements rel {rel:.2e}, max abs {:.2e} m",
            max_abs(&got, &want)
        );
        assert!(rel < tol, "{precision:?}: relative error {rel:.2e} >= {tol:.0e}");
    }
}
