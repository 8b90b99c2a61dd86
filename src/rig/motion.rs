//! Motion clips (joint hierarchy + per-frame local rotations and translations, as BVH holds
//! them), resampling to the model's 30 Hz, and retargeting onto a [`Skeleton`] by bone name.
//!
//! Retargeting follows the assets README ("How the pieces combine"): each rig bone's direction
//! in an initial rig pose is aligned with the direction of the same-named clip joint in the
//! clip's rest (a chosen frame, or all rotations zero); per frame, a bone's world rotation is the
//! clip joint's world rotation relative to the clip's rest, applied after that alignment; the
//! root translation relative to the rest is scaled by the leg-length ratio of rig and clip.

use super::{skin, Pose, Skeleton, SkinTransforms, SkinWeights};
use crate::error::{Error, Result};
use alloc::string::String;
use alloc::vec;
use alloc::vec::Vec;
use glam::{Quat, Vec3};

/// The model's frame rate (frames per second).
pub const MODEL_FPS: f32 = 30.0;

/// A joint of a clip's hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct ClipJoint {
    /// Name.
    pub name: String,
    /// Parent joint (earlier in the list), `None` for the root.
    pub parent: Option<usize>,
    /// Rest offset from the parent joint, in clip units.
    pub offset: [f32; 3],
    /// Offset of the end site (a leaf's far end), if any.
    pub end_site: Option<[f32; 3]>,
}

/// A motion clip: a joint hierarchy and, per frame and joint, the local rotation (relative to
/// the parent, rest = identity) and local translation (offset from the parent in clip units;
/// the rest offset unless the joint has position channels).
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    joints: Vec<ClipJoint>,
    frame_time: f32,
    n_frames: usize,
    rotations: Vec<Quat>,
    translations: Vec<Vec3>,
}

impl Clip {
    /// Builds a clip. `rotations` and `translations` hold `n_frames x joints` entries, frame
    /// major; `frame_time` is in seconds.
    ///
    /// # Errors
    /// [`Error::Empty`] without joints or frames, [`Error::IndexOutOfRange`] for a parent that is
    /// not an earlier joint, [`Error::SizeMismatch`] for arrays of the wrong length,
    /// [`Error::OutOfRange`] for a frame time that is not positive, [`Error::NonFinite`] for NaNs.
    pub fn new(joints: Vec<ClipJoint>, frame_time: f32, rotations: Vec<Quat>, translations: Vec<Vec3>) -> Result<Clip> {
        if joints.is_empty() {
            return Err(Error::Empty { what: "clip joints" });
        }
        for (i, j) in joints.iter().enumerate() {
            if let Some(p) = j.parent {
                if p >= i {
                    return Err(Error::IndexOutOfRange { what: "clip joint parent", at: i, index: p, len: i });
                }
            }
        }
        if !(frame_time > 0.0 && frame_time.is_finite()) {
            return Err(Error::OutOfRange { what: "frame time", index: 0 });
        }
        let nj = joints.len();
        if rotations.is_empty() {
            return Err(Error::Empty { what: "clip frames" });
        }
        if rotations.len() / nj * nj != rotations.len() || translations.len() != rotations.len() {
            return Err(Error::SizeMismatch {
                what: "clip channels",
                expected: rotations.len(),
                got: translations.len(),
            });
        }
        if let Some(i) = rotations.iter().position(|q| !q.is_finite()) {
            return Err(Error::NonFinite { what: "clip rotation", index: i });
        }
        if let Some(i) = translations.iter().position(|t| !t.is_finite()) {
            return Err(Error::NonFinite { what: "clip translation", index: i });
        }
        let n_frames = rotations.len() / nj;
        Ok(Clip { joints, frame_time, n_frames, rotations, translations })
    }

    /// The joints, parents first.
    pub fn joints(&self) -> &[ClipJoint] {
        &self.joints
    }
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.n_frames
    }
    /// Seconds between frames.
    pub fn frame_time(&self) -> f32 {
        self.frame_time
    }
    /// Duration from the first to the last frame, seconds.
    pub fn duration(&self) -> f32 {
        (self.n_frames - 1) as f32 * self.frame_time
    }
    /// Index of the joint called `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }
    /// Local rotations of frame `f`.
    pub fn rotations(&self, f: usize) -> &[Quat] {
        let n = self.joints.len();
        &self.rotations[f * n..(f + 1) * n]
    }
    /// Local translations of frame `f`, clip units.
    pub fn translations(&self, f: usize) -> &[Vec3] {
        let n = self.joints.len();
        &self.translations[f * n..(f + 1) * n]
    }

    /// World rotations and positions of every joint for the given local rotations and
    /// translations (one per joint), into caller buffers.
    pub fn world_from_local(&self, local: &[Quat], trans: &[Vec3], rot: &mut [Quat], pos: &mut [Vec3]) {
        for (i, j) in self.joints.iter().enumerate() {
            match j.parent {
                Some(p) => {
                    pos[i] = pos[p] + rot[p] * trans[i];
                    rot[i] = (rot[p] * local[i]).normalize();
                }
                None => {
                    pos[i] = trans[i];
                    rot[i] = local[i].normalize();
                }
            }
        }
    }

    /// World rotations and positions of every joint at frame `f`.
    pub fn world(&self, f: usize, rot: &mut [Quat], pos: &mut [Vec3]) {
        let n = self.joints.len();
        let (l, t) = (&self.rotations[f * n..(f + 1) * n], &self.translations[f * n..(f + 1) * n]);
        self.world_from_local(l, t, rot, pos);
    }

    /// The clip resampled at `fps` frames per second over the same duration: rotations by
    /// slerp, translations linearly. The last output frame is at or before the last input frame.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a rate that is not positive; [`Error::CapacityExceeded`] when
    /// the resampled clip would hold more than [`crate::limits::MAX_MOTION_SAMPLES`] joint
    /// samples (a long frame time at a high rate), before anything is allocated.
    pub fn resample(&self, fps: f32) -> Result<Clip> {
        if !(fps > 0.0 && fps.is_finite()) {
            return Err(Error::OutOfRange { what: "frame rate", index: 0 });
        }
        let nj = self.joints.len();
        let step = 1.0 / fps as f64;
        let dt = self.frame_time as f64;
        let frames = libm::floor((self.n_frames - 1) as f64 * dt / step + 1e-6) + 1.0;
        let samples = frames * nj as f64;
        if samples > crate::limits::MAX_MOTION_SAMPLES as f64 {
            return Err(Error::CapacityExceeded {
                what: "resampled clip joint samples (frames x joints)",
                capacity: crate::limits::MAX_MOTION_SAMPLES,
                needed: samples.min(usize::MAX as f64) as usize,
            });
        }
        let m = frames as usize;
        let mut rotations = Vec::with_capacity(m * nj);
        let mut translations = Vec::with_capacity(m * nj);
        for k in 0..m {
            let s = k as f64 * step / dt;
            let i = (s as usize).min(self.n_frames - 1);
            let a = (s - i as f64) as f32;
            let i1 = (i + 1).min(self.n_frames - 1);
            for j in 0..nj {
                let (q0, q1) = (self.rotations[i * nj + j], self.rotations[i1 * nj + j]);
                rotations.push(if a == 0.0 { q0 } else { q0.slerp(q1, a).normalize() });
                translations.push(self.translations[i * nj + j].lerp(self.translations[i1 * nj + j], a));
            }
        }
        Clip::new(self.joints.clone(), step as f32, rotations, translations)
    }

    /// Sum of the rest offsets of `names` (e.g. thigh and shin), clip units; `None` if one is
    /// missing.
    pub fn chain_length(&self, names: &[&str]) -> Option<f32> {
        names.iter().map(|n| self.find(n).map(|j| Vec3::from(self.joints[j].offset).length())).sum()
    }
}

/// What counts as the clip's rest, against which per-frame rotations are measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ClipRest {
    /// A frame of the clip (the CMU clips start with a T-pose calibration frame 0).
    Frame(usize),
    /// All rotations zero, root at its frame-0 position (e.g. the AMP clips, arms down).
    ZeroRotations,
}

/// How to retarget a clip onto a rig.
///
/// Built from [`Default`] and the `with_` methods (new fields may come, so it has no struct
/// literal outside this crate).
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct RetargetOptions<'a> {
    /// The clip's rest.
    pub clip_rest: ClipRest,
    /// Local rotations (one per rig bone, as [`Skeleton::forward_kinematics`] takes them) that
    /// bring the rig's rest pose near the clip's rest (e.g. the MakeHuman A-pose to T-pose).
    /// `None`: the rig's rest pose as is.
    pub rig_initial: Option<&'a [Quat]>,
    /// `(rig bone, clip joint)` pairs overriding the same-name match; an empty clip joint name
    /// leaves the rig bone undriven (it keeps its initial pose relative to its parent).
    pub aliases: &'a [(&'a str, &'a str)],
    /// Leg chain (thigh, shin, foot) whose length ratio scales the root translation.
    pub leg: [&'a str; 3],
    /// Left and right thigh names: they give the facing direction (left x up).
    pub hips: [&'a str; 2],
    /// Driven bones whose direction is *not* aligned with the clip's rest: bones inside the
    /// pelvis whose rest direction reflects the capture skeleton's build rather than a pose
    /// (aligning CMU's hip joints would drop the MakeHuman legs by 4 cm).
    pub keep_direction: &'a [&'a str],
}

impl Default for RetargetOptions<'_> {
    fn default() -> Self {
        RetargetOptions {
            clip_rest: ClipRest::Frame(0),
            rig_initial: None,
            aliases: &[],
            leg: ["LeftUpLeg", "LeftLeg", "LeftFoot"],
            hips: ["LeftUpLeg", "RightUpLeg"],
            keep_direction: &["LHipJoint", "RHipJoint"],
        }
    }
}

impl<'a> RetargetOptions<'a> {
    with_fields! {
        /// Sets [`clip_rest`](Self::clip_rest): the clip's rest.
        with_clip_rest => clip_rest: ClipRest;
        /// Sets [`rig_initial`](Self::rig_initial): the rig's initial local rotations (`None`: its rest).
        with_rig_initial => rig_initial: Option<&'a [Quat]>;
        /// Sets [`aliases`](Self::aliases): `(rig bone, clip joint)` overrides.
        with_aliases => aliases: &'a [(&'a str, &'a str)];
        /// Sets [`leg`](Self::leg): the leg chain (thigh, shin, foot).
        with_leg => leg: [&'a str; 3];
        /// Sets [`hips`](Self::hips): the left and right thigh names.
        with_hips => hips: [&'a str; 2];
        /// Sets [`keep_direction`](Self::keep_direction): bones whose rest direction is kept.
        with_keep_direction => keep_direction: &'a [&'a str];
    }
}

/// A prepared mapping from one clip to one rig (see the module docs for the method).
#[derive(Clone, Debug)]
pub struct Retarget {
    /// Clip joint driving each rig bone.
    driver: Vec<Option<usize>>,
    /// World rotation of each rig bone at the clip's rest.
    align: Vec<Quat>,
    /// Inverse world rotation of each clip joint at the clip's rest.
    clip_rest_inv: Vec<Quat>,
    /// Clip root position at the rest, clip units.
    clip_root_rest: Vec3,
    /// Rig units per clip unit (leg-length ratio).
    scale: f32,
    root_joint: usize,
    scratch_rot: Vec<Quat>,
    scratch_pos: Vec<Vec3>,
    world: Vec<Quat>,
}

fn horizontal(v: Vec3) -> Vec3 {
    Vec3::new(v.x, 0.0, v.z).normalize_or(Vec3::Z)
}

impl Retarget {
    /// Prepares the mapping.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] when the rest frame is past the clip's end, a leg or hip name is
    /// missing from the rig or the clip, or no rig bone matches a clip joint;
    /// [`Error::SizeMismatch`] for initial rotations of the wrong length.
    pub fn new(skel: &Skeleton, clip: &Clip, opts: &RetargetOptions) -> Result<Retarget> {
        let nj = clip.joints.len();
        let nb = skel.len();
        // Clip rest.
        let mut rest_rot = vec![Quat::IDENTITY; nj];
        let mut rest_pos = vec![Vec3::ZERO; nj];
        match opts.clip_rest {
            ClipRest::Frame(f) => {
                if f >= clip.n_frames {
                    return Err(Error::OutOfRange { what: "clip rest frame", index: f });
                }
                clip.world(f, &mut rest_rot, &mut rest_pos);
            }
            ClipRest::ZeroRotations => {
                let zero = vec![Quat::IDENTITY; nj];
                clip.world_from_local(&zero, clip.translations(0), &mut rest_rot, &mut rest_pos);
            }
        }
        // Rig initial pose.
        let mut init = Pose::rest(skel);
        if let Some(local) = opts.rig_initial {
            skel.forward_kinematics(local, [0.0; 3], &mut init)?;
        }
        // Drivers.
        let mut driver = vec![None; nb];
        for (b, bone) in skel.bones().iter().enumerate() {
            let name = opts.aliases.iter().find(|(r, _)| *r == bone.name).map_or(bone.name.as_str(), |(_, c)| *c);
            driver[b] = if name.is_empty() { None } else { clip.find(name) };
        }
        if driver.iter().all(Option::is_none) {
            return Err(Error::OutOfRange { what: "no rig bone matches a clip joint", index: 0 });
        }
        let root_joint = (0..nj).find(|&j| clip.joints[j].parent.is_none()).unwrap_or(0);
        // Facing (heading) alignment: rig's left x up onto the clip's.
        let find_both = |name: &str| -> Result<(usize, usize)> {
            match (skel.find(name), clip.find(name)) {
                (Some(b), Some(j)) => Ok((b, j)),
                _ => Err(Error::OutOfRange { what: "retarget bone missing from rig or clip", index: 0 }),
            }
        };
        let (lb, lj) = find_both(opts.hips[0])?;
        let (rb, rj) = find_both(opts.hips[1])?;
        let rig_facing = horizontal((init.head[lb] - init.head[rb]).cross(Vec3::Y));
        let clip_facing = horizontal((rest_pos[lj] - rest_pos[rj]).cross(Vec3::Y));
        let yaw = Quat::from_rotation_arc(rig_facing, clip_facing);
        // Per-bone alignment.
        let mut align = vec![Quat::IDENTITY; nb];
        for (b, bone) in skel.bones().iter().enumerate() {
            let base = (yaw * init.rotation[b]).normalize();
            align[b] = base;
            let Some(j) = driver[b] else { continue };
            if opts.keep_direction.contains(&bone.name.as_str()) {
                continue;
            }
            // Best direction pair: a rig child driven by a clip child of j, longest rig offset.
            let mut pair: Option<(Vec3, Vec3)> = None;
            for c in skel.children(b) {
                let Some(k) = driver[c] else { continue };
                if clip.joints[k].parent != Some(j) {
                    continue;
                }
                let v_rig = skel.bones()[c].head - bone.head;
                let v_clip = rest_rot[j] * Vec3::from(clip.joints[k].offset);
                if v_clip.length() > 1e-6 && v_rig.length() > pair.map_or(1e-6, |p| p.0.length()) {
                    pair = Some((v_rig, v_clip));
                }
            }
            if pair.is_none() && bone.length() > 1e-6 {
                let kids: Vec<usize> = (0..nj).filter(|&k| clip.joints[k].parent == Some(j)).collect();
                let far = match (clip.joints[j].end_site, kids.as_slice()) {
                    (Some(e), []) => Some(Vec3::from(e)),
                    (None, [k]) => Some(Vec3::from(clip.joints[*k].offset)),
                    _ => None,
                };
                if let Some(far) = far.filter(|f| f.length() > 1e-6) {
                    pair = Some((bone.tail - bone.head, rest_rot[j] * far));
                }
            }
            if let Some((v_rig, v_clip)) = pair {
                let from = (base * v_rig).normalize();
                align[b] = (Quat::from_rotation_arc(from, v_clip.normalize()) * base).normalize();
            }
        }
        // Leg-length ratio.
        let rig_leg = {
            let ids: Vec<usize> = opts.leg.iter().map(|n| find_both(n).map(|x| x.0)).collect::<Result<_>>()?;
            (skel.bones()[ids[1]].head - skel.bones()[ids[0]].head).length()
                + (skel.bones()[ids[2]].head - skel.bones()[ids[1]].head).length()
        };
        let clip_leg = clip.chain_length(&opts.leg[1..]).unwrap_or(0.0);
        if clip_leg.is_nan() || clip_leg <= 0.0 {
            return Err(Error::OutOfRange { what: "clip leg length", index: 0 });
        }
        Ok(Retarget {
            driver,
            align,
            clip_rest_inv: rest_rot.iter().map(|q| q.conjugate()).collect(),
            clip_root_rest: rest_pos[root_joint],
            scale: rig_leg / clip_leg,
            root_joint,
            scratch_rot: vec![Quat::IDENTITY; nj],
            scratch_pos: vec![Vec3::ZERO; nj],
            world: vec![Quat::IDENTITY; nb],
        })
    }

    /// Rig units per clip unit.
    pub fn scale(&self) -> f32 {
        self.scale
    }

    /// Poses the rig at frame `f` of `clip` into `out` (no allocation).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a frame past the end; [`Error::SizeMismatch`] for a clip or
    /// skeleton other than the ones given to [`Retarget::new`].
    pub fn pose(&mut self, skel: &Skeleton, clip: &Clip, f: usize, out: &mut Pose) -> Result<()> {
        if f >= clip.n_frames {
            return Err(Error::OutOfRange { what: "clip frame", index: f });
        }
        if clip.joints.len() != self.scratch_rot.len() || skel.len() != self.world.len() {
            return Err(Error::SizeMismatch {
                what: "retarget clip/skeleton",
                expected: self.world.len(),
                got: skel.len(),
            });
        }
        clip.world(f, &mut self.scratch_rot, &mut self.scratch_pos);
        for (b, bone) in skel.bones().iter().enumerate() {
            self.world[b] = match (self.driver[b], bone.parent) {
                (Some(j), _) => (self.scratch_rot[j] * self.clip_rest_inv[j] * self.align[b]).normalize(),
                (None, Some(p)) => (self.world[p] * self.align[p].conjugate() * self.align[b]).normalize(),
                (None, None) => self.align[b],
            };
        }
        let t = (self.scratch_pos[self.root_joint] - self.clip_root_rest) * self.scale;
        skel.pose_from_world(&self.world, t.into(), out)
    }
}

/// Body vertex positions per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyMotion {
    /// Frames per second.
    pub fps: f32,
    /// Vertices per frame.
    pub n_vertices: usize,
    /// `frames x n_vertices` positions, frame major.
    pub positions: Vec<[f32; 3]>,
}

impl BodyMotion {
    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.positions.len() / self.n_vertices.max(1)
    }
    /// Positions of frame `f`.
    pub fn frame(&self, f: usize) -> &[[f32; 3]] {
        &self.positions[f * self.n_vertices..(f + 1) * self.n_vertices]
    }
    /// Lowest y over all frames and vertices.
    pub fn min_y(&self) -> f32 {
        self.positions.iter().map(|p| p[1]).fold(f32::INFINITY, f32::min)
    }
    /// Moves every frame by `dy` along y (a per-clip floor correction).
    pub fn shift_y(&mut self, dy: f32) {
        for p in &mut self.positions {
            p[1] += dy;
        }
    }

    /// `rest` skinned with `weights` at each of `poses`, `fps` frames per second.
    ///
    /// # Errors
    /// Errors of [`SkinTransforms::update`] and [`skin`] (sizes that disagree).
    pub fn skinned(
        skel: &Skeleton,
        weights: &SkinWeights,
        rest: &[[f32; 3]],
        poses: &[Pose],
        fps: f32,
    ) -> Result<BodyMotion> {
        let n = rest.len();
        let mut positions = vec![[0.0f32; 3]; n * poses.len()];
        let mut tr = SkinTransforms::new(skel.len());
        for (pose, out) in poses.iter().zip(positions.chunks_exact_mut(n.max(1))) {
            tr.update(skel, pose)?;
            skin(&tr, weights, rest, out)?;
        }
        Ok(BodyMotion { fps, n_vertices: n, positions })
    }
}

/// Skins `rest` (with `weights`, in the rig's units) at every frame of `clip` retargeted by
/// `retarget` into a [`BodyMotion`] at the clip's frame rate.
pub fn animate(
    skel: &Skeleton,
    weights: &SkinWeights,
    rest: &[[f32; 3]],
    clip: &Clip,
    retarget: &mut Retarget,
) -> Result<BodyMotion> {
    let n = rest.len();
    let mut positions = vec![[0.0f32; 3]; n * clip.n_frames()];
    let mut pose = Pose::rest(skel);
    let mut tr = SkinTransforms::new(skel.len());
    for f in 0..clip.n_frames() {
        retarget.pose(skel, clip, f, &mut pose)?;
        tr.update(skel, &pose)?;
        skin(&tr, weights, rest, &mut positions[f * n..(f + 1) * n])?;
    }
    Ok(BodyMotion { fps: 1.0 / clip.frame_time(), n_vertices: n, positions })
}
