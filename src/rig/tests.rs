use super::*;
use alloc::format;

/// splitmix64: a tiny seeded generator for tests.
pub(crate) struct Rng(pub u64);
impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next_u64() >> 40) as f32 / (1u64 << 24) as f32)
    }
    pub fn rotation(&mut self) -> Quat {
        let axis = Vec3::new(self.uniform(-1.0, 1.0), self.uniform(-1.0, 1.0), self.uniform(-1.0, 1.0));
        Quat::from_axis_angle(axis.normalize_or(Vec3::Y), self.uniform(-3.0, 3.0))
    }
}

/// A random tree of bones with random rolls and lengths.
fn random_skeleton(rng: &mut Rng, n: usize) -> Skeleton {
    let mut descs: Vec<BoneDesc> = Vec::new();
    for i in 0..n {
        let parent = if i == 0 { None } else { Some((rng.next_u64() % i as u64) as usize) };
        let head = match parent {
            Some(p) => descs[p].tail,
            None => [rng.uniform(-1.0, 1.0), rng.uniform(0.0, 2.0), rng.uniform(-1.0, 1.0)],
        };
        let d = [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)];
        let tail = [head[0] + d[0], head[1] + d[1], head[2] + d[2]];
        let frame = rest_frame(head, tail, rng.uniform(-3.0, 3.0), Vec3::Y);
        descs.push(BoneDesc { name: format!("b{i}"), parent, head, tail, frame });
    }
    Skeleton::new(descs).unwrap()
}

/// Random vertices near random bones with up to 4 random influences.
fn random_skin(rng: &mut Rng, skel: &Skeleton, n: usize) -> (Vec<[f32; 3]>, SkinWeights) {
    let mut rest = Vec::new();
    let mut triples = Vec::new();
    for v in 0..n {
        let b = (rng.next_u64() % skel.len() as u64) as usize;
        let bone = &skel.bones()[b];
        let s = rng.uniform(0.0, 1.0);
        let p = bone.head.lerp(bone.tail, s)
            + Vec3::new(rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1));
        rest.push(p.into());
        for _ in 0..1 + rng.next_u64() % 4 {
            let b = (rng.next_u64() % skel.len() as u64) as u16;
            triples.push((v as u32, b, rng.uniform(0.01, 1.0)));
        }
    }
    let w = SkinWeights::from_triples(n, skel.len(), &triples, 4).unwrap();
    (rest, w)
}

#[test]
fn rig_rest_pose_reproduces_rest_mesh_exactly() {
    let mut rng = Rng(1);
    for _ in 0..10 {
        let skel = random_skeleton(&mut rng, 20);
        let (rest, w) = random_skin(&mut rng, &skel, 500);
        let mut pose = Pose::rest(&skel);
        skel.forward_kinematics(&vec![Quat::IDENTITY; skel.len()], [0.0; 3], &mut pose).unwrap();
        assert_eq!(pose, Pose::rest(&skel));
        let mut tr = SkinTransforms::new(skel.len());
        tr.update(&skel, &pose).unwrap();
        let mut out = vec![[0.0f32; 3]; rest.len()];
        skin(&tr, &w, &rest, &mut out).unwrap();
        assert_eq!(out, rest, "skinning at rest must not move any vertex");
        // World-rotation posing from identities is also the rest pose.
        let mut pose2 = Pose::rest(&skel);
        skel.pose_from_world(&vec![Quat::IDENTITY; skel.len()], [0.0; 3], &mut pose2).unwrap();
        assert_eq!(pose2, pose);
    }
}

#[test]
fn rig_random_rotations_keep_bone_lengths() {
    let mut rng = Rng(2);
    let skel = random_skeleton(&mut rng, 30);
    let mut pose = Pose::rest(&skel);
    for _ in 0..50 {
        let local: Vec<Quat> = (0..skel.len()).map(|_| rng.rotation()).collect();
        let t = [rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0), rng.uniform(-2.0, 2.0)];
        skel.forward_kinematics(&local, t, &mut pose).unwrap();
        for (b, bone) in skel.bones().iter().enumerate() {
            let len = (pose.tail(&skel, b) - pose.head[b]).length();
            assert!((len - bone.length()).abs() < 1e-5, "bone {b}: {len} vs {}", bone.length());
            // Children stay attached at the rest offset from the parent's head.
            if let Some(p) = bone.parent {
                let d = (pose.head[b] - pose.head[p]).length();
                let d0 = (bone.head - skel.bones()[p].head).length();
                assert!((d - d0).abs() < 1e-5);
            }
        }
        // Round trip: the local rotations recovered from the pose give the same pose.
        let mut back = vec![Quat::IDENTITY; skel.len()];
        skel.local_from_pose(&pose, &mut back).unwrap();
        let mut pose2 = Pose::rest(&skel);
        skel.forward_kinematics(&back, t, &mut pose2).unwrap();
        for b in 0..skel.len() {
            assert!(pose2.rotation[b].dot(pose.rotation[b]).abs() > 1.0 - 1e-5);
            assert!((pose2.head[b] - pose.head[b]).length() < 1e-4);
        }
    }
}

#[test]
fn rig_single_bone_skinning_is_rigid() {
    let mut rng = Rng(3);
    let head = [0.1, 0.9, -0.2];
    let tail = [0.1, 1.4, 0.0];
    let skel = Skeleton::new(vec![BoneDesc {
        name: "root".into(),
        parent: None,
        head,
        tail,
        frame: rest_frame(head, tail, 0.4, Vec3::Y),
    }])
    .unwrap();
    let rest: Vec<[f32; 3]> =
        (0..300).map(|_| [rng.uniform(-1.0, 1.0), rng.uniform(0.0, 2.0), rng.uniform(-1.0, 1.0)]).collect();
    let triples: Vec<(u32, u16, f32)> = (0..300).map(|v| (v, 0, rng.uniform(0.1, 3.0))).collect();
    let w = SkinWeights::from_triples(300, 1, &triples, 4).unwrap();
    let mut pose = Pose::rest(&skel);
    let mut tr = SkinTransforms::new(1);
    let mut out = vec![[0.0; 3]; 300];
    for _ in 0..20 {
        let q = rng.rotation();
        let t = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)];
        skel.forward_kinematics(&[q], t, &mut pose).unwrap();
        tr.update(&skel, &pose).unwrap();
        skin(&tr, &w, &rest, &mut out).unwrap();
        let world = skel.bones()[0].frame * q * skel.bones()[0].frame.conjugate();
        for (x, y) in rest.iter().zip(&out) {
            let expect = Vec3::from(head) + Vec3::from(t) + world * (Vec3::from(*x) - Vec3::from(head));
            assert!((expect - Vec3::from(*y)).length() < 1e-5);
        }
        // Rigid: pairwise distances are kept.
        for k in 0..50 {
            let (a, b) = (k, 299 - k);
            let d0 = (Vec3::from(rest[a]) - Vec3::from(rest[b])).length();
            let d1 = (Vec3::from(out[a]) - Vec3::from(out[b])).length();
            assert!((d0 - d1).abs() < 1e-5);
        }
    }
}

#[test]
fn rig_rejects_bad_input() {
    let d =
        |parent| BoneDesc { name: "x".into(), parent, head: [0.0; 3], tail: [0.0, 1.0, 0.0], frame: Quat::IDENTITY };
    assert!(matches!(Skeleton::new(vec![d(Some(0))]), Err(Error::IndexOutOfRange { .. })));
    assert!(matches!(Skeleton::new(vec![]), Err(Error::Empty { .. })));
    assert!(SkinWeights::from_triples(2, 1, &[(0, 0, 1.0)], 4).is_err(), "vertex 1 has no weight");
    assert!(SkinWeights::from_triples(1, 1, &[(0, 3, 1.0)], 4).is_err());
    let skel = Skeleton::new(vec![d(None)]).unwrap();
    let mut pose = Pose::rest(&skel);
    assert!(skel.forward_kinematics(&[], [0.0; 3], &mut pose).is_err());
    // Named parents in any order come out parents first.
    let mut a = d(None);
    a.name = "child".into();
    let mut b = d(None);
    b.name = "root".into();
    let s = Skeleton::from_named(vec![(a, Some("root".into())), (b, None)]).unwrap();
    assert_eq!(s.bones()[0].name, "root");
    assert_eq!(s.bones()[1].parent, Some(0));
}

/// A lead-in starts at the rest pose, only moved horizontally under the first pose's root, keeps
/// every bone's length, turns monotonically towards the motion, and leaves the motion unchanged
/// from its last frame on.
#[test]
fn rig_lead_in_blends_from_the_rest_pose_into_the_motion() {
    let mut rng = Rng(11);
    let skel = random_skeleton(&mut rng, 6);
    let local: Vec<Quat> = (0..skel.len()).map(|_| rng.rotation()).collect();
    // A motion that holds one pose while its root rises and travels along x.
    let motion: Vec<Pose> = (0..16)
        .map(|f| {
            let mut pose = Pose::rest(&skel);
            skel.forward_kinematics(&local, [0.4 + 0.05 * f as f32, 0.25, -1.5], &mut pose).unwrap();
            pose
        })
        .collect();
    let frames = 12;
    let mut lead = motion.clone();
    Pose::lead_in(&skel, &mut lead, frames).unwrap();
    let rest = Pose::rest(&skel);
    assert!(lead[0].rotation.iter().all(|q| *q == Quat::IDENTITY));
    for (h, r) in lead[0].head.iter().zip(&rest.head) {
        assert_eq!(*h, *r + Vec3::new(0.4, 0.0, -1.5));
    }
    let mut last_angle = f32::INFINITY;
    for (k, pose) in lead.iter().enumerate().take(frames) {
        for b in 0..skel.len() {
            let len = (pose.tail(&skel, b) - pose.head[b]).length();
            assert!((len - skel.bones()[b].length()).abs() < 1e-5, "frame {k}, bone {b}");
        }
        let angle = pose.rotation[0].angle_between(motion[k].rotation[0]);
        assert!(angle <= last_angle + 1e-6, "frame {k}: {angle} after {last_angle}");
        last_angle = angle;
    }
    // The root's speed along x grows from 0 to the motion's 5 cm per frame and stays there: from
    // the lead-in's end the motion is its own, moved back by the distance the start-up lost.
    let speed = |k: usize| lead[k + 1].head[0].x - lead[k].head[0].x;
    assert!(speed(0) < 1e-6, "{}", speed(0));
    for k in 1..15 {
        assert!(speed(k) >= speed(k - 1) - 1e-6 && speed(k) <= 0.05 + 1e-6, "frame {k}: {}", speed(k));
    }
    let shift = lead[frames].head[0] - motion[frames].head[0];
    assert!(shift.x < -0.1 && shift.y == 0.0 && shift.z == 0.0, "{shift:?}");
    for (a, b) in lead[frames..].iter().zip(&motion[frames..]) {
        assert_eq!(a.rotation, b.rotation);
        assert!(a.head.iter().zip(&b.head).all(|(p, q)| (*p - *q - shift).length() < 1e-5));
    }
    let bad = Pose { rotation: vec![], head: vec![] };
    assert!(matches!(Pose::lead_in(&skel, &mut [bad], 3), Err(Error::SizeMismatch { .. })));
}
