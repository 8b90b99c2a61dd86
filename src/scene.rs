//! Animated scenes: a garment dressed on a skinned body that follows a motion at the model's
//! 30 Hz. One place builds them for the trainer's data, the workloads, `hood simulate` and the
//! evaluation: the procedural mannequin with the procedural garments and motions, and (under
//! `std`) the MakeHuman body with its garments on the CMU walk.
//!
//! The garment is skinned along with the body (weights diffused from the body's, MODEL.md
//! section 7): [`Scene::skinned_garment`] gives the pinned vertices' targets at every frame and,
//! pushed out of the body, the garment's initial state ([`Scene::initial_garment`]).

use crate::body::{BodyFrame, BodyMesh, Nearest};
use crate::error::{Error, Result};
use crate::mesh::{Garment, GarmentDesc, Material};
use crate::physics::FaceFrame;
use crate::rig::fit::{diffused_weights, pose_garment, DIFFUSION_SAMPLES};
use crate::rig::motion::BodyMotion;
use crate::rig::procedural::{self as proc_, LocalMotion, Mannequin};
use crate::rig::{Pose, Skeleton, SkinWeights};
use crate::solve::push_out;
use alloc::string::String;
use alloc::vec;
use alloc::vec::Vec;

/// Clearance the initial garment keeps from the body (MODEL.md section 7), m.
pub const INITIAL_CLEARANCE: f32 = 2e-3;

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
    /// [`INITIAL_CLEARANCE`] to (or behind) its nearest body face pushed out along that face's
    /// normal.
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

/// Pushes the unpinned vertices of `x` at least [`INITIAL_CLEARANCE`] out of the body at
/// `body_pos`, along the normal of the face whose centroid is nearest.
///
/// # Errors
/// Errors of the body queries.
pub fn push_out_of(body: &BodyMesh, body_pos: &[[f32; 3]], x: &mut [[f32; 3]], pinned: &[bool]) -> Result<usize> {
    let mut frame = BodyFrame::new(body)?;
    frame.update(body, body_pos)?;
    let mut near = vec![Nearest { index: 0, distance: 0.0 }; x.len()];
    frame.nearest_faces(x, &mut near)?;
    let idx: Vec<u32> = near.iter().map(|n| n.index).collect();
    let ff = FaceFrame { centroids: frame.centroids(), normals: frame.face_normals() };
    push_out(x, &idx, ff, INITIAL_CLEARANCE, pinned)
}

/// Local rotations (as [`Skeleton::forward_kinematics`] takes them) that turn the upper arms of
/// a rig with the CMU bone names from its rest to hanging straight down (-y): the rest of the AMP
/// clips. Every other bone stays at rest.
#[cfg(feature = "std")]
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

#[cfg(feature = "std")]
pub use assets::{makehuman, makehuman_on, makehuman_on_bvh, BvhRest, MakeHumanGarment};

#[cfg(feature = "std")]
mod assets {
    use super::*;
    use crate::io::bvh;
    use crate::io::makehuman::{MakeHuman, METRES_PER_UNIT};
    use crate::io::obj::{split_components, Obj};
    use crate::rig::fit::{boundary_loop_pins, pinned_flags, LoopChoice, MhcloBinding};
    use crate::rig::motion::{ClipRest, Retarget, RetargetOptions, MODEL_FPS};
    use std::path::Path;

    /// The MakeHuman garments of the assets: the pieces of the three outfits of
    /// `assets/garments` (README there). Tops hang free; trousers and leggings have their waist
    /// pinned.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum MakeHumanGarment {
        /// The t-shirt of `female_casualsuit01`, 1,311 vertices.
        Tee,
        /// The jeans of `female_casualsuit01`, 886 vertices.
        Jeans,
        /// The crop top of `female_sportsuit01`, 911 vertices.
        CropTop,
        /// The leggings of `female_sportsuit01`, 886 vertices.
        Leggings,
        /// The tee of `male_casualsuit04` (fitted to the same body), 810 vertices: held out from
        /// training, for validation on a garment no model has seen.
        MaleTee,
        /// The jeans of `male_casualsuit04`, 886 vertices: held out like [`MakeHumanGarment::MaleTee`].
        MaleJeans,
    }

    impl MakeHumanGarment {
        /// Every piece.
        pub const ALL: [MakeHumanGarment; 6] = [
            MakeHumanGarment::Tee,
            MakeHumanGarment::Jeans,
            MakeHumanGarment::CropTop,
            MakeHumanGarment::Leggings,
            MakeHumanGarment::MaleTee,
            MakeHumanGarment::MaleJeans,
        ];

        /// The name used on the command line and in training configs (`tee`, `jeans`,
        /// `crop-top`, `leggings`, `male-tee`, `male-jeans`).
        pub fn name(self) -> &'static str {
            match self {
                MakeHumanGarment::Tee => "tee",
                MakeHumanGarment::Jeans => "jeans",
                MakeHumanGarment::CropTop => "crop-top",
                MakeHumanGarment::Leggings => "leggings",
                MakeHumanGarment::MaleTee => "male-tee",
                MakeHumanGarment::MaleJeans => "male-jeans",
            }
        }

        /// The piece named `name` (see [`MakeHumanGarment::name`]).
        pub fn parse(name: &str) -> Option<MakeHumanGarment> {
            MakeHumanGarment::ALL.into_iter().find(|g| g.name() == name)
        }

        /// Whether the piece is held out from training (the garment split: validation only).
        pub fn is_held_out(self) -> bool {
            matches!(self, MakeHumanGarment::MaleTee | MakeHumanGarment::MaleJeans)
        }

        /// Whether its waist is pinned (the lower pieces).
        pub fn pinned_waist(self) -> bool {
            matches!(self, MakeHumanGarment::Jeans | MakeHumanGarment::Leggings | MakeHumanGarment::MaleJeans)
        }

        /// The outfit file (stem in `assets/garments`) and the piece's rank from the top (0: the
        /// upper piece).
        fn source(self) -> (&'static str, usize) {
            match self {
                MakeHumanGarment::Tee => ("female_casualsuit01", 0),
                MakeHumanGarment::Jeans => ("female_casualsuit01", 1),
                MakeHumanGarment::CropTop => ("female_sportsuit01", 0),
                MakeHumanGarment::Leggings => ("female_sportsuit01", 1),
                MakeHumanGarment::MaleTee => ("male_casualsuit04", 0),
                MakeHumanGarment::MaleJeans => ("male_casualsuit04", 1),
            }
        }

        /// What it is, for scene names.
        fn description(self) -> &'static str {
            match self {
                MakeHumanGarment::Tee => "t-shirt",
                MakeHumanGarment::Jeans => "jeans",
                MakeHumanGarment::CropTop => "crop top",
                MakeHumanGarment::Leggings => "leggings",
                MakeHumanGarment::MaleTee => "men's tee",
                MakeHumanGarment::MaleJeans => "men's jeans",
            }
        }
    }

    /// The MakeHuman body (`assets/body`) wearing `which` (fitted with its `.mhclo` binding,
    /// outside the body) on the CMU 12_03 walk retargeted at 30 Hz, at most `max_frames` frames.
    ///
    /// # Errors
    /// [`Error::Io`] when the assets are absent; parse and fitting errors.
    pub fn makehuman(assets: &Path, which: MakeHumanGarment, max_frames: usize) -> Result<Scene> {
        makehuman_on(assets, which, None, max_frames)
    }

    /// The CMU finger names as the MakeHuman rig spells them.
    const CMU_FINGERS: &[(&str, &str)] =
        &[("LeftHandFinger1", "LeftHandIndex1"), ("RightHandFinger1", "RightHandIndex1")];

    /// `poses` lifted onto the floor: clips put their lowest joint (often an ankle) at y = 0,
    /// which sinks the feet, and some rise over a take (the AMP walk's root by 8 cm). Each frame
    /// goes onto the line through the lowest body vertex of each half of the clip (a stance in
    /// any clip that starts and ends on its feet), so that the soles sit where the rest pose's do.
    fn lifted_onto_the_floor(mh: &MakeHuman, mut poses: Vec<Pose>) -> Result<Vec<Pose>> {
        let nb = mh.body.rest.len();
        let rest_low = mh.body.rest.iter().map(|v| v[1]).fold(f32::INFINITY, f32::min);
        let mut lows = Vec::with_capacity(poses.len());
        let mut tr = crate::rig::SkinTransforms::new(mh.skeleton.len());
        let mut buf = vec![[0.0; 3]; nb];
        for pose in &poses {
            tr.update(&mh.skeleton, pose)?;
            crate::rig::skin(&tr, &mh.body_weights, &mh.body.rest, &mut buf)?;
            lows.push(buf.iter().map(|v| v[1]).fold(f32::INFINITY, f32::min));
        }
        let n = poses.len();
        let lowest = |r: core::ops::Range<usize>| r.min_by(|&a, &b| lows[a].total_cmp(&lows[b])).unwrap_or(0);
        let (f1, f2) = (lowest(0..n / 2), lowest(n / 2..n));
        let slope = if f2 > f1 { (lows[f2] - lows[f1]) / (f2 - f1) as f32 } else { 0.0 };
        for (f, pose) in poses.iter_mut().enumerate() {
            let lift = rest_low - (lows[f1] + slope * (f as f32 - f1 as f32));
            pose.head.iter_mut().for_each(|h| h.y += lift);
        }
        Ok(poses)
    }

    /// [`makehuman`] on `motion` instead of the CMU walk when given: a procedural motion or a
    /// clip of the motion corpus, posed on the MakeHuman rig directly (it has the CMU bone
    /// names), `max_frames` frames long.
    ///
    /// # Errors
    /// As [`makehuman`], and errors of the motion generators.
    pub fn makehuman_on(
        assets: &Path,
        which: MakeHumanGarment,
        motion: Option<MotionKind>,
        max_frames: usize,
    ) -> Result<Scene> {
        let source = match motion {
            None => Source::CmuWalk,
            Some(MotionKind::Mocap(clip)) => {
                Source::Bvh(assets.join("motions").join(clip.file()), BvhRest::ZeroArmsDown)
            }
            Some(kind) => Source::Procedural(kind),
        };
        let name = motion.map_or_else(|| "CMU walk".into(), |m| m.name());
        makehuman_from(assets, which, source, &name, max_frames)
    }

    /// [`makehuman`] on a BVH clip of the user's (any frame rate: resampled to 30 Hz), retargeted
    /// onto the MakeHuman rig by bone name (the CMU / MotionBuilder names: `Hips`, `Spine`,
    /// `LeftUpLeg`, `LeftArm`, ...; joints the rig lacks are ignored, bones the clip lacks stay
    /// at rest relative to their parents), the root translation scaled by the ratio of leg
    /// lengths (so the clip's length unit does not matter), each frame lifted onto the floor as
    /// [`MocapClip`]s are. `rest` says what the clip's rest is.
    ///
    /// # Errors
    /// As [`makehuman`]; BVH parse errors; [`Error::Empty`] when no clip joint matches a rig bone.
    pub fn makehuman_on_bvh(
        assets: &Path,
        which: MakeHumanGarment,
        bvh: &Path,
        rest: BvhRest,
        max_frames: usize,
    ) -> Result<Scene> {
        let name = bvh.file_stem().map_or_else(|| "a BVH clip".into(), |s| s.to_string_lossy().into_owned());
        makehuman_from(assets, which, Source::Bvh(bvh.to_path_buf(), rest), &name, max_frames)
    }

    /// Where a MakeHuman scene's motion comes from.
    enum Source {
        /// The CMU walk of the assets (frame 0 its T-pose calibration frame).
        CmuWalk,
        /// A procedural motion, posed on the rig directly.
        Procedural(MotionKind),
        /// A BVH file, retargeted.
        Bvh(std::path::PathBuf, BvhRest),
    }

    /// The rest of a BVH clip, which retargeting aligns the rig to.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum BvhRest {
        /// Frame 0 is a T-pose calibration frame (the CMU takes); the clip starts at frame 1.
        FirstFrameTPose,
        /// All rotations zero is a T-pose (Mixamo and many exporters).
        ZeroTPose,
        /// All rotations zero has the arms hanging down (the AMP humanoid).
        ZeroArmsDown,
    }

    impl BvhRest {
        /// Names as the command line takes them.
        pub const NAMES: [&'static str; 3] = ["first-frame-t-pose", "zero-t-pose", "zero-arms-down"];

        /// The rest called `name` (see [`BvhRest::NAMES`]).
        pub fn parse(name: &str) -> Option<BvhRest> {
            let all = [BvhRest::FirstFrameTPose, BvhRest::ZeroTPose, BvhRest::ZeroArmsDown];
            BvhRest::NAMES.iter().position(|&n| n == name).map(|i| all[i])
        }
    }

    fn makehuman_from(
        assets: &Path,
        which: MakeHumanGarment,
        source: Source,
        motion_name: &str,
        max_frames: usize,
    ) -> Result<Scene> {
        let mh = MakeHuman::load(assets.join("body"))?;
        let (outfit, rank) = which.source();
        let path = assets.join("garments").join(alloc::format!("{outfit}.mhclo"));
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let binding = MhcloBinding::parse(&text, METRES_PER_UNIT)?;
        let obj = Obj::read(assets.join("garments").join(&binding.obj_file))?;
        let mut normals = vec![[0.0; 3]; mh.obj.positions.len()];
        crate::mesh::vertex_normals(&mh.obj.triangles, &mh.obj.positions, &mut normals);
        let mut fitted = vec![[0.0; 3]; binding.vertices.len()];
        binding.fit_outside(&mh.obj.positions, &normals, &mh.obj.positions, &mut fitted)?;
        let mut pieces = split_components(&fitted, &obj.triangles)?;
        let mean_y = |p: &crate::mesh::repair::CompactedMesh| {
            p.rest.iter().map(|v| v[1] as f64).sum::<f64>() / p.rest.len().max(1) as f64
        };
        pieces.sort_by(|a, b| mean_y(b).total_cmp(&mean_y(a)));
        if pieces.len() != 2 {
            return Err(Error::parse("mhclo", 0, alloc::format!("{outfit}: expected an upper and a lower piece")));
        }
        let piece = &pieces[rank];
        let mut garment = Garment::new(GarmentDesc::new(&piece.rest, &piece.faces))?;
        if which.pinned_waist() {
            let waist = boundary_loop_pins(&garment, LoopChoice::Highest)?;
            garment.set_pinned(&pinned_flags(garment.n_vertices(), &waist)?)?;
        }
        let nb = mh.body.rest.len();
        let mut poses = Vec::new();
        let mut positions = Vec::new();
        let mut tr = crate::rig::SkinTransforms::new(mh.skeleton.len());
        let mut buf = vec![[0.0; 3]; nb];
        let mut push = |pose: Pose, poses: &mut Vec<Pose>, positions: &mut Vec<[f32; 3]>| -> Result<()> {
            tr.update(&mh.skeleton, &pose)?;
            crate::rig::skin(&tr, &mh.body_weights, &mh.body.rest, &mut buf)?;
            positions.extend_from_slice(&buf);
            poses.push(pose);
            Ok(())
        };
        match source {
            Source::Procedural(kind) => {
                let frames = max_frames.max(1);
                let local = kind.local(&mh.skeleton, (frames - 1).max(1) as f32 / MODEL_FPS)?;
                for f in 0..frames.min(local.n_frames()) {
                    let mut pose = Pose::rest(&mh.skeleton);
                    local.pose(&mh.skeleton, f, &mut pose)?;
                    push(pose, &mut poses, &mut positions)?;
                }
            }
            Source::CmuWalk => {
                let clip = bvh::read(assets.join("motions/cmu_12_03_walk.bvh"))?.resample(MODEL_FPS)?;
                let opts = RetargetOptions {
                    clip_rest: ClipRest::Frame(0),
                    rig_initial: Some(&mh.t_pose),
                    aliases: CMU_FINGERS,
                    ..Default::default()
                };
                let mut rt = Retarget::new(&mh.skeleton, &clip, &opts)?;
                // Frame 0 of the clip is its T-pose calibration frame: start on the walk.
                let first = 1.min(clip.n_frames() - 1);
                let frames = (clip.n_frames() - first).min(max_frames.max(1));
                for f in first..first + frames {
                    let mut pose = Pose::rest(&mh.skeleton);
                    rt.pose(&mh.skeleton, &clip, f, &mut pose)?;
                    push(pose, &mut poses, &mut positions)?;
                }
            }
            Source::Bvh(path, rest) => {
                let clip = bvh::read(&path)?.resample(MODEL_FPS)?;
                let arms_down = arms_hanging_down(&mh.skeleton);
                let opts = RetargetOptions {
                    clip_rest: if rest == BvhRest::FirstFrameTPose {
                        ClipRest::Frame(0)
                    } else {
                        ClipRest::ZeroRotations
                    },
                    rig_initial: Some(if rest == BvhRest::ZeroArmsDown { &arms_down } else { &mh.t_pose }),
                    // The AMP "Head" joint is the base of the neck; the head rides on it.
                    aliases: if rest == BvhRest::ZeroArmsDown {
                        &[("Neck", "Head"), ("Head", "")]
                    } else {
                        CMU_FINGERS
                    },
                    ..Default::default()
                };
                let mut rt = Retarget::new(&mh.skeleton, &clip, &opts)?;
                let first = usize::from(rest == BvhRest::FirstFrameTPose).min(clip.n_frames() - 1);
                let frames = (clip.n_frames() - first).min(max_frames.max(1));
                let mut clip_poses = Vec::with_capacity(frames);
                for f in first..first + frames {
                    let mut pose = Pose::rest(&mh.skeleton);
                    rt.pose(&mh.skeleton, &clip, f, &mut pose)?;
                    clip_poses.push(pose);
                }
                for pose in lifted_onto_the_floor(&mh, clip_poses)? {
                    push(pose, &mut poses, &mut positions)?;
                }
            }
        }
        let body_motion = BodyMotion { fps: MODEL_FPS, n_vertices: nb, positions };
        let body = BodyMesh::new(nb, &mh.body.faces)?;
        let garment_name = which.description();
        let name = alloc::format!("MakeHuman {garment_name} on {motion_name}");
        Scene::new(name, garment, body, &mh.body.rest, &mh.body_weights, mh.skeleton.clone(), poses, body_motion)
    }
}
