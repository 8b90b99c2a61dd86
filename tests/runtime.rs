//! Runtime behaviour on procedural scenes: determinism across thread counts, refusal of bad
//! input with the state unchanged, effects that are off, effects the model lacks.

mod common;
use common::*;
use hood::body::BodyMesh;
use hood::sim::{BodyDesc, Precision, Sim, SimConfig};
use hood::Error;

fn rollout(threads: usize, precision: Precision, steps: usize) -> Vec<[f32; 3]> {
    rollout_with(16, SimConfig::network().with_threads(threads).with_precision(precision), steps)
}

/// The cloth of an `n x n` grid after `steps` steps with `cfg`.
fn rollout_with(n: usize, cfg: SimConfig, steps: usize) -> Vec<[f32; 3]> {
    let scene = Scene::new(n, n);
    let bytes = random_model(32, 2, true);
    let model = bytes.model().unwrap();
    let mut sim = scene.sim(&model, cfg).unwrap();
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
    // The solver step mode and refinement, on a cloth of several task blocks (256 vertices each).
    for (step, refine) in
        [(hood::sim::StepMode::Solver { iterations: 8 }, None), (hood::sim::StepMode::Network, Some(4))]
    {
        let cfg = |threads| SimConfig::network().with_threads(threads).with_step(step).with_refine(refine);
        let one = rollout_with(30, cfg(1), 3);
        for threads in [2, 3] {
            assert_eq!(one, rollout_with(30, cfg(threads), 3), "{threads} threads, {step:?}, refine {refine:?}");
        }
    }
}

/// On a kernel path without bf16 products, bf16 runs its weights widened to f32 once: the
/// same bits as an f32 run of a model whose f32 weights past the encoders are the bf16 ones
/// (the encoders run in f32 at every precision). Where the path has bf16 products nothing is
/// widened.
#[test]
fn runtime_bf16_without_bf16_products_is_f32_on_the_bf16_weights() {
    use hood::kernels::{Kernels, Tier};
    use hood::model::{write_model, ModelBytes, ModelSpec, Params};
    let spec = ModelSpec::hood(32);
    let mut p = Params::init(&spec, 9).unwrap();
    p.normalisers = hood::model::Normalisers::unit_scale(9);
    let bytes = ModelBytes::new(&write_model(&p, true, &[]).unwrap());
    let encoders = (p.mlps.node_encoder.clone(), p.mlps.edge_encoders.clone(), p.mlps.body_encoder.clone());
    for m in p.mlps.iter_mut() {
        for l in &mut m.layers {
            l.weight.iter_mut().for_each(|w| *w = half::bf16::from_f32(*w).to_f32());
        }
    }
    (p.mlps.node_encoder, p.mlps.edge_encoders, p.mlps.body_encoder) = encoders;
    let rounded = ModelBytes::new(&write_model(&p, false, &[]).unwrap());
    let scene = Scene::new(12, 12);
    let run = |bytes: &ModelBytes, precision: Precision, tier: Tier| {
        let model = bytes.model().unwrap();
        let cfg = SimConfig::network().with_precision(precision).with_tier(Some(tier)).with_threads(2);
        let mut sim = scene.sim(&model, cfg).unwrap();
        for t in 1..=3 {
            sim.step(&scene.body_at(t)).unwrap();
        }
        (sim.positions().to_vec(), sim.widened_weight_bytes(), sim.tier())
    };
    let best = Kernels::best().tier();
    for tier in Tier::ALL.into_iter().filter(|t| *t <= best) {
        let (bf16, widened, ran) = run(&bytes, Precision::Bf16, tier);
        assert_eq!(ran, tier);
        if tier.has_bf16_products() {
            assert_eq!(widened, 0, "{}: native bf16 widens nothing", tier.name());
            continue;
        }
        assert!(widened > 0, "{}", tier.name());
        let (f32_on_bf16_weights, none, _) = run(&rounded, Precision::F32, tier);
        assert_eq!(none, 0, "f32 widens nothing");
        assert_eq!(bf16, f32_on_bf16_weights, "{}", tier.name());
        println!("{}: bf16 = f32 on the bf16 weights, {widened} bytes widened", tier.name());
    }
}

/// The encoders run in f32 at every precision: a bf16 step encodes the same latents as an f32
/// step, bit for bit, on every tier, and only the blocks and the decoder differ.
#[test]
fn runtime_bf16_encodes_in_f32() {
    use hood::kernels::{Kernels, Tier};
    use hood::sim::{Probe, Stage};
    let scene = Scene::new(12, 12);
    let bytes = random_model(32, 5, true);
    let model = bytes.model().unwrap();
    let step = |precision: Precision, tier: Tier| {
        let cfg = SimConfig::network().with_precision(precision).with_tier(Some(tier));
        let mut sim = scene.sim(&model, cfg).unwrap();
        let (mut encoded, mut decoded) = (Vec::new(), Vec::new());
        let mut observe = |p: Probe<'_>| match p.stage {
            // The first pass only: later ones start from the first's bf16 output.
            Stage::Encoded if encoded.is_empty() => encoded = [p.garment, p.body].concat(),
            Stage::Decoded if decoded.is_empty() => decoded = p.garment.to_vec(),
            _ => {}
        };
        sim.step_observed(&scene.body_at(1), &mut observe).unwrap();
        (encoded, decoded)
    };
    let best = Kernels::best().tier();
    for tier in Tier::ALL.into_iter().filter(|t| *t <= best) {
        let (enc_f32, dec_f32) = step(Precision::F32, tier);
        let (enc_bf16, dec_bf16) = step(Precision::Bf16, tier);
        assert!(!enc_f32.is_empty() && !dec_f32.is_empty(), "{}", tier.name());
        let differ = |a: &[f32], b: &[f32]| a.iter().zip(b).filter(|(x, y)| x.to_bits() != y.to_bits()).count();
        assert_eq!(enc_bf16.len(), enc_f32.len(), "{}", tier.name());
        assert_eq!(differ(&enc_bf16, &enc_f32), 0, "{}: encoded latents differ", tier.name());
        assert!(differ(&dec_bf16, &dec_f32) > 0, "{}: the bf16 blocks ran in f32", tier.name());
    }
}

#[test]
fn runtime_refuses_non_finite_body_and_keeps_state() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 3, false);
    let model = bytes.model().unwrap();
    let mut sim = scene.sim(&model, SimConfig::network()).unwrap();
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

/// The first step runs the start-up pass and then the regular one: when either is refused, the
/// state (velocities, body frames, "started"), the normals, the last refinement and the steps
/// after are as if the refused call had never happened.
#[test]
fn runtime_refused_first_step_restores_the_state() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    // A body that moves 3e38 m in a frame (no teleport): the start-up pass (static body)
    // succeeds, and the regular pass's refinement, which the start-up pass skips, cannot place
    // the body's faces in its grid.
    let cfg = SimConfig::network().with_teleport(None).with_normals(true).with_refine(Some(3));
    let far = |t: usize| -> Vec<[f32; 3]> { scene.body_at(t).iter().map(|p| [p[0] + 3.0e38, p[1], p[2]]).collect() };
    let mut sim = scene.sim(&model, cfg).unwrap();
    let (state0, normals0) = (sim.state().clone(), sim.normals().to_vec());
    for _ in 0..2 {
        assert!(matches!(sim.step(&far(1)).unwrap_err(), Error::NonFinite { .. }));
        assert_eq!(sim.state(), &state0);
        assert_eq!(sim.normals(), &normals0[..]);
        assert!(sim.last_refinement().is_none());
    }
    let mut fresh = scene.sim(&model, cfg).unwrap();
    for t in 1..=2 {
        let b = scene.body_at(t);
        assert_eq!(sim.step(&b).unwrap(), fresh.step(&b).unwrap(), "step {t}");
    }
    assert_eq!(sim.state(), fresh.state());
    assert_eq!(sim.normals(), fresh.normals());
    // A refused later step keeps the last refinement's report.
    let report = sim.last_refinement().copied();
    assert!(report.is_some());
    let before = sim.state().clone();
    assert!(sim.step(&far(3)).is_err());
    assert_eq!(sim.state(), &before);
    assert_eq!(sim.last_refinement().copied(), report);

    // A refusal in the start-up pass itself (a body frame whose extent overflows the body's
    // grid) keeps the velocities the start-up would have zeroed.
    let cfg = SimConfig::network().with_teleport(None).with_speed_limit(None);
    let mut sim = scene.sim(&model, cfg).unwrap();
    let mut state = sim.state().clone();
    state.velocity.iter_mut().enumerate().for_each(|(i, v)| *v = [0.001 * i as f32, 0.0, 0.0]);
    let spread: Vec<[f32; 3]> = scene
        .body_at(0)
        .iter()
        .enumerate()
        .map(|(i, p)| [if i % 2 == 0 { 3.0e38 } else { -3.0e38 }, p[1], p[2]])
        .collect();
    state.body_pos.clone_from(&spread);
    state.body_prev.clone_from(&spread);
    sim.set_state(&state).unwrap();
    let refused = sim.step(&spread);
    assert!(matches!(refused, Err(Error::NonFinite { .. })), "{:?}", refused.map(|p| p[0]));
    assert_eq!(sim.state(), &state);
}

/// A refused step leaves what the sim reports about the last step (FLOPs, body counts, projected
/// and tethered vertices, the tethers' ties) as the last step that ran left it, like the state.
#[test]
fn runtime_refused_step_keeps_the_last_steps_figures() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    // As above: the start-up pass succeeds (it ties the tethers and runs the network), the regular
    // pass's refinement is refused.
    let cfg = SimConfig::network()
        .with_teleport(None)
        .with_refine(Some(3))
        .with_projection(Some(0.002))
        .with_tether(Some(0.05));
    let far = |t: usize| -> Vec<[f32; 3]> { scene.body_at(t).iter().map(|p| [p[0] + 3.0e38, p[1], p[2]]).collect() };
    let figures = |s: &Sim| {
        (s.last_step_flops(), s.last_body_counts(), s.last_projected(), s.last_tethered(), s.tethered_vertices())
    };
    let mut sim = scene.sim(&model, cfg).unwrap();
    let none = figures(&sim);
    assert_eq!(none, (0, (0, 0), 0, 0, 0));
    assert!(sim.step(&far(1)).is_err());
    assert_eq!(figures(&sim), none);
    for t in 1..=2 {
        sim.step(&scene.body_at(t)).unwrap();
    }
    let last = figures(&sim);
    assert!(last.0 > 0 && last.4 > 0, "{last:?}");
    assert!(sim.step(&far(3)).is_err());
    assert_eq!(figures(&sim), last);
}

/// Normals (when on) always belong to the current positions: at creation and after `set_state`
/// as well as after steps.
#[test]
fn runtime_normals_follow_the_state_from_creation_and_reset() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 6, false);
    let model = bytes.model().unwrap();
    let mut sim = scene.sim(&model, SimConfig::network().with_normals(true)).unwrap();
    let expected = |pos: &[[f32; 3]]| {
        let mut out = vec![[0.0f32; 3]; pos.len()];
        hood::mesh::vertex_normals(scene.garment.faces(), pos, &mut out);
        out
    };
    assert_eq!(sim.normals(), &expected(scene.garment.rest())[..]);
    assert!(sim.normals().iter().all(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - 1.0).abs() < 1e-4));
    let mut state = sim.state().clone();
    // Tilt the garment by a quarter turn about z: the normals turn with it.
    for p in state.pos.iter_mut() {
        *p = [-p[1], p[0], p[2]];
    }
    sim.set_state(&state).unwrap();
    assert_eq!(sim.normals(), &expected(&state.pos)[..]);
    sim.step(&scene.body_at(1)).unwrap();
    assert_eq!(sim.normals(), &expected(sim.positions())[..]);
}

#[test]
fn runtime_refuses_absurd_thread_counts() {
    let scene = Scene::new(6, 6);
    let bytes = random_model(16, 7, false);
    let model = bytes.model().unwrap();
    let cfg = SimConfig::network().with_threads(hood::sim::MAX_THREADS + 1);
    let refused = scene.sim(&model, cfg).err();
    assert!(matches!(refused, Some(Error::OutOfRange { what, .. }) if what.starts_with("threads")), "{refused:?}");
    let cfg = SimConfig::network().with_threads(3);
    assert!(scene.sim(&model, cfg).is_ok());
}

#[test]
fn runtime_pinned_vertices_follow_their_targets() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 4, false);
    let model = bytes.model().unwrap();
    let mut sim = Sim::new(&model, &scene.garment, None, SimConfig::network()).unwrap();
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
    let cfg = SimConfig::network().with_precision(Precision::Bf16);
    assert!(matches!(Sim::new(&model, &scene.garment, None, cfg).err(), Some(Error::UnsupportedEffect { .. })));
}

fn centroid(p: &[[f32; 3]]) -> [f32; 3] {
    let n = p.len() as f32;
    let s = p.iter().fold([0.0f32; 3], |s, q| [s[0] + q[0], s[1] + q[1], s[2] + q[2]]);
    [s[0] / n, s[1] / n, s[2] / n]
}

#[test]
fn runtime_teleport_carries_the_garment_rigidly() {
    let scene = Scene::new(10, 10);
    let bytes = random_model(16, 6, false);
    let model = bytes.model().unwrap();
    let mut sim = scene.sim(&model, SimConfig::network()).unwrap();
    sim.step(&scene.body_at(1)).unwrap();
    let before = sim.positions().to_vec();
    let vel = sim.state().velocity.clone();
    // A 1 m jump along x in one frame.
    let jumped: Vec<[f32; 3]> = scene.body_at(1).iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect();
    let after = sim.step(&jumped).unwrap().to_vec();
    for (a, b) in before.iter().zip(&after) {
        assert!((b[0] - a[0] - 1.0).abs() < 1e-4 && (b[1] - a[1]).abs() < 1e-4 && (b[2] - a[2]).abs() < 1e-4);
    }
    for (a, b) in vel.iter().zip(&sim.state().velocity) {
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5));
    }
    // A 180° turn about the vertical axis through the body's centre, in one frame.
    let c = centroid(&jumped);
    let turned: Vec<[f32; 3]> = jumped.iter().map(|p| [2.0 * c[0] - p[0], p[1], 2.0 * c[2] - p[2]]).collect();
    let before = sim.positions().to_vec();
    let after = sim.step(&turned).unwrap().to_vec();
    for (a, b) in before.iter().zip(&after) {
        let want = [2.0 * c[0] - a[0], a[1], 2.0 * c[2] - a[2]];
        assert!((0..3).all(|k| (b[k] - want[k]).abs() < 1e-3), "{b:?} vs {want:?}");
    }
    // And stepping goes on from there, finite.
    let p = sim.step(&turned).unwrap();
    assert!(p.iter().all(|q| q.iter().all(|x| x.is_finite())));
    // A finite motion that would carry the garment past f32's range is refused, state unchanged.
    let far = hood::body::rigid::RigidMotion { rotation: glam::Quat::IDENTITY, translation: glam::Vec3::splat(3e38) };
    sim.teleport(&far, &turned).unwrap();
    let before = (sim.positions().to_vec(), sim.state().velocity.clone());
    let err = sim.teleport(&far, &turned).unwrap_err();
    assert!(matches!(err, hood::Error::NonFinite { .. }), "{err}");
    assert_eq!((sim.positions().to_vec(), sim.state().velocity.clone()), before);
}

#[test]
fn runtime_fixed_step_driver_runs_at_30_hz() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 7, false);
    let model = bytes.model().unwrap();
    for (hz, want) in [(60.0f32, 30u64), (144.0, 30), (30.0, 30), (24.0, 30)] {
        let sim = scene.sim(&model, SimConfig::network()).unwrap();
        let mut d = hood::sim::FixedStep::new(sim);
        let frames = hz as usize;
        for f in 1..=frames {
            // Body at engine time f / hz: the same sway as the scene's 30 Hz frames, resampled.
            let t = f as f32 / hz * 30.0;
            let dx = 0.01 * (t * 0.3).sin();
            let body: Vec<[f32; 3]> = scene.body_rest.iter().map(|p| [p[0] + dx, p[1], p[2]]).collect();
            let out = d.update(1.0 / hz, &body).unwrap();
            assert!(out.iter().all(|q| q.iter().all(|x| x.is_finite())));
        }
        let steps = d.model_steps();
        assert!(steps.abs_diff(want) <= 1, "{hz} Hz for 1 s: {steps} model steps");
    }
    // A hitch: an engine frame of 1e20 s (or 5 s) is simulated as `MAX_ENGINE_DT`, 30 steps,
    // instead of looping for ever.
    for dt in [1e20f32, 5.0] {
        let mut d = hood::sim::FixedStep::new(scene.sim(&model, SimConfig::network()).unwrap());
        d.update(dt, &scene.body_rest).unwrap();
        let steps = d.model_steps();
        let want = (hood::sim::MAX_ENGINE_DT / hood::sim::MODEL_DT).round() as u64;
        assert!(steps.abs_diff(want) <= 1, "dt {dt}: {steps} model steps");
    }
}

/// The speed limit runs the step in a frame of reference that follows the body's motion beyond
/// the limit: a sim under the limit whose body moves at 0.3 m/frame must match, up to that
/// frame's translation, a sim without the limit whose body (and pins) are moved back by the
/// accumulated carry. Below the limit it changes nothing, bit for bit.
#[test]
fn runtime_speed_limit_follows_the_excess_motion() {
    let scene = Scene::new(10, 10);
    let bytes = random_model(16, 9, false);
    let model = bytes.model().unwrap();
    let limit = hood::sim::DEFAULT_SPEED_LIMIT;
    let frames = 12;
    // 0.3 m/frame along z from frame 3 to frame 8, still before and after.
    let z = |t: usize| 0.3 * (t.clamp(3, 8) - 3) as f32;
    let body_a: Vec<Vec<[f32; 3]>> =
        (0..=frames).map(|t| scene.body_at(t).iter().map(|p| [p[0], p[1], p[2] + z(t)]).collect()).collect();
    let pins_a: Vec<Vec<[f32; 3]>> =
        (0..=frames).map(|t| scene.garment.rest().iter().map(|p| [p[0], p[1], p[2] + z(t)]).collect()).collect();
    // The carry of every step, computed independently: the mean displacement beyond the limit.
    let mut total = vec![[0.0f32; 3]; frames + 1];
    for t in 1..=frames {
        let n = body_a[t].len() as f64;
        let d: [f64; 3] =
            [0, 1, 2].map(|k| body_a[t].iter().zip(&body_a[t - 1]).map(|(b, a)| (b[k] - a[k]) as f64).sum::<f64>() / n);
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let s = if len > limit as f64 { 1.0 - limit as f64 / len } else { 0.0 };
        total[t] = [0, 1, 2].map(|k| total[t - 1][k] + (d[k] * s) as f32);
    }
    assert!(total[frames][2] > 0.5, "the scene exceeds the limit: {:?}", total[frames]);
    let shift = |v: &[[f32; 3]], c: [f32; 3]| -> Vec<[f32; 3]> {
        v.iter().map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]]).collect()
    };
    let b0 = body_a[0].clone();
    let new = |limit: Option<f32>| {
        let cfg = SimConfig::network().with_speed_limit(limit);
        Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b0 }), cfg).unwrap()
    };
    let (mut a, mut b, mut plain) = (new(Some(limit)), new(None), new(None));
    for t in 1..=frames {
        a.set_pin_targets(&pins_a[t]).unwrap();
        a.step(&body_a[t]).unwrap();
        b.set_pin_targets(&shift(&pins_a[t], total[t])).unwrap();
        b.step(&shift(&body_a[t], total[t])).unwrap();
        plain.set_pin_targets(&pins_a[t]).unwrap();
        plain.step(&body_a[t]).unwrap();
        if total[t] == [0.0; 3] {
            assert_eq!(a.state(), plain.state(), "frame {t}: under the limit nothing changes");
        }
        let moved_back = shift(a.positions(), total[t]);
        let err = moved_back
            .iter()
            .zip(b.positions())
            .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f32::max))
            .fold(0.0, f32::max);
        let verr = a
            .state()
            .velocity
            .iter()
            .zip(&b.state().velocity)
            .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f32::max))
            .fold(0.0, f32::max);
        assert!(err < 1e-3 && verr < 1e-3, "frame {t}: positions {err} m, velocities {verr} m/frame apart");
    }
    // The carried garment came along; without the limit the network saw 9 m/s.
    let gap = |s: &Sim| (centroid(s.positions())[2] - centroid(&pins_a[frames])[2]).abs();
    println!("garment centroid behind the pins: {:.3} m with the limit, {:.3} m without", gap(&a), gap(&plain));
    // A limit or teleport threshold that is not a positive distance is refused: a NaN limit
    // used to carry every position to NaN on a still body.
    for bad in [f32::NAN, -0.1, 0.0, f32::INFINITY] {
        for cfg in [SimConfig::network().with_speed_limit(Some(bad)), SimConfig::network().with_teleport(Some(bad))] {
            assert!(matches!(scene.sim(&model, cfg), Err(Error::OutOfRange { .. })), "{bad}");
        }
    }
}

/// Collision projection moves exactly the free vertices that end a step within the margin of the
/// plane of their nearest body face (nearest centroid by brute force, within the reach), by the
/// missing distance along the face's normal, and adds the move to their velocity. Off, it costs
/// nothing and changes nothing; it refuses bad margins and scenes without a body.
#[test]
fn runtime_collision_projection_pushes_cloth_out_of_the_body() {
    use hood::sim::PROJECTION_REACH;
    let scene = Scene::new(13, 13);
    let bytes = random_model(16, 11, false);
    let model = bytes.model().unwrap();
    let b0 = scene.body_at(0);
    let margin = 0.004;
    let new_with = |projection: Option<f32>, refine: Option<u32>| {
        let cfg = SimConfig::network().with_projection(projection).with_refine(refine).with_startup(false);
        Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b0 }), cfg)
    };
    let new = |projection: Option<f32>| new_with(projection, None);
    // Also after solver refinement, whose body faces the projection then reuses.
    for refine in [None, Some(1)] {
        let (mut a, mut plain) = (new_with(Some(margin), refine).unwrap(), new_with(None, refine).unwrap());
        // Sunk 5 cm: the middle of the sheet starts inside the top of the body.
        let mut start = plain.state().clone();
        start.pos.iter_mut().for_each(|p| p[1] -= 0.05);
        a.set_state(&start).unwrap();
        let faces = scene.body.faces();
        let (mut centroids, mut normals) = (vec![[0.0f32; 3]; faces.len()], vec![[0.0f32; 3]; faces.len()]);
        let (mut moved_total, mut kept_total) = (0, 0);
        for t in 1..=4 {
            plain.set_state(a.state()).unwrap();
            let body = scene.body_at(t);
            plain.step(&body).unwrap();
            a.step(&body).unwrap();
            hood::body::geometry::face_centroids(faces, &body, &mut centroids);
            hood::body::geometry::face_normals(faces, &body, &mut normals);
            let mut moved = 0;
            for (i, p) in plain.positions().iter().enumerate() {
                let got = a.positions()[i];
                let dv: Vec<f32> =
                    (0..3).map(|k| a.state().velocity[i][k] - plain.state().velocity[i][k] - (got[k] - p[k])).collect();
                assert!(
                    dv.iter().all(|d| d.abs() < 1e-5),
                    "frame {t}, vertex {i}: the velocity misses the move {dv:?}"
                );
                let d2 = |c: &[f32; 3]| (0..3).map(|k| (p[k] - c[k]) * (p[k] - c[k])).sum::<f32>();
                let best = centroids.iter().map(d2).fold(f32::INFINITY, f32::min);
                // Every face as near as the nearest (ties on the symmetric body) is a right answer.
                let expected: Vec<[f32; 3]> = if scene.garment.pinned()[i] || best.sqrt() > PROJECTION_REACH {
                    vec![*p]
                } else {
                    (0..faces.len())
                        .filter(|&f| d2(&centroids[f]) <= best * (1.0 + 1e-5))
                        .map(|f| {
                            let d: f32 = (0..3).map(|k| (p[k] - centroids[f][k]) * normals[f][k]).sum();
                            let push = (margin - d).max(0.0);
                            [0, 1, 2].map(|k| p[k] + push * normals[f][k])
                        })
                        .collect()
                };
                let off = |e: &[f32; 3]| (0..3).map(|k| (got[k] - e[k]).abs()).fold(0.0, f32::max);
                assert!(
                    expected.iter().any(|e| off(e) < 1e-5),
                    "frame {t}, vertex {i}: projected to {got:?}, expected one of {expected:?}"
                );
                if got != *p {
                    moved += 1;
                } else if best.sqrt() <= PROJECTION_REACH {
                    kept_total += 1;
                }
            }
            assert_eq!(a.last_projected(), moved, "frame {t}");
            assert_eq!(plain.last_projected(), 0);
            moved_total += moved;
        }
        // Refinement pushes most of the cloth out by itself: fewer are left to project.
        let need = if refine.is_none() { 20 } else { 5 };
        assert!(
            moved_total >= need && kept_total >= 20,
            "a real test: {moved_total} moved, {kept_total} near but kept"
        );
    }
    for bad in [-1e-3, f32::NAN, PROJECTION_REACH] {
        assert!(matches!(new(Some(bad)).err(), Some(Error::OutOfRange { .. })), "margin {bad}");
    }
    let cfg = SimConfig::network().with_projection(Some(margin));
    assert!(matches!(Sim::new(&model, &scene.garment, None, cfg).err(), Some(Error::UnsupportedEffect { .. })));
}

/// Solver refinement in the step: the velocity takes the refined move (the state stays
/// consistent), pinned vertices stay at their targets, each refinement lowers the objective it
/// reports, a scene without a body refines the cloth terms alone, and bad iteration counts are
/// refused. Off, nothing is reported.
#[test]
fn runtime_refinement_lowers_the_objective_and_keeps_the_state_consistent() {
    use hood::sim::MAX_REFINE_ITERATIONS;
    let scene = Scene::new(12, 12);
    let bytes = random_model(16, 12, false);
    let model = bytes.model().unwrap();
    let b0 = scene.body_at(0);
    let body = || Some(BodyDesc { mesh: &scene.body, positions: &b0 });
    let new = |refine: Option<u32>, with_body: bool| {
        let cfg = SimConfig::network().with_refine(refine);
        Sim::new(&model, &scene.garment, if with_body { body() } else { None }, cfg)
    };
    let mut plain = new(None, true).unwrap();
    for with_body in [true, false] {
        let mut sim = new(Some(5), with_body).unwrap();
        assert!(sim.last_refinement().is_none());
        for t in 1..=4 {
            let before = sim.positions().to_vec();
            let b = scene.body_at(t);
            // A fresh sim from the same state builds every body frame anew: the same step.
            let mut fresh = new(Some(5), with_body).unwrap();
            fresh.set_state(sim.state()).unwrap();
            fresh.step(if with_body { &b } else { &[] }).unwrap();
            sim.step(if with_body { &b } else { &[] }).unwrap();
            assert_eq!(sim.state(), fresh.state(), "frame {t}, body {with_body}");
            let r = *sim.last_refinement().unwrap();
            assert!(r.iterations >= 1 && r.f < r.f_start, "frame {t}, body {with_body}: {r:?}");
            for (i, (p, q)) in before.iter().zip(sim.positions()).enumerate() {
                if scene.garment.pinned()[i] {
                    assert_eq!(*q, scene.garment.rest()[i], "pinned vertex {i} moved");
                    continue;
                }
                if t == 1 {
                    continue; // the start-up step ran first
                }
                // No speed limit carry in this slow scene: v' = x' - x.
                let v = sim.state().velocity[i];
                assert!((0..3).all(|k| (v[k] - (q[k] - p[k])).abs() < 1e-6), "frame {t}, vertex {i}");
            }
        }
    }
    plain.step(&scene.body_at(1)).unwrap();
    assert!(plain.last_refinement().is_none());
    for bad in [0, MAX_REFINE_ITERATIONS + 1] {
        assert!(matches!(new(Some(bad), true).err(), Some(Error::OutOfRange { .. })), "{bad} iterations");
    }
}

/// Under the speed limit's carry the refinement minimises the objective of the world's
/// coasting (`velocity + carry`): an independent implicit step started from the refined
/// positions finds almost nothing left to gain, against what the step gained from coasting.
#[test]
fn runtime_refinement_coasts_in_the_carried_frame() {
    use hood::physics::{face_frames, Cloth, FaceFrame, Objective};
    use hood::sim::REFINE_COLLISION_WEIGHT;
    use hood::solve::{ImplicitStep, LbfgsParams, StepBody, StepState};
    let scene = Scene::new(10, 10);
    let bytes = random_model(16, 13, false);
    let model = bytes.model().unwrap();
    let limit = 0.05;
    let cfg = SimConfig::network().with_refine(Some(300)).with_speed_limit(Some(limit)).with_teleport(None);
    let mut sim = scene.sim(&model, cfg).unwrap();
    // The body slides by 0.08 m a frame along x: the limit carries 0.03 m of it.
    let body =
        |t: usize| -> Vec<[f32; 3]> { scene.body_at(0).iter().map(|p| [p[0] + 0.08 * t as f32, p[1], p[2]]).collect() };
    sim.step(&body(1)).unwrap();
    let faces = scene.body.faces();
    let frame_of = |b: &[[f32; 3]]| {
        let (mut c, mut n) = (vec![[0.0f32; 3]; faces.len()], vec![[0.0f32; 3]; faces.len()]);
        face_frames(b, faces, &mut c, &mut n).unwrap();
        let mut grid = hood::body::PointGrid::new(c.len(), 8 * c.len()).unwrap();
        grid.rebuild(&c).unwrap();
        (c, n, grid)
    };
    for t in 2..=3 {
        let before = sim.state().clone();
        sim.step(&body(t)).unwrap();
        let x = sim.positions().to_vec();
        let carry = [0.08 - limit, 0.0, 0.0];
        let coast: Vec<[f32; 3]> = before.velocity.iter().map(|v| [v[0] + carry[0], v[1], v[2]]).collect();
        let (now, next) = (frame_of(&before.body_pos), frame_of(&body(t)));
        let (fnow, fnext) =
            (FaceFrame { centroids: &now.0, normals: &now.1 }, FaceFrame { centroids: &next.0, normals: &next.1 });
        let sb = StepBody {
            prev: fnow,
            current: fnow,
            next: fnext,
            query_prev: &now.2,
            query_current: &now.2,
            query_next: &next.2,
        };
        let pinned = scene.garment.pinned();
        let state = StepState { pos: &before.pos, velocity: &coast, dt: hood::features::DT, pinned, targets: &x };
        let cloth = Cloth::<f32>::new(&scene.garment);
        let objective = Objective::training(REFINE_COLLISION_WEIGHT);
        let mut solver = ImplicitStep::<f32>::new(x.len(), 10);
        let mut coasted: Vec<[f32; 3]> =
            before.pos.iter().zip(&coast).map(|(p, v)| [p[0] + v[0], p[1] + v[1], p[2] + v[2]]).collect();
        for (i, c) in coasted.iter_mut().enumerate() {
            if pinned[i] {
                *c = x[i];
            }
        }
        let e_coast = solver.evaluate(&cloth, &objective, &state, Some(&sb), &coasted).unwrap().total();
        let mut y = x.clone();
        let r = solver
            .refine(&cloth, &objective, &state, Some(&sb), &LbfgsParams::default().with_max_iterations(50), &mut y)
            .unwrap();
        let (gained, left) = (e_coast as f64 - r.f_start, r.f_start - r.f);
        println!("frame {t}: the step gained {gained:.3e} J from coasting; {left:.3e} J left");
        assert!(gained > 0.0 && left <= 1e-3 * gained, "frame {t}: {left:e} J left of {gained:e}");
    }
}

/// The solver step mode: no network, the implicit step by L-BFGS from the coasting guess. It
/// lowers the objective from coasting, more iterations lower it further from the same state,
/// the first step is a regular one (no start-up), a random model's weights do not matter, and
/// it refuses `refine` beside it.
#[test]
fn runtime_solver_step_mode_is_the_implicit_step_without_the_network() {
    use hood::sim::StepMode;
    let scene = Scene::new(12, 12);
    let b0 = scene.body_at(0);
    let new = |seed: u64, iterations: u32| {
        let bytes = random_model(16, seed, false);
        let cfg = SimConfig::network().with_step(StepMode::Solver { iterations });
        let model = bytes.model().unwrap();
        let mut sim =
            Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b0 }), cfg).unwrap();
        let mut objective = Vec::new();
        for t in 1..=20 {
            sim.step(&scene.body_at(t)).unwrap();
            let r = *sim.last_refinement().unwrap();
            assert!(r.f <= r.f_start, "frame {t}: {r:?}");
            objective.push(r.f);
        }
        (objective, sim.positions().to_vec())
    };
    let (few, x_few) = new(1, 5);
    let (other_model, x_other) = new(2, 5);
    assert_eq!((few.clone(), x_few), (other_model, x_other), "the network's weights changed a solver step");
    // From the same first state, 100 iterations reach a lower objective than 5.
    let (many, _) = new(1, 100);
    assert!(many[0] < few[0], "first step: {} with 100 iterations against {} with 5", many[0], few[0]);
    let bytes = random_model(16, 1, false);
    let model = bytes.model().unwrap();
    let cfg = SimConfig::network().with_step(StepMode::Solver { iterations: 5 }).with_refine(Some(3));
    let err = Sim::new(&model, &scene.garment, None, cfg).err();
    assert!(matches!(err, Some(Error::UnsupportedEffect { .. })), "{err:?}");
}

/// The solver step mode within a time budget starts no iteration it predicts would end past the
/// budget, counted from the step's start (here a clock that moves 1 ms each time it is read: the
/// step's start at 0, the solve's at 1 ms, every iteration looks 1 ms long: after the second, at
/// 3 ms, a third would end at 4 ms, past 2.5 ms; with 4.5 ms, three run) and is then the
/// fixed-count solver step of as many iterations, bitwise; a clock that stands still leaves the
/// iteration cap; a zero budget is refused. Each step reports the time it used against its
/// budget ([`Sim::last_budget`], `StepEffects::over_budget`), a budget it could not keep too.
#[test]
fn runtime_solver_budget_ends_each_solve_on_the_clock() {
    use hood::sim::{BudgetUse, Clock, StepMode};
    use std::sync::atomic::{AtomicU64, Ordering};
    struct Ticking(AtomicU64, u64);
    impl Clock for Ticking {
        fn now_ns(&self) -> u64 {
            self.0.fetch_add(self.1, Ordering::SeqCst)
        }
    }
    let scene = Scene::new(12, 12);
    let b0 = scene.body_at(0);
    let bytes = random_model(16, 1, false);
    let model = bytes.model().unwrap();
    let run = |step: StepMode, tick_ns: Option<u64>| {
        let cfg = SimConfig::network().with_step(step);
        let mut sim =
            Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b0 }), cfg).unwrap();
        if let Some(tick) = tick_ns {
            sim.set_clock(Box::new(Ticking(AtomicU64::new(0), tick)));
        }
        let mut iterations = Vec::new();
        let mut budgets = Vec::new();
        for t in 1..=8 {
            sim.step(&scene.body_at(t)).unwrap();
            iterations.push(sim.last_refinement().unwrap().iterations);
            let used = sim.last_budget();
            assert_eq!(sim.last_effects().over_budget, used.is_some_and(|b| !b.met()), "step {t}");
            budgets.push(used);
        }
        if matches!(step, StepMode::Solver { .. }) {
            assert!(budgets.iter().all(Option::is_none), "a fixed count has no budget: {budgets:?}");
        }
        // A placed garment has no solved step to report on.
        sim.set_state(&sim.state().clone()).unwrap();
        assert_eq!((sim.last_budget(), sim.last_effects().over_budget), (None, false));
        (iterations, sim.positions().to_vec(), budgets)
    };
    let budget = StepMode::SolverBudget { micros: 2500, max_iterations: 50 };
    let (its, x, used) = run(budget, Some(1_000_000));
    assert_eq!(its, vec![2; 8], "iterations per step within 2.5 ms of a 1 ms clock");
    // Five readings a step (its start, the solve's, after each iteration, its end): 4 ms used,
    // over the 2.5 ms budget, and the step says so.
    let over = BudgetUse { budget_ns: 2_500_000, used_ns: 4_000_000 };
    assert_eq!(used, vec![Some(over); 8]);
    assert!(!over.met());
    assert_eq!(x, run(StepMode::Solver { iterations: 2 }, None).1, "the budgeted step differs from 2 iterations");
    let (its, _, _) = run(StepMode::SolverBudget { micros: 4500, max_iterations: 50 }, Some(1_000_000));
    assert_eq!(its, vec![3; 8], "iterations per step within 4.5 ms of a 1 ms clock");
    let (its, x, used) = run(budget, Some(0));
    assert!(its.iter().all(|&k| k > 3 && k <= 50), "{its:?}");
    assert_eq!(used, vec![Some(BudgetUse { budget_ns: 2_500_000, used_ns: 0 }); 8], "a clock standing still");
    assert_eq!(x, run(StepMode::Solver { iterations: 50 }, None).1, "a stopped clock differs from the cap");
    let cfg = SimConfig::network().with_step(StepMode::SolverBudget { micros: 0, max_iterations: 5 });
    let err = Sim::new(&model, &scene.garment, None, cfg).err();
    assert!(matches!(err, Some(Error::OutOfRange { .. })), "{err:?}");
}

/// The shipped model files carry their checksum: a single flipped bit anywhere (here at 400
/// positions spread over each file, header included) is refused at load.
#[test]
fn runtime_shipped_models_refuse_any_flipped_bit() {
    for name in ["compact", "medium"] {
        let path = format!("{}/models/{name}.hood", env!("CARGO_MANIFEST_DIR"));
        let bytes = std::fs::read(&path).unwrap();
        assert!(hood::model::ModelBytes::new(&bytes).model().is_ok(), "{name} loads");
        let mut rng = hood::rng::Rng::new(17);
        for k in 0..400 {
            let mut b = bytes.clone();
            let bit = if k < 128 { k } else { rng.below(b.len() * 8) };
            b[bit / 8] ^= 1 << (bit % 8);
            assert!(hood::model::ModelBytes::new(&b).model().is_err(), "{name}: bit {bit} flipped and it loaded");
        }
    }
}

#[test]
fn runtime_refuses_an_inside_out_body_and_surveys_a_coarse_one() {
    let scene = Scene::new(6, 6);
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let b0 = scene.body_at(0);
    // As it comes: outward, and fine enough for the body edges' radius.
    let sim = scene.sim(&model, SimConfig::network()).unwrap();
    let survey = sim.body_survey().unwrap();
    assert!(survey.volume > 0.0 && !survey.too_coarse_for(hood::sim::BODY_EDGE_RADIUS), "{survey:?}");
    // Every face reversed, as a change of handedness between engines gives.
    let flipped: Vec<[u32; 3]> = scene.body.faces().iter().map(|f| [f[0], f[2], f[1]]).collect();
    let inside_out = BodyMesh::new(b0.len(), &flipped).unwrap();
    let err =
        Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &inside_out, positions: &b0 }), SimConfig::network())
            .err()
            .unwrap();
    assert!(matches!(err, Error::InsideOut { what: "body" }), "{err}");
    assert_eq!(err.code(), 15);
    // 164 vertices over the same ellipsoid: accepted, and said to be too coarse.
    let (cv, cf) = hood::body::shapes::ellipsoid(9, 18, [0.25, 0.3, 0.25], [0.0; 3]);
    let coarse = BodyMesh::new(cv.len(), &cf).unwrap();
    let sim = Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &coarse, positions: &cv }), SimConfig::network())
        .unwrap();
    assert!(sim.body_survey().unwrap().too_coarse_for(hood::sim::BODY_EDGE_RADIUS));
}

/// A saved state restores everything the next steps depend on: a fresh sim that loads it
/// continues bitwise as the saving one, with the speed limit's carry (a body moving faster than
/// the limit), the sleeping count and pin targets in play (each left out makes the continuation
/// diverge: a sim given only `set_state` does); damaged or
/// foreign bytes are refused and change nothing.
#[test]
fn runtime_saved_state_continues_bitwise_and_bad_bytes_change_nothing() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 7, false);
    let model = bytes.model().unwrap();
    let cfg = SimConfig::network()
        .with_normals(true)
        // A generous "at rest" (10 m/frame) so that sleeping counts frames in both cases.
        .with_sleeping(Some(hood::sim::Sleeping::new(10.0, 4)))
        .with_speed_limit(Some(0.001));
    let pin_targets = |t: usize| -> Vec<[f32; 3]> {
        scene.garment.rest().iter().map(|p| [p[0] + 0.002 * t as f32, p[1], p[2]]).collect()
    };
    // Moving throughout (the carry), or still from frame 5 to 11 (sleeping counts up).
    for still in [false, true] {
        let body = |t: usize| if still && (5..12).contains(&t) { scene.body_at(5) } else { scene.body_at(t) };
        let mut a = scene.sim(&model, cfg).unwrap();
        for t in 1..8 {
            a.set_pin_targets(&pin_targets(t)).unwrap();
            a.step(&body(t)).unwrap();
        }
        let mut saved = vec![0u8; a.saved_state_len()];
        assert_eq!(a.save_state(&mut saved).unwrap(), saved.len());
        let go_on = |sim: &mut Sim<'_>| -> Vec<Vec<[f32; 3]>> {
            (8..16)
                .map(|t| {
                    sim.step(&body(t)).unwrap();
                    sim.positions().to_vec()
                })
                .collect()
        };
        let mut b = scene.sim(&model, cfg).unwrap();
        b.load_state(&saved).unwrap();
        assert_eq!(b.state(), a.state());
        assert_eq!(b.normals(), a.normals());
        // A sim given only the state (`set_state`) forgets the carry and the sleeping count.
        let mut forgetful = scene.sim(&model, cfg).unwrap();
        forgetful.set_state(a.state()).unwrap();
        forgetful.set_pin_targets(&pin_targets(7)).unwrap();
        let expected = go_on(&mut a);
        assert!(go_on(&mut b) == expected, "the loaded sim diverges (still: {still})");
        assert!(go_on(&mut forgetful) != expected, "the case does not exercise the saved extras (still: {still})");
    }
    // Damaged bytes: every byte of the header and some of the arrays flipped in turn; truncated;
    // another garment's state.
    let a = scene.sim(&model, cfg).unwrap();
    let mut saved = vec![0u8; a.saved_state_len()];
    a.save_state(&mut saved).unwrap();
    let mut c = scene.sim(&model, cfg).unwrap();
    c.step(&scene.body_at(1)).unwrap();
    let before = c.state().clone();
    for i in (0..64).chain((64..saved.len()).step_by(97)) {
        let mut bad = saved.clone();
        bad[i] ^= 0x10;
        assert!(c.load_state(&bad).is_err(), "byte {i} flipped was accepted");
        assert_eq!(c.state(), &before);
    }
    assert!(matches!(c.load_state(&saved[..saved.len() - 1]).unwrap_err(), Error::CorruptData { .. }));
    let other = Scene::new(6, 6);
    let d = other.sim(&model, cfg).unwrap();
    let mut small = vec![0u8; d.saved_state_len()];
    d.save_state(&mut small).unwrap();
    assert!(matches!(c.load_state(&small).unwrap_err(), Error::SizeMismatch { .. }));
    assert!(matches!(d.save_state(&mut [0u8; 8]).unwrap_err(), Error::SizeMismatch { .. }));
    assert_eq!(c.state(), &before);
}

/// The network step's hand-offs (jobs split between threads, each a synchronisation) stay within
/// two per edge set (the pair of node projections in one job, then the fused edge kernel), four
/// for the body edges (both directions' projections in one job, two edge kernels, the sum of the
/// garment-to-body messages), one to zero the block's message slots and one for the node MLP
/// (which copies its residual in the same job), besides the encoders and the decoder. Counted by
/// an executor that claims two threads and runs the tasks in order, with the body far enough
/// below the cloth for few body edges and then close enough for many.
#[test]
fn runtime_network_step_hands_off_few_jobs() {
    use hood::sim::Executor;
    use std::sync::atomic::{AtomicUsize, Ordering};
    struct Counting(std::sync::Arc<AtomicUsize>);
    // SAFETY: every index once, in order, on the calling thread.
    unsafe impl Executor for Counting {
        fn parallelism(&self) -> usize {
            2
        }
        fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
            if n > 1 {
                self.0.fetch_add(1, Ordering::Relaxed);
            }
            (0..n).for_each(task);
        }
    }
    let scene = Scene::new(24, 24);
    let bytes = random_model(32, 5, false);
    let model = bytes.model().unwrap();
    let mut sim = scene.sim(&model, SimConfig::network().with_startup(false)).unwrap();
    let count = std::sync::Arc::new(AtomicUsize::new(0));
    sim.set_executor(Box::new(Counting(count.clone())));
    let mut body_covered = false;
    for t in 1..=6 {
        // From step 4 the body rises to just under the cloth.
        let lift = if t > 3 { 0.018 } else { 0.0 };
        let body: Vec<[f32; 3]> = scene.body_at(t).iter().map(|p| [p[0], p[1] + lift, p[2]]).collect();
        let before = count.load(Ordering::Relaxed);
        sim.step(&body).unwrap();
        let handoffs = count.load(Ordering::Relaxed) - before;
        let spec = model.spec();
        // Body edges split between tasks only past 64 of them: both directions' projections in
        // one job, both directions' edge kernels in another, and the sum.
        let body_jobs = if sim.last_body_counts().0 > 64 { 1 + 1 + 1 } else { 0 };
        let per_block: usize = spec.blocks.iter().map(|b| 2 * b.keys.len() + body_jobs + 1 + 1).sum();
        let encoders =
            1 + spec.blocks.iter().flat_map(|b| &b.keys).collect::<std::collections::BTreeSet<_>>().len() + 1;
        let bound = per_block + encoders + 1;
        assert!(handoffs > spec.blocks.len(), "step {t}: {handoffs} hand-offs: the step should split its work");
        println!("step {t}: {handoffs} hand-offs (at most {bound}), {} body edges", sim.last_body_counts().0);
        assert!(handoffs <= bound, "step {t}: {handoffs} hand-offs, more than {bound}");
        body_covered |= body_jobs > 0;
    }
    assert!(body_covered, "no step had enough body edges to split their work");
}

/// Without an observer the last block leaves out the body's rows (nothing reads them): the
/// garment comes out bitwise as in an observed step, which computes every row, for less work.
#[test]
fn runtime_unobserved_last_block_skips_only_unread_body_rows() {
    let scene = Scene::new(24, 24);
    let mut split_between_tasks = false;
    for precision in [Precision::F32, Precision::Bf16] {
        let bytes = random_model(32, 5, true);
        let model = bytes.model().unwrap();
        let cfg = SimConfig::network().with_precision(precision).with_threads(2);
        let (mut plain, mut observed) = (scene.sim(&model, cfg).unwrap(), scene.sim(&model, cfg).unwrap());
        for t in 1..=4 {
            // The body just under the cloth, for many body edges.
            let body: Vec<[f32; 3]> = scene.body_at(t).iter().map(|p| [p[0], p[1] + 0.018, p[2]]).collect();
            plain.step(&body).unwrap();
            let mut last_body_rows = 0;
            let last = hood::sim::Stage::Block(model.spec().blocks.len() - 1);
            observed
                .step_observed(&body, &mut |p| {
                    if p.stage == last {
                        last_body_rows = p.body.len();
                    }
                })
                .unwrap();
            assert_eq!(plain.positions(), observed.positions(), "step {t}, {precision:?}");
            let (edges, active) = plain.last_body_counts();
            println!("step {t}: {edges} body edges, {active} active body nodes");
            assert!(edges > 0 && active > 0, "step {t}: no body edges");
            split_between_tasks |= edges > 64;
            assert_eq!(last_body_rows, active * 32, "step {t}: the observer sees the last block whole");
            let (less, all) = (plain.last_step_flops(), observed.last_step_flops());
            assert!(less < all, "step {t}: {less} FLOPs unobserved, {all} observed");
        }
    }
    assert!(split_between_tasks, "no step had enough body edges to split them between tasks");
}
