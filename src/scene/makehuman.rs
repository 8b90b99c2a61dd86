//! The MakeHuman scenes: the body of the assets folder wearing a piece of its
//! outfits, or a garment of the user's, on the CMU walk, a procedural motion, a clip of the
//! motion corpus or a BVH clip, retargeted onto its rig.

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
const CMU_FINGERS: &[(&str, &str)] = &[("LeftHandFinger1", "LeftHandIndex1"), ("RightHandFinger1", "RightHandIndex1")];

/// How a CMU clip is retargeted onto the MakeHuman rig: the clip's frame 0 is its T-pose
/// calibration, matched to the rig's T-pose; the CMU finger bones go to MakeHuman's index
/// fingers. (Skip frame 0 when playing the clip: it is the calibration, not the motion.)
pub fn cmu_retarget(mh: &MakeHuman) -> RetargetOptions<'_> {
    RetargetOptions {
        clip_rest: ClipRest::Frame(0),
        rig_initial: Some(&mh.t_pose),
        aliases: CMU_FINGERS,
        ..Default::default()
    }
}

/// `poses` lifted onto the floor: clips put their lowest joint (often an ankle) at y = 0,
/// which sinks the feet, and some rise over a take (the AMP walk's root by 8 cm). Each frame
/// goes onto the line through the lowest body vertex of each half of the clip (a stance in
/// any clip that starts and ends on its feet), so that the soles sit where the rest pose's do.
fn lifted_onto_the_floor(mh: &MakeHuman, mut poses: Vec<Pose>) -> Result<Vec<Pose>> {
    let rest_low = mh.body.rest.iter().map(|v| v[1]).fold(f32::INFINITY, f32::min);
    let skinned = BodyMotion::skinned(&mh.skeleton, &mh.body_weights, &mh.body.rest, &poses, MODEL_FPS)?;
    let lows: Vec<f32> =
        (0..poses.len()).map(|f| skinned.frame(f).iter().map(|v| v[1]).fold(f32::INFINITY, f32::min)).collect();
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

/// [`makehuman`](fn@makehuman) on `motion` instead of the CMU walk when given: a procedural motion or a
/// clip of the motion corpus, posed on the MakeHuman rig directly (it has the CMU bone
/// names), `max_frames` frames long.
///
/// # Errors
/// As [`makehuman`](fn@makehuman), and errors of the motion generators.
pub fn makehuman_on(
    assets: &Path,
    which: MakeHumanGarment,
    motion: Option<MotionKind>,
    max_frames: usize,
) -> Result<Scene> {
    makehuman_wearing(assets, Wearing::Piece(which), MakeHumanMotion::named(assets, motion), max_frames)
}

/// [`makehuman`](fn@makehuman) on a BVH clip of the user's (any frame rate: resampled to 30 Hz), retargeted
/// onto the MakeHuman rig by bone name (the CMU / MotionBuilder names: `Hips`, `Spine`,
/// `LeftUpLeg`, `LeftArm`, ...; joints the rig lacks are ignored, bones the clip lacks stay
/// at rest relative to their parents), the root translation scaled by the ratio of leg
/// lengths (so the clip's length unit does not matter), each frame lifted onto the floor as
/// [`MocapClip`]s are. `rest` says what the clip's rest is.
///
/// # Errors
/// As [`makehuman`](fn@makehuman); BVH parse errors; [`Error::Empty`] when no clip joint matches a rig bone.
pub fn makehuman_on_bvh(
    assets: &Path,
    which: MakeHumanGarment,
    bvh: &Path,
    rest: BvhRest,
    max_frames: usize,
) -> Result<Scene> {
    makehuman_wearing(assets, Wearing::Piece(which), MakeHumanMotion::Bvh(bvh.to_path_buf(), rest), max_frames)
}

/// Where a MakeHuman scene's motion comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum MakeHumanMotion {
    /// The CMU walk of the assets (frame 0 its T-pose calibration frame).
    CmuWalk,
    /// A procedural motion, posed on the rig directly (it has the CMU bone names).
    Procedural(MotionKind),
    /// A BVH clip (any frame rate: resampled to 30 Hz), retargeted onto the rig by bone name
    /// (the CMU / MotionBuilder names: `Hips`, `Spine`, `LeftUpLeg`, `LeftArm`, ...; joints the
    /// rig lacks are ignored, bones the clip lacks stay at rest relative to their parents), the
    /// root translation scaled by the ratio of leg lengths, each frame lifted onto the floor.
    Bvh(std::path::PathBuf, BvhRest),
    /// A motion whose first frames blend in from the rest pose, in which the garments are
    /// modelled ([`Pose::lead_in`] over this many frames): the garment then starts exactly as
    /// modelled (only moved) and the cloth follows the body into the motion, instead of being
    /// skinned into a first pose it was not made for.
    FromRest(alloc::boxed::Box<MakeHumanMotion>, usize),
}

impl MakeHumanMotion {
    /// `motion` as [`makehuman_on`] takes it: `None` is the CMU walk; the corpus's motion-capture
    /// clips are BVH files of `assets/motions`.
    pub fn named(assets: &Path, motion: Option<MotionKind>) -> MakeHumanMotion {
        match motion {
            None => MakeHumanMotion::CmuWalk,
            Some(MotionKind::Mocap(clip)) => {
                MakeHumanMotion::Bvh(assets.join("motions").join(clip.file()), BvhRest::ZeroArmsDown)
            }
            Some(kind) => MakeHumanMotion::Procedural(kind),
        }
    }

    /// What it is, for scene names.
    fn name(&self) -> std::string::String {
        match self {
            MakeHumanMotion::CmuWalk => "CMU walk".into(),
            MakeHumanMotion::Procedural(kind) => kind.name(),
            MakeHumanMotion::Bvh(path, _) => {
                path.file_stem().map_or_else(|| "a BVH clip".into(), |s| s.to_string_lossy().into_owned())
            }
            MakeHumanMotion::FromRest(motion, _) => alloc::format!("{} from rest", motion.name()),
        }
    }
}

/// What the MakeHuman body wears.
#[derive(Clone, Debug, PartialEq)]
pub enum Wearing<'a> {
    /// A piece of the assets' outfits, fitted with its `.mhclo` binding.
    Piece(MakeHumanGarment),
    /// A mesh of the user's around the body's rest shape.
    Own(super::own::OwnGarment<'a>),
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

/// The MakeHuman body of `assets` wearing `wearing`, doing `motion`, at most `max_frames`
/// frames at 30 Hz.
///
/// # Errors
/// [`Error::Io`] when the assets are absent; parse and fitting errors; errors of the motion
/// generators and of [`own::garment_from_mesh`].
pub fn makehuman_wearing(
    assets: &Path,
    wearing: Wearing<'_>,
    motion: MakeHumanMotion,
    max_frames: usize,
) -> Result<Scene> {
    let mh = MakeHuman::load(assets.join("body"))?;
    let body = BodyMesh::new(mh.body.rest.len(), &mh.body.faces)?;
    let (garment, garment_name) = match wearing {
        Wearing::Piece(which) => (outfit_piece(assets, &mh, which)?, which.description()),
        Wearing::Own(own) => {
            // Modelled around `base.obj`: the garment goes with the body into metres, onto the floor.
            let options = super::own::GarmentOptions {
                scale: own.options.scale * METRES_PER_UNIT,
                offset: [0.0, mh.floor_shift, 0.0],
                ..own.options.clone()
            };
            (super::own::OwnGarment { options: &options, ..own }.garment(&body, &mh.body.rest)?, own.name)
        }
    };
    let motion_name = motion.name();
    let poses = makehuman_poses(assets, &mh, motion, max_frames)?;
    let body_motion = BodyMotion::skinned(&mh.skeleton, &mh.body_weights, &mh.body.rest, &poses, MODEL_FPS)?;
    let name = alloc::format!("MakeHuman {garment_name} on {motion_name}");
    Scene::new(name, garment, body, &mh.body.rest, &mh.body_weights, mh.skeleton.clone(), poses, body_motion)
}

/// A piece of the assets' outfits fitted to the MakeHuman body `mh` by its `.mhclo` binding.
fn outfit_piece(assets: &Path, mh: &MakeHuman, which: MakeHumanGarment) -> Result<Garment> {
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
    Ok(garment)
}

/// The poses of `motion` on the MakeHuman rig, at most `max_frames`.
fn makehuman_poses(assets: &Path, mh: &MakeHuman, motion: MakeHumanMotion, max_frames: usize) -> Result<Vec<Pose>> {
    let mut poses = Vec::new();
    match motion {
        MakeHumanMotion::FromRest(motion, frames) => {
            poses = makehuman_poses(assets, mh, *motion, max_frames)?;
            Pose::lead_in(&mh.skeleton, &mut poses, frames)?;
        }
        MakeHumanMotion::Procedural(kind) => {
            let frames = max_frames.max(1);
            let local = kind.local(&mh.skeleton, (frames - 1).max(1) as f32 / MODEL_FPS)?;
            for f in 0..frames.min(local.n_frames()) {
                let mut pose = Pose::rest(&mh.skeleton);
                local.pose(&mh.skeleton, f, &mut pose)?;
                poses.push(pose);
            }
        }
        MakeHumanMotion::CmuWalk => {
            let clip = bvh::read(assets.join("motions/cmu_12_03_walk.bvh"))?.resample(MODEL_FPS)?;
            let mut rt = Retarget::new(&mh.skeleton, &clip, &cmu_retarget(mh))?;
            // Frame 0 of the clip is its T-pose calibration frame: start on the walk.
            let first = 1.min(clip.n_frames() - 1);
            let frames = (clip.n_frames() - first).min(max_frames.max(1));
            for f in first..first + frames {
                let mut pose = Pose::rest(&mh.skeleton);
                rt.pose(&mh.skeleton, &clip, f, &mut pose)?;
                poses.push(pose);
            }
        }
        MakeHumanMotion::Bvh(path, rest) => {
            let clip = bvh::read(&path)?.resample(MODEL_FPS)?;
            let arms_down = arms_hanging_down(&mh.skeleton);
            let opts = RetargetOptions {
                clip_rest: if rest == BvhRest::FirstFrameTPose { ClipRest::Frame(0) } else { ClipRest::ZeroRotations },
                rig_initial: Some(if rest == BvhRest::ZeroArmsDown { &arms_down } else { &mh.t_pose }),
                // The AMP "Head" joint is the base of the neck; the head rides on it.
                aliases: if rest == BvhRest::ZeroArmsDown { &[("Neck", "Head"), ("Head", "")] } else { CMU_FINGERS },
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
            poses = lifted_onto_the_floor(mh, clip_poses)?;
        }
    }
    Ok(poses)
}
