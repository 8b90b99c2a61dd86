//! Animated scenes: the procedural garments dressed on the walking mannequin, and the MakeHuman
//! jeans on the CMU walk (skipped with a message when ../shared/assets is absent).
#![cfg(feature = "tools")]

mod common;

use hood::rig::procedural::Mannequin;
use hood::scene::{procedural, GarmentKind, MotionKind};
use hood::solve::INITIAL_CLEARANCE;

#[test]
fn scene_procedural_skirt_starts_outside_and_pins_follow_the_body() {
    let m = Mannequin::new();
    let s = procedural(&m, GarmentKind::Skirt, 400, MotionKind::Walk, 1.0).unwrap();
    assert!((30..=31).contains(&s.n_frames()), "{} frames", s.n_frames());
    assert_eq!(s.body_frame(0).len(), m.rest().len());
    let pinned = s.garment.pinned().to_vec();
    assert!(pinned.iter().any(|&p| p), "the skirt's waist is pinned");
    for f in [0, 15, 29] {
        let x = s.initial_garment(f).unwrap();
        // Not inside the body: the mannequin's own signed distance at the posed frame is not
        // available, so check against the nearest body face plane via the same push-out again.
        let mut y = x.clone();
        let moved = hood::solve::push_out_of(&s.body, s.body_frame(f), &mut y, &pinned).unwrap();
        let worst =
            x.iter().zip(&y).map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f32::max)).fold(0.0, f32::max);
        assert!(worst < 0.2 * INITIAL_CLEARANCE, "frame {f}: {moved} vertices still moved by up to {worst} m");
    }
    // Pin targets move with the hips: between frames the waist moves forward with the walk.
    let n = s.garment.n_vertices();
    let (mut a, mut b) = (vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
    s.skinned_garment(0, &mut a).unwrap();
    s.skinned_garment(29, &mut b).unwrap();
    let mean_dz = |p: &[[f32; 3]]| {
        let w: Vec<usize> = (0..n).filter(|&i| pinned[i]).collect();
        w.iter().map(|&i| p[i][2]).sum::<f32>() / w.len() as f32
    };
    let body_dz = {
        let mz = |f: usize| s.body_frame(f).iter().map(|p| p[2]).sum::<f32>() / m.rest().len() as f32;
        mz(29) - mz(0)
    };
    let waist_dz = mean_dz(&b) - mean_dz(&a);
    println!("walk 1 s: body moved {body_dz:.3} m along z, waist pins {waist_dz:.3} m");
    assert!(body_dz.abs() > 0.3, "the walk should move the body");
    assert!((waist_dz - body_dz).abs() < 0.1 * body_dz.abs(), "the waist follows the body");
}

#[test]
fn scene_motion_names_round_trip() {
    for k in [
        MotionKind::Walk,
        MotionKind::Run,
        MotionKind::Jump,
        MotionKind::Turn,
        MotionKind::ArmSwings,
        MotionKind::RandomPoses(17),
    ] {
        assert_eq!(MotionKind::parse(&k.name()), Some(k));
    }
    for g in GarmentKind::ALL {
        assert_eq!(GarmentKind::parse(g.name()), Some(g));
    }
    assert_eq!(MotionKind::parse("random-x"), None);
}

#[test]
fn scene_makehuman_jeans_on_cmu_walk() {
    let assets = common::shared_dir().join("assets");
    if !assets.join("body/base.obj").exists() {
        common::skip("scene_makehuman_jeans_on_cmu_walk", &assets);
        return;
    }
    let s = hood::scene::makehuman(&assets, hood::scene::MakeHumanGarment::Jeans, 60).unwrap();
    assert_eq!(s.garment.n_vertices(), 886);
    assert_eq!(s.n_frames(), 60);
    let pins = s.garment.pinned().iter().filter(|&&p| p).count();
    assert!(pins > 20, "waist pins {pins}");
    let x = s.initial_garment(0).unwrap();
    assert!(x.iter().flatten().all(|c| c.is_finite()));
}

/// A garment of the user's on the MakeHuman body: the fitted jeans and t-shirt given back as
/// meshes around `base.obj` (its frame, in tenths of its units), z up (as a Blender export
/// without axis conversion would give them) come out as the built-in pieces: same rest shape, the jeans' waist pinned automatically, the
/// t-shirt free; and they follow a clip of the motion corpus.
#[test]
fn scene_own_garment_on_makehuman_matches_the_fitted_piece() {
    use hood::scene::own::{GarmentOptions, OwnGarment, Pins, UpAxis};
    use hood::scene::{makehuman_wearing, MakeHumanGarment, MakeHumanMotion, Wearing};
    let assets = common::shared_dir().join("assets");
    if !assets.join("body/base.obj").exists() {
        common::skip("scene_own_garment_on_makehuman_matches_the_fitted_piece", &assets);
        return;
    }
    let motion = MakeHumanMotion::named(&assets, MotionKind::parse("jumps-1001"));
    for which in [MakeHumanGarment::Jeans, MakeHumanGarment::Tee] {
        let piece = hood::scene::makehuman_on(&assets, which, MotionKind::parse("jumps-1001"), 20).unwrap();
        // In base.obj's frame (decimetres, centred) times 10, z up; --scale 0.1 brings it back.
        let shift = hood::io::makehuman::MakeHuman::load(assets.join("body")).unwrap().floor_shift;
        let file: Vec<[f32; 3]> =
            piece.garment.rest().iter().map(|p| [p[0] * 100.0, -p[2] * 100.0, (p[1] - shift) * 100.0]).collect();
        let options = GarmentOptions::default().with_scale(0.1).with_up(UpAxis::Z).with_pins(Pins::Auto);
        let own = Wearing::Own(OwnGarment {
            name: "mine",
            positions: &file,
            triangles: piece.garment.faces(),
            options: &options,
        });
        let s = makehuman_wearing(&assets, own, motion.clone(), 20).unwrap();
        assert_eq!(s.n_frames(), piece.n_frames());
        assert_eq!(s.garment.pinned(), piece.garment.pinned(), "{which:?}");
        let (a, b) = (s.initial_garment(10).unwrap(), piece.initial_garment(10).unwrap());
        let worst =
            a.iter().zip(&b).map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f32::max)).fold(0.0, f32::max);
        assert!(worst < 1e-4, "{which:?}: {worst} m from the built-in piece at frame 10");
    }
}

/// A motion led in from the rest pose: frame 0 is the body and the garment as modelled, only
/// moved along the floor under the clip's first root position; from the lead-in's end on the
/// clip is its own, moved along the floor.
#[test]
fn scene_lead_in_starts_from_the_rest_pose_and_joins_the_clip() {
    use hood::scene::{makehuman_wearing, BvhRest, MakeHumanGarment, MakeHumanMotion, Wearing};
    let assets = common::shared_dir().join("assets");
    if !assets.join("body/base.obj").exists() {
        common::skip("scene_lead_in_starts_from_the_rest_pose_and_joins_the_clip", &assets);
        return;
    }
    let clip = MakeHumanMotion::Bvh(assets.join("motions/amp_walk.bvh"), BvhRest::ZeroArmsDown);
    let piece = Wearing::Piece(MakeHumanGarment::Tee);
    let plain = makehuman_wearing(&assets, piece.clone(), clip.clone(), 50).unwrap();
    let led = makehuman_wearing(&assets, piece, MakeHumanMotion::FromRest(Box::new(clip), 30), 50).unwrap();
    assert_eq!(led.n_frames(), 50);
    // From the lead-in's end the clip is its own, moved along the floor.
    let (a, b) = (led.body_frame(30), plain.body_frame(30));
    let moved_by = [a[0][0] - b[0][0], a[0][1] - b[0][1], a[0][2] - b[0][2]];
    assert!(moved_by[1].abs() < 1e-5, "{moved_by:?}");
    for f in 30..50 {
        let (a, b) = (led.body_frame(f), plain.body_frame(f));
        let off = a
            .iter()
            .zip(b)
            .map(|(p, q)| (0..3).map(|k| (p[k] - q[k] - moved_by[k]).abs()).fold(0.0, f32::max))
            .fold(0.0, f32::max);
        assert!(off < 1e-4, "clip frame {f}: {off} m");
    }
    // Frame 0: the rest body and the garment as fitted, both moved by the same horizontal shift.
    let mh = hood::io::makehuman::MakeHuman::load(assets.join("body")).unwrap();
    let rest = &mh.body.rest;
    let b0 = led.body_frame(0);
    let shift = [b0[0][0] - rest[0][0], b0[0][1] - rest[0][1], b0[0][2] - rest[0][2]];
    assert!(shift[1].abs() < 1e-6, "{shift:?}");
    let moved = |a: &[[f32; 3]], b: &[[f32; 3]]| {
        a.iter()
            .zip(b)
            .map(|(p, q)| (0..3).map(|k| (p[k] - q[k] - shift[k]).abs()).fold(0.0, f32::max))
            .fold(0.0, f32::max)
    };
    assert!(moved(b0, rest) < 1e-5, "body {} m off the moved rest", moved(b0, rest));
    // The garment too, but for the few vertices the start-up push-out lifts off the skin.
    let g0 = led.initial_garment(0).unwrap();
    let off = moved(&g0, led.garment.rest());
    let lifted = g0.iter().zip(led.garment.rest()).filter(|(p, q)| moved(&[**p], &[**q]) > 1e-5).count();
    assert!(
        off <= hood::solve::INITIAL_CLEARANCE && lifted * 20 < g0.len(),
        "garment {off} m off its moved rest shape, {lifted} vertices"
    );
    // It blends into the clip without a jolt: the largest change of a body vertex's motion from
    // one frame to the next is never more than the clip's own over the same frames (its feet
    // strike the floor), and the first frames start gently.
    let jolt = |anim: &hood::scene::Scene, frames: core::ops::Range<usize>| {
        frames
            .flat_map(|f| (0..rest.len()).map(move |v| (f, v)))
            .map(|(f, v)| {
                let (a, b, c) = (anim.body_frame(f)[v], anim.body_frame(f + 1)[v], anim.body_frame(f + 2)[v]);
                ((0..3).map(|k| (c[k] - 2.0 * b[k] + a[k]).powi(2)).sum::<f32>()).sqrt()
            })
            .fold(0.0, f32::max)
    };
    let (led_jolt, clip_jolt) = (jolt(&led, 0..34), jolt(&plain, 0..34));
    assert!(led_jolt <= clip_jolt, "{led_jolt} m per frame per frame against the clip's {clip_jolt}");
    let start = jolt(&led, 0..5);
    assert!(start < 0.01, "{start} m per frame per frame in the first frames");
}

/// The initial garment states the trainer starts from: stretching energy per vertex and the
/// largest edge strain over a few frames of every scene kind.
#[test]
fn scene_initial_states_are_not_torn() {
    use hood::physics::{max_edge_strain, Cloth, Objective, StepInputs};
    let m = Mannequin::new();
    let mut scenes = vec![
        procedural(&m, GarmentKind::Skirt, 300, MotionKind::Walk, 2.0).unwrap(),
        procedural(&m, GarmentKind::Dress, 400, MotionKind::RandomPoses(2), 2.0).unwrap(),
        procedural(&m, GarmentKind::Cape, 200, MotionKind::ArmSwings, 2.0).unwrap(),
    ];
    let assets = common::shared_dir().join("assets");
    if assets.join("body/base.obj").exists() {
        for g in [hood::scene::MakeHumanGarment::Tee, hood::scene::MakeHumanGarment::Jeans] {
            scenes.push(hood::scene::makehuman(&assets, g, 60).unwrap());
        }
    } else {
        common::skip("the MakeHuman scenes", &assets);
    }
    let obj = Objective { inertia: false, gravity: false, bending: false, ..Objective::cloth_only() };
    for s in &scenes {
        let cloth = Cloth::<f64>::new(&s.garment);
        for f in [0, s.n_frames() / 2, s.n_frames() - 1] {
            let x: Vec<[f64; 3]> = s.initial_garment(f).unwrap().iter().map(|p| p.map(f64::from)).collect();
            let inputs = StepInputs { pos: &[], velocity: &[], dt: 1.0 / 30.0, collision: None, friction: None };
            let e = obj.eval(&cloth, &inputs, &x, None).unwrap().stretching;
            let strain = max_edge_strain(&cloth, &x);
            println!(
                "{:<32} frame {f:>3}: stretching {:.3} mJ/vertex, largest edge strain {:.1} %",
                s.name,
                1e3 * e / s.garment.n_vertices() as f64,
                100.0 * strain
            );
            assert!(
                strain.is_finite() && strain < 5.0,
                "{} frame {f}: an edge stretched by {:.0} %",
                s.name,
                100.0 * strain
            );
        }
    }
}

/// The bodies the project ships or builds are wound outward and fine enough for the body edges
/// (MakeHuman skipped with a message when ../shared/assets is absent).
#[test]
fn scene_bodies_are_outward_and_fine_enough_for_the_body_edges() {
    let m = Mannequin::new();
    let mut scenes = vec![procedural(&m, GarmentKind::Dress, 800, MotionKind::Walk, 0.1).unwrap()];
    let assets = common::shared_dir().join("assets");
    if assets.join("body/base.obj").exists() {
        scenes.push(hood::scene::makehuman(&assets, hood::scene::MakeHumanGarment::Tee, 2).unwrap());
    } else {
        common::skip("the MakeHuman body", &assets);
    }
    for s in &scenes {
        let survey = s.body.survey(s.body_frame(0)).unwrap();
        println!("{}: {survey:?}", s.name);
        assert!(!survey.inside_out() && !survey.too_coarse_for(hood::sim::BODY_EDGE_RADIUS), "{}: {survey:?}", s.name);
    }
}

/// Every piece of the three MakeHuman outfits loads, fitted outside the body, the lower pieces'
/// waists pinned, the men's outfit held out (skipped with a message when ../shared/assets is
/// absent).
#[test]
fn scene_every_makehuman_outfit_piece_loads() {
    use hood::scene::MakeHumanGarment;
    let assets = common::shared_dir().join("assets");
    if !assets.join("body/base.obj").exists() {
        common::skip("scene_every_makehuman_outfit_piece_loads", &assets);
        return;
    }
    let expected = [1311, 886, 911, 886, 810, 886];
    for (g, n) in MakeHumanGarment::ALL.into_iter().zip(expected) {
        assert_eq!(MakeHumanGarment::parse(g.name()), Some(g));
        let s = hood::scene::makehuman_on(&assets, g, None, 2).unwrap();
        assert_eq!(s.garment.n_vertices(), n, "{}", s.name);
        let pins = s.garment.pinned().iter().filter(|&&p| p).count();
        assert_eq!(pins > 0, g.pinned_waist(), "{}: {pins} pins", s.name);
        let x = s.initial_garment(0).unwrap();
        assert!(x.iter().flatten().all(|c| c.is_finite()), "{}", s.name);
    }
    assert!(MakeHumanGarment::MaleTee.is_held_out() && !MakeHumanGarment::CropTop.is_held_out());
}
