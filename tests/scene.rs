//! Animated scenes: the procedural garments dressed on the walking mannequin, and the MakeHuman
//! jeans on the CMU walk (skipped with a message when ../shared/assets is absent).

use hood::rig::procedural::Mannequin;
use hood::scene::{procedural, GarmentKind, MotionKind, INITIAL_CLEARANCE};

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
        let moved = hood::scene::push_out_of(&s.body, s.body_frame(f), &mut y, &pinned).unwrap();
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
    let assets = hood::workloads::default_shared_dir().join("assets");
    if !assets.join("body/base.obj").exists() {
        println!("SKIPPED: {} not found", assets.display());
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
