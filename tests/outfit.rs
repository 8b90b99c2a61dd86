//! Several garments on one body (`hood::sim::Outfit`): each garment steps as its own sim would,
//! bit for bit, while the body's grids are built once per frame for all of them; a refused step
//! leaves every garment as it was.

mod common;
use common::*;
use hood::sim::{BodyDesc, Outfit, Sim, SimConfig, StepMode};
use hood::Error;

/// Three garments over the same ellipsoid, each reading the body differently: the network with
/// refinement and collision projection (vertex grid and face grids), the solver step (face
/// grids), the network alone (vertex grid).
fn configs() -> [SimConfig; 3] {
    [
        SimConfig::network().with_refine(Some(2)).with_projection(Some(0.003)).with_normals(true),
        SimConfig::network().with_step(StepMode::Solver { iterations: 5 }),
        SimConfig::network().with_threads(2),
    ]
}

#[test]
fn outfit_steps_each_garment_as_its_own_sim_with_one_body_build_per_frame() {
    let scenes = [Scene::new(12, 12), Scene::new(9, 7), Scene::new(10, 14)];
    let bytes = random_model(16, 3, false);
    let model = bytes.model().unwrap();
    let sims = || -> Vec<Sim<'_>> {
        scenes.iter().zip(configs()).map(|(scene, cfg)| scene.sim(&model, cfg).unwrap()).collect()
    };
    let mut alone = sims();
    let mut outfit = Outfit::new(sims()).unwrap();
    let frames = 12;
    for t in 1..=frames {
        let body = scenes[0].body_at(t);
        outfit.step(&body).unwrap();
        for (i, sim) in alone.iter_mut().enumerate() {
            sim.step(&body).unwrap();
            assert_eq!(outfit.positions(i).unwrap(), sim.positions(), "garment {i}, frame {t}");
            let together = outfit.sim(i).unwrap();
            assert_eq!(together.state(), sim.state(), "garment {i}, frame {t}");
            assert_eq!(together.normals(), sim.normals(), "garment {i}, frame {t}");
            assert_eq!(together.last_effects(), sim.last_effects(), "garment {i}, frame {t}");
        }
    }
    // Per frame one vertex grid (at the current frame) and one face grid (at the next), and the
    // first frame's current faces (for the start-up step's projection): separate sims would
    // build 4 per frame between them.
    assert_eq!(outfit.body_builds(), 2 * frames as u64 + 1, "body grids built in {frames} frames");
    // Taken apart again, each sim goes on as it would have.
    let mut apart = outfit.into_sims().unwrap();
    for t in frames + 1..frames + 4 {
        let body = scenes[0].body_at(t);
        for (a, b) in apart.iter_mut().zip(&mut alone) {
            assert_eq!(a.step(&body).unwrap(), b.step(&body).unwrap(), "frame {t}");
        }
    }
}

#[test]
fn outfit_refused_step_leaves_every_garment_unchanged() {
    let scenes = [Scene::new(8, 8), Scene::new(7, 9)];
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let plain = SimConfig::network().with_teleport(None).with_speed_limit(None);
    // The second garment's refinement cannot place a body that moved 3e38 m in its grid; the
    // first garment alone steps there.
    let refined = plain.with_refine(Some(3));
    let far =
        |t: usize| -> Vec<[f32; 3]> { scenes[0].body_at(t).iter().map(|p| [p[0] + 3.0e38, p[1], p[2]]).collect() };
    let mut outfit =
        Outfit::new(vec![scenes[0].sim(&model, plain).unwrap(), scenes[1].sim(&model, refined).unwrap()]).unwrap();
    let mut first = scenes[0].sim(&model, plain).unwrap();
    let mut second = scenes[1].sim(&model, refined).unwrap();
    for t in 1..=3 {
        let body = scenes[0].body_at(t);
        outfit.step(&body).unwrap();
        first.step(&body).unwrap();
        second.step(&body).unwrap();
    }
    let mut probe = scenes[0].sim(&model, plain).unwrap();
    probe.set_state(first.state()).unwrap();
    probe.step(&far(4)).expect("the first garment alone steps on the far body");
    let before: Vec<_> = outfit.sims().iter().map(|s| (s.state().clone(), last_step(s))).collect();
    let err = outfit.step(&far(4)).unwrap_err();
    assert!(matches!(err, Error::NonFinite { .. }), "{err:?}");
    for (i, sim) in outfit.sims().iter().enumerate() {
        assert_eq!((sim.state(), last_step(sim)), (&before[i].0, before[i].1), "garment {i} changed by a refused step");
    }
    // Bad body input is refused before any garment steps.
    assert!(matches!(outfit.step(&far(4)[1..]), Err(Error::SizeMismatch { .. })));
    let mut nan = scenes[0].body_at(4);
    nan[5][1] = f32::NAN;
    assert!(matches!(outfit.step(&nan), Err(Error::NonFinite { .. })));
    // And the outfit goes on as the garments alone.
    for t in 4..=6 {
        let body = scenes[0].body_at(t);
        outfit.step(&body).unwrap();
        assert_eq!(outfit.positions(0).unwrap(), first.step(&body).unwrap());
        assert_eq!(outfit.positions(1).unwrap(), second.step(&body).unwrap());
    }
}

/// What a sim reports about its last step.
fn last_step(s: &Sim) -> (u64, (usize, usize), usize, usize, usize, hood::sim::StepEffects) {
    (
        s.last_step_flops(),
        s.last_body_counts(),
        s.last_projected(),
        s.last_tethered(),
        s.tethered_vertices(),
        s.last_effects(),
    )
}

/// A first step refused by the second garment after the first has run its start-up and regular
/// passes: the first garment reports no step, as before the call, and then steps as a sim alone.
#[test]
fn outfit_refused_first_step_leaves_the_first_garment_unstepped() {
    let scenes = [Scene::new(8, 8), Scene::new(7, 9)];
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let plain = SimConfig::network().with_teleport(None).with_speed_limit(None);
    let first = plain;
    let refined = plain.with_refine(Some(3));
    // The body at the first frame moved far: the refinement cannot place it in its grid.
    let far =
        |t: usize| -> Vec<[f32; 3]> { scenes[0].body_at(t).iter().map(|p| [p[0] + 3.0e38, p[1], p[2]]).collect() };
    let mut outfit =
        Outfit::new(vec![scenes[0].sim(&model, first).unwrap(), scenes[1].sim(&model, refined).unwrap()]).unwrap();
    let mut alone = scenes[0].sim(&model, first).unwrap();
    let unstepped = last_step(&alone);
    assert_eq!(unstepped, (0, (0, 0), 0, 0, 0, Default::default()));
    let mut probe = scenes[0].sim(&model, first).unwrap();
    probe.step(&far(1)).expect("the first garment alone steps on the far body");
    assert!(probe.last_step_flops() > 0 && probe.last_effects().startup);
    assert!(matches!(outfit.step(&far(1)), Err(Error::NonFinite { .. })));
    assert_eq!(last_step(&outfit.sims()[0]), unstepped);
    for t in 1..=3 {
        let body = scenes[0].body_at(t);
        outfit.step(&body).unwrap();
        alone.step(&body).unwrap();
        assert_eq!(outfit.positions(0).unwrap(), alone.positions(), "frame {t}");
        assert_eq!(last_step(&outfit.sims()[0]), last_step(&alone), "frame {t}");
    }
    assert!(alone.last_step_flops() > 0);
}

/// An automatic teleport moves a garment's pin targets with it; when a later garment of the same
/// frame is refused, the first is put back, pin targets included.
#[test]
fn outfit_refused_step_puts_back_the_pin_targets_a_teleport_moved() {
    let scenes = [Scene::new(8, 8), Scene::new(7, 9)];
    let bytes = random_model(16, 5, false);
    let model = bytes.model().unwrap();
    let cfg = SimConfig::network(); // automatic teleport on
    let (mut first, mut alone, mut second) =
        (scenes[0].sim(&model, cfg).unwrap(), scenes[0].sim(&model, cfg).unwrap(), scenes[1].sim(&model, cfg).unwrap());
    for t in 1..=2 {
        let body = scenes[0].body_at(t);
        for sim in [&mut first, &mut alone, &mut second] {
            sim.step(&body).unwrap();
        }
    }
    // The second garment far out (finite): the body's jump below carries it past f32's range,
    // and its teleport is refused after the first garment's has run.
    let mut far = second.state().clone();
    far.pos.iter_mut().for_each(|p| p[0] = 3.0e38);
    second.set_state(&far).unwrap();
    let mut outfit = Outfit::new(vec![first, second]).unwrap();
    let jumped: Vec<[f32; 3]> = scenes[0].body_at(3).iter().map(|p| [p[0] + 3.0e38, p[1], p[2]]).collect();
    assert!(matches!(outfit.step(&jumped), Err(Error::NonFinite { .. })));
    // The first garment goes on as the one that never saw the refused frame, pinned corners too.
    let mut first = outfit.into_sims().unwrap().swap_remove(0);
    for t in 3..=5 {
        let body = scenes[0].body_at(t);
        assert_eq!(first.step(&body).unwrap(), alone.step(&body).unwrap(), "frame {t}");
    }
}

#[test]
fn outfit_refuses_garments_on_another_body_or_frame() {
    let scene = Scene::new(8, 8);
    let bytes = random_model(16, 7, false);
    let model = bytes.model().unwrap();
    let cfg = SimConfig::network();
    assert!(matches!(Outfit::new(Vec::new()), Err(Error::Empty { .. })));
    let b1 = scene.body_at(1);
    let later = Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &scene.body, positions: &b1 }), cfg).unwrap();
    let err = Outfit::new(vec![scene.sim(&model, cfg).unwrap(), later]).err();
    assert!(matches!(err, Some(Error::OutOfRange { index: 1, .. })), "{err:?}");
    let (bv, bf) = hood::body::shapes::ellipsoid(12, 16, [0.25, 0.3, 0.25], [0.0, 0.0, 0.0]);
    let other = hood::body::BodyMesh::new(bv.len(), &bf).unwrap();
    let elsewhere = Sim::new(&model, &scene.garment, Some(BodyDesc { mesh: &other, positions: &bv }), cfg).unwrap();
    let err = Outfit::new(vec![scene.sim(&model, cfg).unwrap(), elsewhere]).err();
    assert!(matches!(err, Some(Error::OutOfRange { index: 1, .. })), "{err:?}");
    let bodiless = Sim::new(&model, &scene.garment, None, cfg).unwrap();
    let err = Outfit::new(vec![scene.sim(&model, cfg).unwrap(), bodiless]).err();
    assert!(matches!(err, Some(Error::OutOfRange { index: 1, .. })), "{err:?}");
    // Pin targets go to the garment named, and no other.
    let mut outfit = Outfit::new(vec![scene.sim(&model, cfg).unwrap(), scene.sim(&model, cfg).unwrap()]).unwrap();
    let mut targets = scene.garment.rest().to_vec();
    targets.iter_mut().for_each(|p| p[1] += 0.01);
    outfit.set_pin_targets(1, &targets).unwrap();
    assert!(matches!(outfit.set_pin_targets(2, &targets), Err(Error::OutOfRange { index: 2, .. })));
    outfit.step(&scene.body_at(1)).unwrap();
    assert_eq!(outfit.positions(1).unwrap()[0], targets[0]);
    assert_eq!(outfit.positions(0).unwrap()[0], scene.garment.rest()[0]);
}
