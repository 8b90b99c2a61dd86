//! Runtime behaviour on procedural scenes: determinism across thread counts, refusal of bad
//! input with the state unchanged, effects that are off, effects the model lacks.

mod common;
use common::*;
use hood::sim::{BodyDesc, Precision, Sim, SimConfig};
use hood::Error;

fn rollout(threads: usize, precision: Precision, steps: usize) -> Vec<[f32; 3]> {
    let scene = Scene::new(16, 14);
    let bytes = random_model(32, 2, true);
    let model = bytes.model().unwrap();
    let b0 = scene.body_at(0);
    let cfg = SimConfig { threads, precision, ..SimConfig::default() };
    let mut sim = Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b0 }), cfg).unwrap();
    for t in 1..=steps {
        sim.step(&scene.body_at(t)).unwrap();
    }
    sim.positions().to_vec()
}

#[test]
fn runtime_threads_give_bitwise_identical_results() {
    for precision in [Precision::F32, Precision::Bf16] {
        let one = rollout(1, precision, 3);
        for threads in [2, 3] {
            assert_eq!(one, rollout(threads, precision, 3), "{threads} threads, {precision:?}");
        }
    }
}

#[test]
fn runtime_refuses_non_finite_body_and_keeps_state() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 3, false);
    let model = bytes.model().unwrap();
    let b0 = scene.body_at(0);
    let mut sim =
        Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b0 }), SimConfig::default())
            .unwrap();
    sim.step(&scene.body_at(1)).unwrap();
    let before = sim.state().clone();
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut b = scene.body_at(2);
        b[17][1] = bad;
        assert_eq!(sim.step(&b).unwrap_err(), Error::NonFinite { what: "body vertex", index: 17 });
        assert_eq!(sim.state(), &before);
    }
    let short = &scene.body_at(2)[1..];
    assert!(matches!(sim.step(short).unwrap_err(), Error::SizeMismatch { .. }));
    assert_eq!(sim.state(), &before);
    // And it still steps afterwards.
    sim.step(&scene.body_at(2)).unwrap();
    assert_ne!(sim.state(), &before);
}

#[test]
fn runtime_pinned_vertices_follow_their_targets() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 4, false);
    let model = bytes.model().unwrap();
    let mut sim = Sim::new(&model, &scene.garment, None, SimConfig::default()).unwrap();
    let mut targets = scene.garment.rest().to_vec();
    targets[0][1] += 0.05;
    sim.set_pin_targets(&targets).unwrap();
    sim.step(&[]).unwrap();
    assert_eq!(sim.positions()[0], targets[0]);
    assert_eq!(sim.positions()[7], targets[7]);
    assert_eq!(sim.state().velocity[0], [0.0; 3]);
    let mut bad = targets.clone();
    bad[7][0] = f32::NAN;
    assert!(matches!(sim.set_pin_targets(&bad).unwrap_err(), Error::NonFinite { what: "pin target", index: 7 }));
}

#[test]
fn runtime_refuses_effects_the_model_lacks() {
    let scene = Scene::new(6, 6);
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let cfg = SimConfig { precision: Precision::Bf16, ..SimConfig::default() };
    assert!(matches!(Sim::new(&model, &scene.garment, None, cfg).err(), Some(Error::UnsupportedEffect { .. })));
}
