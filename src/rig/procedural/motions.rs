//! Motions for the mannequin (or any rig with the CMU bone names), at 30 Hz: walk, run, jump,
//! turn on the spot, arm swings, and random smooth pose sequences within joint limits.
//!
//! Joint angles are given about the *world* axes of the rest pose (x = the character's left,
//! y = up, z = forward) relative to the parent and converted to each bone's rest frame; so
//! "flex the hip forward" is a rotation about -x whatever the bone's roll. Grounded motions move
//! the root vertically so that the lowest heel or toe stays at its rest height.

use crate::error::{Error, Result};
use crate::rig::motion::{BodyMotion, MODEL_FPS};
use crate::rig::{skin, Pose, Skeleton, SkinTransforms, SkinWeights};
use alloc::vec;
use alloc::vec::Vec;
use core::f32::consts::{PI, TAU};
use glam::{Quat, Vec3};
use libm::{cosf, sinf};

/// Local rotations (each bone's rest frame, as [`Skeleton::forward_kinematics`] takes them) and
/// root translations per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalMotion {
    /// Frames per second.
    pub fps: f32,
    /// Bones per frame.
    pub n_bones: usize,
    /// `frames x bones` local rotations, frame major.
    pub local: Vec<Quat>,
    /// Root translation per frame, metres.
    pub root: Vec<[f32; 3]>,
}

impl LocalMotion {
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.root.len()
    }
    /// Local rotations of frame `f`.
    pub fn rotations(&self, f: usize) -> &[Quat] {
        &self.local[f * self.n_bones..(f + 1) * self.n_bones]
    }
    /// Poses `skel` at frame `f`.
    pub fn pose(&self, skel: &Skeleton, f: usize, out: &mut Pose) -> Result<()> {
        if f >= self.n_frames() {
            return Err(Error::OutOfRange { what: "motion frame", index: f });
        }
        skel.forward_kinematics(self.rotations(f), self.root[f], out)
    }
    /// Skins `rest` with `weights` at every frame.
    pub fn animate(&self, skel: &Skeleton, weights: &SkinWeights, rest: &[[f32; 3]]) -> Result<BodyMotion> {
        let n = rest.len();
        let mut positions = vec![[0.0f32; 3]; n * self.n_frames()];
        let mut pose = Pose::rest(skel);
        let mut tr = SkinTransforms::new(skel.len());
        for f in 0..self.n_frames() {
            self.pose(skel, f, &mut pose)?;
            tr.update(skel, &pose)?;
            skin(&tr, weights, rest, &mut positions[f * n..(f + 1) * n])?;
        }
        Ok(BodyMotion { fps: self.fps, n_vertices: n, positions })
    }
}

/// Joint angles of one frame about world axes, by bone, and the root offset.
pub(crate) struct Frame {
    /// World-axis rotation of each bone relative to its parent.
    pub(crate) rot: Vec<Quat>,
    /// Root offset, m (y is added after grounding).
    pub(crate) root: Vec3,
    /// How much of the grounding offset applies, 0..1 (1 unless a motion leaves the floor on
    /// purpose, as a flight of a flip does).
    pub(crate) contact: f32,
}

/// Bone indices by CMU name.
pub(crate) struct Bones {
    pub(crate) idx: Vec<usize>,
}

const NAMES: [&str; 21] = [
    "Hips",
    "LowerBack",
    "Spine",
    "Spine1",
    "Neck",
    "Head",
    "LeftShoulder",
    "LeftArm",
    "LeftForeArm",
    "LeftHand",
    "RightShoulder",
    "RightArm",
    "RightForeArm",
    "RightHand",
    "LeftUpLeg",
    "LeftLeg",
    "LeftFoot",
    "RightUpLeg",
    "RightLeg",
    "RightFoot",
    "LeftToeBase",
];
pub(crate) const HIPS: usize = 0;
pub(crate) const LOWER_BACK: usize = 1;
pub(crate) const SPINE: usize = 2;
pub(crate) const SPINE1: usize = 3;
pub(crate) const NECK: usize = 4;
pub(crate) const HEAD: usize = 5;
pub(crate) const L_ARM: usize = 7;
pub(crate) const L_FOREARM: usize = 8;
pub(crate) const R_ARM: usize = 11;
pub(crate) const R_FOREARM: usize = 12;
pub(crate) const L_UPLEG: usize = 14;
pub(crate) const L_LEG: usize = 15;
pub(crate) const L_FOOT: usize = 16;
pub(crate) const R_UPLEG: usize = 17;
pub(crate) const R_LEG: usize = 18;
pub(crate) const R_FOOT: usize = 19;

impl Bones {
    pub(crate) fn new(skel: &Skeleton) -> Result<Bones> {
        let mut idx = Vec::with_capacity(NAMES.len());
        for (k, n) in NAMES.iter().enumerate() {
            idx.push(skel.find(n).ok_or(Error::OutOfRange { what: "rig lacks a CMU bone name", index: k })?);
        }
        if skel.find("RightToeBase").is_none() {
            return Err(Error::OutOfRange { what: "rig lacks a CMU bone name", index: NAMES.len() });
        }
        Ok(Bones { idx })
    }
}

pub(crate) fn rx(a: f32) -> Quat {
    Quat::from_rotation_x(a)
}
pub(crate) fn ry(a: f32) -> Quat {
    Quat::from_rotation_y(a)
}
pub(crate) fn rz(a: f32) -> Quat {
    Quat::from_rotation_z(a)
}

/// What keeps a motion on the floor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Ground {
    /// Nothing: the root moves as the motion says.
    Free,
    /// The lowest heel or toe stays at its rest height (standing and stepping motions).
    Feet,
    /// The lowest of heels, toes, knees, hands and the top of the head stays at the feet's rest
    /// height (inversions, falls, kneeling).
    AnyContact,
}

/// Points that touch the floor: heels (below the ankles) and toe tips, each with its bone; with
/// `any_contact` also the knees, the finger tips and the top of the head.
fn ground_points(skel: &Skeleton, any_contact: bool) -> Result<Vec<(usize, Vec3)>> {
    let f = |n: &str| skel.find(n).ok_or(Error::OutOfRange { what: "rig lacks a CMU bone name", index: 0 });
    let (lf, rf, lt, rt) = (f("LeftFoot")?, f("RightFoot")?, f("LeftToeBase")?, f("RightToeBase")?);
    let b = skel.bones();
    let heel = |i: usize| b[i].head - Vec3::new(0.0, 0.8 * b[i].head.y, 0.03);
    let mut points = vec![(lf, heel(lf)), (rf, heel(rf)), (lt, b[lt].tail), (rt, b[rt].tail)];
    if any_contact {
        for name in ["LeftLeg", "RightLeg", "LeftHand", "RightHand", "Head"] {
            let i = f(name)?;
            points.push(if name.ends_with("Leg") { (i, b[i].head) } else { (i, b[i].tail) });
        }
    }
    Ok(points)
}

/// Runs `f(t, frame)` at 30 Hz for `seconds`, converting world-axis angles to local rotations;
/// `grounded` keeps the lowest heel/toe at its rest height (before `frame.root.y` is added).
fn build(skel: &Skeleton, seconds: f32, grounded: bool, f: impl FnMut(f32, &mut Frame)) -> Result<LocalMotion> {
    build_frames(skel, seconds, if grounded { Ground::Feet } else { Ground::Free }, false, f)
}

/// [`build`] with any [`Ground`] mode: the lowest contact point is brought to the rest height of
/// the feet before `frame.root.y` is added; and, since a floor only pushes, the root never
/// falls faster than gravity: where the grounded pose would drop it faster (a stance knee that
/// bends faster than a body can fall), the body leaves the floor on a ballistic arc until the
/// pose catches up with it.
pub(crate) fn build_on(
    skel: &Skeleton,
    seconds: f32,
    ground_mode: Ground,
    f: impl FnMut(f32, &mut Frame),
) -> Result<LocalMotion> {
    build_frames(skel, seconds, ground_mode, ground_mode != Ground::Free, f)
}

fn build_frames(
    skel: &Skeleton,
    seconds: f32,
    ground_mode: Ground,
    floor_only_pushes: bool,
    mut f: impl FnMut(f32, &mut Frame),
) -> Result<LocalMotion> {
    if !(seconds > 0.0 && seconds.is_finite()) {
        return Err(Error::OutOfRange { what: "motion duration", index: 0 });
    }
    let nb = skel.len();
    let n_frames = (seconds * MODEL_FPS) as usize + 1;
    let ground = ground_points(skel, ground_mode == Ground::AnyContact)?;
    let rest_low = ground[..4].iter().map(|(_, p)| p.y).fold(f32::INFINITY, f32::min);
    let mut out =
        LocalMotion { fps: MODEL_FPS, n_bones: nb, local: Vec::with_capacity(n_frames * nb), root: Vec::new() };
    let mut frame = Frame { rot: vec![Quat::IDENTITY; nb], root: Vec3::ZERO, contact: 1.0 };
    let mut local = vec![Quat::IDENTITY; nb];
    let mut pose = Pose::rest(skel);
    for k in 0..n_frames {
        frame.rot.fill(Quat::IDENTITY);
        frame.root = Vec3::ZERO;
        frame.contact = 1.0;
        f(k as f32 / MODEL_FPS, &mut frame);
        for (b, bone) in skel.bones().iter().enumerate() {
            local[b] = (bone.frame.conjugate() * frame.rot[b] * bone.frame).normalize();
        }
        let mut root = frame.root;
        if ground_mode != Ground::Free {
            skel.forward_kinematics(&local, [root.x, 0.0, root.z], &mut pose)?;
            let low = ground.iter().map(|&(b, p)| pose.transform_point(skel, b, p).y).fold(f32::INFINITY, f32::min);
            root.y += frame.contact * (rest_low - low);
        }
        if floor_only_pushes && k >= 2 {
            // Height after a fall under gravity alone from the last two frames, m.
            let dt = 1.0 / MODEL_FPS;
            let (y1, y2) = (out.root[k - 1][1], out.root[k - 2][1]);
            root.y = root.y.max(2.0 * y1 - y2 - crate::physics::GRAVITY as f32 * dt * dt);
        }
        out.local.extend_from_slice(&local);
        out.root.push(root.into());
    }
    Ok(out)
}

/// A gait cycle: `speed` m/s forward (+z), `cadence` cycles per second, amplitudes scaled by
/// `amp` (1 = walk).
fn gait(skel: &Skeleton, seconds: f32, speed: f32, cadence: f32, amp: f32, run: bool) -> Result<LocalMotion> {
    let b = Bones::new(skel)?.idx;
    build(skel, seconds, true, |t, fr| {
        gait_pose(&b, TAU * cadence * t, amp, if run { 1.0 } else { 0.0 }, fr);
        fr.root.z = speed * t;
    })
}

/// The joint angles of a gait at phase `ph` (radians of the stride cycle), amplitudes scaled by
/// `amp`, `run` from 0 (a walk) to 1 (a run; between, a blend, so that a gait speeding up has no
/// jump in its pose); sets `fr.root.y` to the run's bounce.
pub(crate) fn gait_pose(b: &[usize], ph: f32, amp: f32, run: f32, fr: &mut Frame) {
    // `walk` at 0, `run` at 1, exactly.
    let blend = |walk: f32, run_value: f32| walk * (1.0 - run) + run_value * run;
    for (side, shift) in [(0usize, 0.0f32), (1, PI)] {
        let p = ph + shift;
        let (hip, knee, foot) = if side == 0 { (L_UPLEG, L_LEG, L_FOOT) } else { (R_UPLEG, R_LEG, R_FOOT) };
        let flex = 0.42 * amp * sinf(p);
        let swing = 0.5 + 0.5 * cosf(p - 0.4);
        let knee_flex = blend(0.08 + 0.9 * swing * swing * swing, 0.35 + 1.3 * swing * swing);
        fr.rot[b[hip]] = rx(-flex - blend(0.0, 0.25));
        fr.rot[b[knee]] = rx(knee_flex);
        fr.rot[b[foot]] = rx(-0.15 * sinf(p - 0.5) - blend(0.0, 0.1));
        // Arms swing against the leg of the same side.
        let (arm, fore) = if side == 0 { (L_ARM, L_FOREARM) } else { (R_ARM, R_FOREARM) };
        let dz = if side == 0 { -0.55 } else { 0.55 };
        fr.rot[b[arm]] = rx(0.35 * amp * sinf(p)) * rz(dz);
        fr.rot[b[fore]] = rx(-blend(0.3, 1.3) - 0.15 * amp * sinf(p));
    }
    fr.rot[b[SPINE]] = ry(0.06 * amp * sinf(ph)) * rx(blend(0.03, 0.15));
    fr.rot[b[HIPS]] = ry(-0.05 * amp * sinf(ph));
    fr.root.y = blend(0.0, 0.04 * (sinf(2.0 * ph)).abs());
}

/// Walking forward (+z) at about 1.2 m/s for `seconds`.
pub fn walk(skel: &Skeleton, seconds: f32) -> Result<LocalMotion> {
    gait(skel, seconds, 1.2, 0.9, 1.0, false)
}

/// Running forward (+z) at about 3 m/s for `seconds`.
pub fn run(skel: &Skeleton, seconds: f32) -> Result<LocalMotion> {
    gait(skel, seconds, 3.0, 1.4, 1.6, true)
}

pub(crate) fn smoothstep(a: f32, b: f32, t: f32) -> f32 {
    let x = ((t - a) / (b - a)).clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// A standing jump, 0.3 m high, every 2 s for `seconds`: crouch, take off with the arms swinging
/// up, fly, land in a crouch, stand up.
pub fn jump(skel: &Skeleton, seconds: f32) -> Result<LocalMotion> {
    let b = Bones::new(skel)?.idx;
    build(skel, seconds, true, |t, fr| {
        let c = t % 2.0;
        // Crouch before take-off (0.1-0.75 s) and after landing (1.0-1.9 s).
        let crouch = smoothstep(0.1, 0.5, c) * (1.0 - smoothstep(0.5, 0.75, c))
            + 0.7 * smoothstep(1.0, 1.3, c) * (1.0 - smoothstep(1.35, 1.9, c));
        let air = if (0.7..1.1).contains(&c) {
            let s = (c - 0.7) / 0.4;
            4.0 * s * (1.0 - s)
        } else {
            0.0
        };
        let arms_up = smoothstep(0.5, 0.8, c) * (1.0 - smoothstep(0.9, 1.3, c));
        for (hip, knee, foot, arm, fore, sz) in
            [(L_UPLEG, L_LEG, L_FOOT, L_ARM, L_FOREARM, 1.0f32), (R_UPLEG, R_LEG, R_FOOT, R_ARM, R_FOREARM, -1.0)]
        {
            fr.rot[b[hip]] = rx(-crouch - 0.1 * air);
            fr.rot[b[knee]] = rx(1.6 * crouch + 0.2 * air);
            fr.rot[b[foot]] = rx(-0.6 * crouch + 0.3 * air);
            fr.rot[b[arm]] = rx(0.5 * crouch - 2.0 * arms_up) * rz(sz * 0.2 * arms_up);
            fr.rot[b[fore]] = rx(-0.3 * crouch - 0.2);
        }
        fr.rot[b[LOWER_BACK]] = rx(0.45 * crouch);
        fr.root.y = 0.3 * air;
    })
}

/// Turning on the spot, one full turn every 4 s, with small alternating steps.
pub fn turn_on_the_spot(skel: &Skeleton, seconds: f32) -> Result<LocalMotion> {
    let b = Bones::new(skel)?.idx;
    build(skel, seconds, true, |t, fr| {
        let ph = TAU * 1.0 * t;
        fr.rot[b[HIPS]] = ry(TAU * t / 4.0);
        for (hip, knee, shift) in [(L_UPLEG, L_LEG, 0.0), (R_UPLEG, R_LEG, PI)] {
            let half = 0.5 + 0.5 * sinf(ph + shift);
            let lift = half * half;
            fr.rot[b[hip]] = rx(-0.35 * lift);
            fr.rot[b[knee]] = rx(0.6 * lift);
        }
        fr.rot[b[L_ARM]] = rz(-0.4);
        fr.rot[b[R_ARM]] = rz(0.4);
    })
}

/// Arm swings: raising both arms sideways to above the shoulders and back, then swinging them
/// forward and back, on a 3 s cycle.
pub fn arm_swings(skel: &Skeleton, seconds: f32) -> Result<LocalMotion> {
    let b = Bones::new(skel)?.idx;
    build(skel, seconds, true, |t, fr| {
        let c = t % 3.0;
        let raise = sinf(PI * smoothstep(0.0, 1.5, c)).max(0.0);
        let swing = if c > 1.5 { sinf(TAU * (c - 1.5) / 1.5) } else { 0.0 };
        fr.rot[b[L_ARM]] = rx(-0.9 * swing) * rz(1.4 * raise - 0.2 * (1.0 - raise));
        fr.rot[b[R_ARM]] = rx(0.9 * swing) * rz(-1.4 * raise + 0.2 * (1.0 - raise));
        fr.rot[b[L_FOREARM]] = rx(-0.3 - 0.5 * swing.max(0.0));
        fr.rot[b[R_FOREARM]] = rx(-0.3 - 0.5 * (-swing).max(0.0));
        fr.rot[b[SPINE1]] = ry(0.1 * swing);
    })
}

/// Joint limits about the world x, y, z axes (radians), for the left side and the spine; the
/// right side mirrors y and z.
pub(crate) const LIMITS: [(usize, [[f32; 2]; 3]); 13] = [
    (HIPS, [[-0.1, 0.1], [-0.6, 0.6], [-0.08, 0.08]]),
    (LOWER_BACK, [[-0.1, 0.3], [-0.15, 0.15], [-0.1, 0.1]]),
    (SPINE, [[-0.1, 0.2], [-0.2, 0.2], [-0.1, 0.1]]),
    (SPINE1, [[-0.1, 0.2], [-0.2, 0.2], [-0.08, 0.08]]),
    (NECK, [[-0.3, 0.4], [-0.4, 0.4], [-0.2, 0.2]]),
    (HEAD, [[-0.2, 0.3], [-0.4, 0.4], [-0.15, 0.15]]),
    (6, [[-0.1, 0.1], [-0.1, 0.1], [-0.05, 0.2]]),
    (L_ARM, [[-1.3, 0.5], [-0.4, 0.4], [-0.25, 1.3]]),
    (L_FOREARM, [[-1.6, 0.0], [-0.3, 0.3], [0.0, 0.0]]),
    (9, [[-0.6, 0.6], [-0.3, 0.3], [-0.3, 0.3]]),
    (L_UPLEG, [[-1.1, 0.35], [-0.3, 0.3], [-0.08, 0.45]]),
    (L_LEG, [[0.0, 1.7], [0.0, 0.0], [0.0, 0.0]]),
    (L_FOOT, [[-0.35, 0.45], [-0.1, 0.1], [-0.1, 0.1]]),
];

/// The right-side twin of a left-side table index, if any.
pub(crate) fn mirror(k: usize) -> Option<usize> {
    match k {
        6..=9 => Some(k + 4),
        L_UPLEG..=L_FOOT => Some(k + 3),
        _ => None,
    }
}

/// One random joint channel: bone, world axis, limits (radians) and three sines as
/// `(weight, frequency Hz, phase)`.
pub(crate) type Channel = (usize, usize, f32, f32, [(f32, f32, f32); 3]);

/// Random smooth poses within joint limits (see the source for the table), for training
/// variety: every joint angle is a sum of three sines of random frequency (0.1-0.7 Hz), phase and
/// weight, mapped into its limits. The same `seed` gives the same motion.
pub fn random_poses(skel: &Skeleton, seconds: f32, seed: u64) -> Result<LocalMotion> {
    let b = Bones::new(skel)?.idx;
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut channels: Vec<Channel> = Vec::new();
    for &(k, lim) in &LIMITS {
        let mut sides = vec![(b[k], lim)];
        if let Some(r) = mirror(k) {
            let m = [lim[0], [-lim[1][1], -lim[1][0]], [-lim[2][1], -lim[2][0]]];
            sides.push((b[r], m));
        }
        for (bone, l) in sides {
            for (axis, &[lo, hi]) in l.iter().enumerate() {
                if hi > lo {
                    let waves = core::array::from_fn(|_| (0.2 + next(), 0.1 + 0.6 * next(), TAU * next()));
                    channels.push((bone, axis, lo, hi, waves));
                }
            }
        }
    }
    let mut angle = vec![[0.0f32; 3]; skel.len()];
    build(skel, seconds, true, move |t, fr| {
        angle.fill([0.0; 3]);
        for &(bone, axis, lo, hi, waves) in &channels {
            let total: f32 = waves.iter().map(|w| w.0).sum();
            let s: f32 = waves.iter().map(|&(w, f, p)| w * sinf(TAU * f * t + p)).sum::<f32>() / total;
            // s in [-1, 1]; start every motion near the middle of the range so frame 0 is calm.
            let ramp = smoothstep(0.0, 1.0, t);
            let mid = 0.5 * (lo + hi);
            angle[bone][axis] = mid * ramp + 0.5 * (hi - lo) * s * ramp;
        }
        for (bone, a) in angle.iter().enumerate().take(fr.rot.len()) {
            if a != &[0.0; 3] {
                fr.rot[bone] = rz(a[2]) * ry(a[1]) * rx(a[0]);
            }
        }
    })
}
