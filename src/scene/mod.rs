//! Animated scenes (feature `tools`): a garment dressed on a skinned body that follows a motion at
//! the model's 30 Hz. One place builds them for the trainer's data, the workloads, `hood simulate`
//! and the evaluation: the procedural mannequin with the procedural garments and motions, and the
//! MakeHuman body with its garments on the CMU walk.
//!
//! The garment is skinned along with the body (weights diffused from the body's, MODEL.md
//! section 7): [`Scene::skinned_garment`] gives the pinned vertices' targets at every frame and,
//! pushed out of the body, the garment's initial state ([`Scene::initial_garment`]).

use crate::body::BodyMesh;
use crate::error::{Error, Result};
use crate::mesh::{Garment, GarmentDesc, Material};
use crate::rig::fit::{diffused_weights, pose_garment, DIFFUSION_SAMPLES};
use crate::rig::motion::BodyMotion;
use crate::rig::procedural::{self as proc_, LocalMotion, Mannequin};
use crate::rig::{Pose, Skeleton, SkinWeights};
use crate::solve::push_out_of;
use alloc::string::String;
use alloc::vec;
use alloc::vec::Vec;

/// Voxel edge of the weight diffusion, m.
const DIFFUSION_VOXEL: f32 = 0.01;

/// The procedural garments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GarmentKind {
    /// A skirt, waist pinned.
    Skirt,
    /// A long dress hanging from the shoulders (its top ring pinned).
    Dress,
    /// A cape, shoulders pinned.
    Cape,
}

impl GarmentKind {
    /// Every kind.
    pub const ALL: [GarmentKind; 3] = [GarmentKind::Skirt, GarmentKind::Dress, GarmentKind::Cape];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            GarmentKind::Skirt => "skirt",
            GarmentKind::Dress => "dress",
            GarmentKind::Cape => "cape",
        }
    }

    /// The kind called `name`.
    pub fn parse(name: &str) -> Option<GarmentKind> {
        GarmentKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// The procedural motions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionKind {
    /// A walk cycle moving forward.
    Walk,
    /// A run.
    Run,
    /// Jumps on the spot.
    Jump,
    /// Turning on the spot.
    Turn,
    /// Arm swings.
    ArmSwings,
    /// Random smooth poses within joint limits, from a seed.
    RandomPoses(u64),
    /// A clip of the motion corpus: a family and the seed of its draws (`jumps-3`, `dance-1001`).
    Corpus(proc_::Family, u64),
    /// A motion-capture clip of `../shared/assets/motions`, retargeted onto the MakeHuman rig
    /// (MakeHuman scenes only).
    Mocap(MocapClip),
}

/// The AMP humanoid's motion-capture clips in `assets/motions` (BSD-3; CMU takes 07_01, 09_11
/// and the AMP back flip): 15 joints, rest pose with the arms hanging down, 30 Hz (the back flip
/// 16 Hz, resampled).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MocapClip {
    /// `amp_walk.bvh`: a walk at about 1.5 m/s, 77 frames.
    AmpWalk,
    /// `amp_run.bvh`: a run at about 3.4 m/s, 41 frames.
    AmpRun,
    /// `amp_backflip.bvh`: a standing back flip, 29 frames at 16 Hz (held out: validation only).
    AmpBackflip,
}

impl MocapClip {
    /// Every clip.
    pub const ALL: [MocapClip; 3] = [MocapClip::AmpWalk, MocapClip::AmpRun, MocapClip::AmpBackflip];

    /// Name as motions are named (`amp-walk`, `amp-run`, `amp-backflip`).
    pub fn name(self) -> &'static str {
        match self {
            MocapClip::AmpWalk => "amp-walk",
            MocapClip::AmpRun => "amp-run",
            MocapClip::AmpBackflip => "amp-backflip",
        }
    }

    /// File name in `assets/motions`.
    pub fn file(self) -> &'static str {
        match self {
            MocapClip::AmpWalk => "amp_walk.bvh",
            MocapClip::AmpRun => "amp_run.bvh",
            MocapClip::AmpBackflip => "amp_backflip.bvh",
        }
    }
}

impl MotionKind {
    /// Lower-case name (random poses as `random-<seed>`).
    pub fn name(self) -> String {
        match self {
            MotionKind::Walk => "walk".into(),
            MotionKind::Run => "run".into(),
            MotionKind::Jump => "jump".into(),
            MotionKind::Turn => "turn".into(),
            MotionKind::ArmSwings => "arm-swings".into(),
            MotionKind::RandomPoses(s) => alloc::format!("random-{s}"),
            MotionKind::Corpus(f, s) => alloc::format!("{}-{s}", f.name()),
            MotionKind::Mocap(c) => c.name().into(),
        }
    }

    /// The kind called `name` (see [`name`](Self::name)).
    pub fn parse(name: &str) -> Option<MotionKind> {
        Some(match name {
            "walk" => MotionKind::Walk,
            "run" => MotionKind::Run,
            "jump" => MotionKind::Jump,
            "turn" => MotionKind::Turn,
            "arm-swings" => MotionKind::ArmSwings,
            _ if name.starts_with("amp-") => MotionKind::Mocap(MocapClip::ALL.into_iter().find(|c| c.name() == name)?),
            _ => {
                let (family, seed) = name.rsplit_once('-')?;
                let seed = seed.parse().ok()?;
                match family {
                    "random" => MotionKind::RandomPoses(seed),
                    _ => MotionKind::Corpus(proc_::Family::parse(family)?, seed),
                }
            }
        })
    }

    /// Whether the motion belongs to the held-out split of the motion corpus (validation only):
    /// corpus clips and random poses with a seed from [`proc_::HELD_OUT_SEEDS`] on, and the
    /// back-flip family.
    pub fn is_held_out(self) -> bool {
        match self {
            MotionKind::Corpus(f, s) => proc_::is_held_out(f, s),
            MotionKind::RandomPoses(s) => s >= proc_::HELD_OUT_SEEDS,
            MotionKind::Mocap(c) => c == MocapClip::AmpBackflip,
            _ => false,
        }
    }

    /// The motion on `skel` (any rig with the CMU bone names), `seconds` long at 30 Hz.
    ///
    /// # Errors
    /// Errors of the motion generators; [`Error::UnsupportedEffect`] for a motion-capture clip
    /// (it needs the assets: [`makehuman_on`]).
    pub fn local(self, skel: &Skeleton, seconds: f32) -> Result<LocalMotion> {
        match self {
            MotionKind::Walk => proc_::walk(skel, seconds),
            MotionKind::Run => proc_::run(skel, seconds),
            MotionKind::Jump => proc_::jump(skel, seconds),
            MotionKind::Turn => proc_::turn_on_the_spot(skel, seconds),
            MotionKind::ArmSwings => proc_::arm_swings(skel, seconds),
            MotionKind::RandomPoses(seed) => proc_::random_poses(skel, seconds, seed),
            MotionKind::Corpus(family, seed) => proc_::family_motion(skel, family, seconds, seed),
            MotionKind::Mocap(_) => Err(Error::UnsupportedEffect {
                effect: "a motion-capture clip on the procedural mannequin (MakeHuman only)",
            }),
        }
    }
}

/// A garment on an animated body, frames at 30 Hz, metres.
#[derive(Clone, Debug)]
pub struct Scene {
    /// What it shows ("dress on walk", ...).
    pub name: String,
    /// The garment (rest shape, pinned flags, default materials).
    pub garment: Garment,
    /// Body topology.
    pub body: BodyMesh,
    /// Body positions per frame.
    pub motion: BodyMotion,
    skeleton: Skeleton,
    poses: Vec<Pose>,
    garment_weights: SkinWeights,
}

impl Scene {
    /// Assembles a scene from a rigged body, its per-frame poses and a garment fitted to the
    /// body's rest shape (its skinning weights are diffused from the body's).
    ///
    /// # Errors
    /// [`Error::Empty`] without frames; [`Error::SizeMismatch`] when the motion's frame count or
    /// vertex count disagrees with `poses` or `body`; errors of the weight diffusion.
    #[allow(clippy::too_many_arguments)] // the parts of a scene
    pub fn new(
        name: String,
        garment: Garment,
        body: BodyMesh,
        body_rest: &[[f32; 3]],
        body_weights: &SkinWeights,
        skeleton: Skeleton,
        poses: Vec<Pose>,
        motion: BodyMotion,
    ) -> Result<Scene> {
        if poses.is_empty() {
            return Err(Error::Empty { what: "scene frames" });
        }
        if motion.n_frames() != poses.len() {
            return Err(Error::SizeMismatch { what: "motion frames", expected: poses.len(), got: motion.n_frames() });
        }
        if motion.n_vertices != body.n_vertices() || body_rest.len() != body.n_vertices() {
            return Err(Error::SizeMismatch {
                what: "body vertices",
                expected: body.n_vertices(),
                got: motion.n_vertices,
            });
        }
        let garment_weights =
            diffused_weights(garment.rest(), body_rest, body_weights, DIFFUSION_SAMPLES, DIFFUSION_VOXEL, 1)?;
        Ok(Scene { name, garment, body, motion, skeleton, poses, garment_weights })
    }

    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.poses.len()
    }

    /// Body positions at frame `f` (clamped to the last frame), m.
    pub fn body_frame(&self, f: usize) -> &[[f32; 3]] {
        self.motion.frame(f.min(self.n_frames() - 1))
    }

    /// The garment's rest shape skinned to frame `f` (clamped to the last frame) into `out`: the
    /// pinned vertices' targets.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `out` is not one entry per garment vertex.
    pub fn skinned_garment(&self, f: usize, out: &mut [[f32; 3]]) -> Result<()> {
        let pose = &self.poses[f.min(self.n_frames() - 1)];
        pose_garment(&self.skeleton, pose, &self.garment_weights, self.garment.rest(), out)
    }

    /// The garment at frame `f`: skinned, then every unpinned vertex closer than
    /// [`INITIAL_CLEARANCE`](crate::solve::INITIAL_CLEARANCE) to (or behind) its nearest body
    /// face pushed out along that face's normal ([`push_out_of`]).
    ///
    /// # Errors
    /// Errors of the body queries.
    pub fn initial_garment(&self, f: usize) -> Result<Vec<[f32; 3]>> {
        let mut x = vec![[0.0; 3]; self.garment.n_vertices()];
        self.skinned_garment(f, &mut x)?;
        push_out_of(&self.body, self.body_frame(f), &mut x, self.garment.pinned())?;
        Ok(x)
    }

    /// The garment's velocity at frame `f`, m per frame: the displacement of its skinned shape
    /// into frame `f` (at frame 0, out of it; zero for a one-frame scene). A clip that starts in
    /// mid-motion (a run, a hop) thus starts its garment moving with the body, not at rest while
    /// the body runs into it.
    ///
    /// # Errors
    /// Errors of the skinning.
    pub fn initial_velocity(&self, f: usize) -> Result<Vec<[f32; 3]>> {
        let n = self.garment.n_vertices();
        let last = self.n_frames() - 1;
        let f = f.min(last);
        if last == 0 {
            return Ok(vec![[0.0; 3]; n]);
        }
        let (from, to) = if f == 0 { (0, 1) } else { (f - 1, f) };
        let mut a = vec![[0.0; 3]; n];
        let mut b = vec![[0.0; 3]; n];
        self.skinned_garment(from, &mut a)?;
        self.skinned_garment(to, &mut b)?;
        Ok(b.iter().zip(&a).map(|(b, a)| crate::math::sub3(*b, *a)).collect())
    }

    /// The scene's garment with every vertex made of `material` (same rest shape and pins, so
    /// the same hierarchy: only masses and the network's material inputs change).
    ///
    /// # Errors
    /// Errors of [`Garment::new`].
    pub fn garment_with_material(&self, material: Material) -> Result<Garment> {
        let g = &self.garment;
        let materials = vec![material; g.n_vertices()];
        Garment::new(GarmentDesc::new(g.rest(), g.faces()).pinned(g.pinned()).materials(&materials))
    }
}

/// Local rotations (as [`Skeleton::forward_kinematics`] takes them) that turn the upper arms of
/// a rig with the CMU bone names from its rest to hanging straight down (-y): the rest of the AMP
/// clips. Every other bone stays at rest.
fn arms_hanging_down(skel: &Skeleton) -> Vec<glam::Quat> {
    let mut local = vec![glam::Quat::IDENTITY; skel.len()];
    for name in ["LeftArm", "RightArm"] {
        if let Some(b) = skel.find(name) {
            let bone = &skel.bones()[b];
            let along = (bone.tail - bone.head).normalize_or_zero();
            // With its parents at rest the world rotation is the bone-frame rotation conjugated.
            let world = glam::Quat::from_rotation_arc(along, -glam::Vec3::Y);
            local[b] = bone.frame.conjugate() * world * bone.frame;
        }
    }
    local
}

/// A procedural scene: `garment` (about `vertices` vertices, its suggested pins set) on the
/// `mannequin` doing `motion` for `seconds` at 30 Hz.
///
/// # Errors
/// Errors of the garment and motion generators and of the weight diffusion.
pub fn procedural(
    mannequin: &Mannequin,
    garment: GarmentKind,
    vertices: usize,
    motion: MotionKind,
    seconds: f32,
) -> Result<Scene> {
    let pg = match garment {
        GarmentKind::Skirt => proc_::skirt(mannequin, vertices)?,
        GarmentKind::Dress => proc_::long_dress(mannequin, vertices)?,
        GarmentKind::Cape => proc_::cape(mannequin, vertices)?,
    };
    let g = pg.garment(true)?;
    let skel = mannequin.skeleton().clone();
    let local = motion.local(&skel, seconds)?;
    let mut poses = Vec::with_capacity(local.n_frames());
    for f in 0..local.n_frames() {
        let mut p = Pose::rest(&skel);
        local.pose(&skel, f, &mut p)?;
        poses.push(p);
    }
    let body_motion = local.animate(&skel, mannequin.weights(), mannequin.rest())?;
    let body = BodyMesh::new(mannequin.rest().len(), mannequin.faces())?;
    let name = alloc::format!("{} on {}", garment.name(), motion.name());
    Scene::new(name, g, body, mannequin.rest(), mannequin.weights(), skel, poses, body_motion)
}

pub use makehuman::{
    cmu_retarget, makehuman, makehuman_on, makehuman_on_bvh, makehuman_wearing, BvhRest, MakeHumanGarment,
    MakeHumanMotion, Wearing,
};

mod gltf;
mod makehuman;
pub mod own;
pub use gltf::gltf_wearing;
