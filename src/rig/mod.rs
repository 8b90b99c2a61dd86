//! Bodies in motion (feature `tools`): a skeleton with rest frames, forward kinematics, linear
//! blend skinning (this module), motion clips and retargeting ([`motion`]), procedural mannequin,
//! motions and garments ([`procedural`]), and garment fitting and skinning ([`fit`]). The runtime
//! does not skin: an engine hands [`crate::sim::Sim::step`] its skinned body vertices.
//!
//! Frames: positions are in the body's units (metres for everything `hood` builds), y up, the
//! body facing +z, x = the character's left. A [`Pose`] holds, per bone, the *world* rotation
//! that carries the bone from its rest placement to its posed placement, and the posed head;
//! skinning applies `x' = head' + R (x - head)` blended over the bones of a vertex.

pub mod fit;
pub mod motion;
pub mod procedural;
#[cfg(test)]
pub(crate) mod testgeom;

use crate::error::{Error, Result};
use crate::math::finite3;
use alloc::string::String;
use alloc::vec;
use alloc::vec::Vec;
use glam::{Quat, Vec3};

/// One bone as given to [`Skeleton::new`].
#[derive(Clone, Debug, PartialEq)]
pub struct BoneDesc {
    /// Name (unique).
    pub name: String,
    /// Index of the parent bone, which must come earlier in the list; `None` for a root.
    pub parent: Option<usize>,
    /// Rest head (the joint the bone turns about).
    pub head: [f32; 3],
    /// Rest tail (the far end; may equal the head for a zero-length bone).
    pub tail: [f32; 3],
    /// Rest frame: rotation from the bone's local axes to world axes. Local +y points from head
    /// to tail; see [`rest_frame`] to make one from a roll angle.
    pub frame: Quat,
}

/// A bone of a [`Skeleton`].
#[derive(Clone, Debug, PartialEq)]
pub struct Bone {
    /// Name.
    pub name: String,
    /// Parent bone (earlier in the skeleton), `None` for a root.
    pub parent: Option<usize>,
    /// Rest head.
    pub head: Vec3,
    /// Rest tail.
    pub tail: Vec3,
    /// Rest frame (bone-local axes to world axes).
    pub frame: Quat,
}

impl Bone {
    /// Rest length `|tail - head|`.
    pub fn length(&self) -> f32 {
        (self.tail - self.head).length()
    }
}

/// The bone frame with local +y along `tail - head` and the given roll (radians, about +y): the
/// shortest-arc rotation from `reference_y` to the bone direction, then the roll. With
/// `reference_y = +y` this is Blender's convention in a y-up world.
pub fn rest_frame(head: [f32; 3], tail: [f32; 3], roll: f32, reference_y: Vec3) -> Quat {
    let d = Vec3::from(tail) - Vec3::from(head);
    let arc =
        if d.length_squared() > 0.0 { Quat::from_rotation_arc(reference_y, d.normalize()) } else { Quat::IDENTITY };
    (arc * Quat::from_rotation_y(roll)).normalize()
}

/// Bones in topological order (every parent before its children).
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    bones: Vec<Bone>,
}

impl Skeleton {
    /// Builds a skeleton from bones listed parents first.
    ///
    /// # Errors
    /// [`Error::Empty`] without bones; [`Error::IndexOutOfRange`] for a parent that is not an
    /// earlier bone; [`Error::NonFinite`] for a NaN head or tail.
    pub fn new(bones: Vec<BoneDesc>) -> Result<Skeleton> {
        if bones.is_empty() {
            return Err(Error::Empty { what: "skeleton" });
        }
        let mut out = Vec::with_capacity(bones.len());
        for (i, b) in bones.into_iter().enumerate() {
            if let Some(p) = b.parent {
                if p >= i {
                    return Err(Error::IndexOutOfRange { what: "bone parent", at: i, index: p, len: i });
                }
            }
            if !finite3(b.head) || !finite3(b.tail) || !b.frame.is_finite() {
                return Err(Error::NonFinite { what: "bone", index: i });
            }
            out.push(Bone {
                name: b.name,
                parent: b.parent,
                head: b.head.into(),
                tail: b.tail.into(),
                frame: b.frame.normalize(),
            });
        }
        Ok(Skeleton { bones: out })
    }

    /// Builds a skeleton from bones in any order whose parents are given by name (`None` or an
    /// empty name for a root); the result is in topological order, siblings in input order.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for an unknown parent name or a cycle.
    pub fn from_named(bones: Vec<(BoneDesc, Option<String>)>) -> Result<Skeleton> {
        let n = bones.len();
        let find = |name: &str| bones.iter().position(|(b, _)| b.name == name);
        let mut parent_of = vec![None; n];
        for (i, (_, p)) in bones.iter().enumerate() {
            if let Some(p) = p.as_deref().filter(|p| !p.is_empty()) {
                parent_of[i] = Some(find(p).ok_or(Error::OutOfRange { what: "bone parent name", index: i })?);
            }
        }
        let mut order: Vec<usize> = Vec::with_capacity(n);
        let mut placed = vec![false; n];
        while order.len() < n {
            let before = order.len();
            for i in 0..n {
                if !placed[i] && parent_of[i].is_none_or(|p| placed[p]) {
                    placed[i] = true;
                    order.push(i);
                }
            }
            if order.len() == before {
                let i = (0..n).find(|&i| !placed[i]).unwrap_or(0);
                return Err(Error::OutOfRange { what: "bone parent cycle", index: i });
            }
        }
        let mut new_index = vec![0usize; n];
        for (k, &i) in order.iter().enumerate() {
            new_index[i] = k;
        }
        let mut slots: Vec<Option<BoneDesc>> = bones.into_iter().map(|(b, _)| Some(b)).collect();
        let mut descs = Vec::with_capacity(n);
        for &i in &order {
            let mut b = slots[i].take().ok_or(Error::OutOfRange { what: "bone", index: i })?;
            b.parent = parent_of[i].map(|p| new_index[p]);
            descs.push(b);
        }
        Skeleton::new(descs)
    }

    /// Number of bones.
    pub fn len(&self) -> usize {
        self.bones.len()
    }
    /// Always false (a skeleton has at least one bone).
    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }
    /// The bones, parents first.
    pub fn bones(&self) -> &[Bone] {
        &self.bones
    }
    /// Index of the bone called `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.bones.iter().position(|b| b.name == name)
    }
    /// The children of bone `b`.
    pub fn children(&self, b: usize) -> impl Iterator<Item = usize> + '_ {
        self.bones.iter().enumerate().filter(move |(_, x)| x.parent == Some(b)).map(|(i, _)| i)
    }

    /// Forward kinematics. `local[b]` rotates bone `b` in its own rest frame relative to its
    /// parent (identity = rest); `root_translation` moves every root. Writes world rotations and
    /// posed heads into `out` without allocating.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `local` or `out` does not have one entry per bone.
    pub fn forward_kinematics(&self, local: &[Quat], root_translation: [f32; 3], out: &mut Pose) -> Result<()> {
        self.check(local.len(), "local rotations", out)?;
        let t = Vec3::from(root_translation);
        for (i, b) in self.bones.iter().enumerate() {
            // Identity stays exactly identity so that the rest pose reproduces the rest mesh bit for bit.
            let own =
                if local[i] == Quat::IDENTITY { Quat::IDENTITY } else { b.frame * local[i] * b.frame.conjugate() };
            match b.parent {
                Some(p) => {
                    out.rotation[i] =
                        if own == Quat::IDENTITY { out.rotation[p] } else { (out.rotation[p] * own).normalize() };
                    out.head[i] = self.follow_parent(i, p, out);
                }
                None => {
                    out.rotation[i] = own.normalize();
                    out.head[i] = b.head + t;
                }
            }
        }
        Ok(())
    }

    /// Poses the skeleton from world rotations (rest to posed, one per bone): heads follow their
    /// parents rigidly, roots move by `root_translation`.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when `world` or `out` does not have one entry per bone.
    pub fn pose_from_world(&self, world: &[Quat], root_translation: [f32; 3], out: &mut Pose) -> Result<()> {
        self.check(world.len(), "world rotations", out)?;
        let t = Vec3::from(root_translation);
        for (i, b) in self.bones.iter().enumerate() {
            out.rotation[i] = world[i].normalize();
            out.head[i] = match b.parent {
                Some(p) => self.follow_parent(i, p, out),
                None => b.head + t,
            };
        }
        Ok(())
    }

    /// Posed head of bone `i` rigidly attached to its posed parent `p`, written as rest head plus
    /// displacements so that a parent at rest gives the rest head exactly.
    fn follow_parent(&self, i: usize, p: usize, pose: &Pose) -> Vec3 {
        let d = self.bones[i].head - self.bones[p].head;
        self.bones[i].head + (pose.head[p] - self.bones[p].head) + (pose.rotation[p] * d - d)
    }

    /// The local rotations (in each bone's rest frame) that [`Self::forward_kinematics`] turns
    /// into the world rotations of `pose`.
    pub fn local_from_pose(&self, pose: &Pose, out: &mut [Quat]) -> Result<()> {
        self.check(out.len(), "local rotations", pose)?;
        for (i, b) in self.bones.iter().enumerate() {
            let parent = b.parent.map_or(Quat::IDENTITY, |p| pose.rotation[p]);
            out[i] = (b.frame.conjugate() * parent.conjugate() * pose.rotation[i] * b.frame).normalize();
        }
        Ok(())
    }

    fn check(&self, n: usize, what: &'static str, pose: &Pose) -> Result<()> {
        if n != self.bones.len() {
            return Err(Error::SizeMismatch { what, expected: self.bones.len(), got: n });
        }
        if pose.rotation.len() != self.bones.len() || pose.head.len() != self.bones.len() {
            return Err(Error::SizeMismatch { what: "pose", expected: self.bones.len(), got: pose.rotation.len() });
        }
        Ok(())
    }
}

/// A posed skeleton: per bone the world rotation from rest to posed and the posed head.
#[derive(Clone, Debug, PartialEq)]
pub struct Pose {
    /// World rotation of each bone relative to its rest placement.
    pub rotation: Vec<Quat>,
    /// Posed head of each bone.
    pub head: Vec<Vec3>,
}

impl Pose {
    /// The rest pose of `skeleton`.
    pub fn rest(skeleton: &Skeleton) -> Pose {
        Pose { rotation: vec![Quat::IDENTITY; skeleton.len()], head: skeleton.bones.iter().map(|b| b.head).collect() }
    }
    /// Posed tail of bone `b`.
    pub fn tail(&self, skeleton: &Skeleton, b: usize) -> Vec3 {
        let bone = &skeleton.bones[b];
        self.head[b] + self.rotation[b] * (bone.tail - bone.head)
    }
    /// Where the rest point `x` goes when rigidly attached to bone `b`.
    pub fn transform_point(&self, skeleton: &Skeleton, b: usize, x: Vec3) -> Vec3 {
        self.head[b] + self.rotation[b] * (x - skeleton.bones[b].head)
    }

    /// Leads a motion in from the rest pose over its first `frames` poses: pose `k` becomes the
    /// rest pose turned a smooth step (w = 3u² - 2u³ of the way, u = k / frames) towards the
    /// motion's own pose `k`, bone by bone in local rotations, the root rising from the rest
    /// height as far; along the floor the root moves w of the motion's own step each frame, so
    /// the body starts from standing and reaches the motion's speed, not its place. Pose 0 is the
    /// rest pose moved along the floor under the motion's first root (a garment modelled around
    /// the rest shape fits it exactly, only moved); from pose `frames` on the motion is its own,
    /// shifted along the floor by the distance the start-up did not cover.
    ///
    /// # Errors
    /// [`Error::SizeMismatch`] when a pose is not one of `skeleton`.
    pub fn lead_in(skeleton: &Skeleton, poses: &mut [Pose], frames: usize) -> Result<()> {
        let Some(root) = skeleton.bones.iter().position(|b| b.parent.is_none()) else { return Ok(()) };
        let translation = |p: &Pose| p.head.get(root).map_or(Vec3::ZERO, |h| *h - skeleton.bones[root].head);
        let smooth = |k: usize| {
            let u = (k as f32 / frames.max(1) as f32).min(1.0);
            u * u * (3.0 - 2.0 * u)
        };
        let floor = Vec3::new(1.0, 0.0, 1.0);
        // The root's place along the floor, and the motion's own, at the pose before.
        let (mut along, mut own) = match poses.first() {
            Some(p) => (translation(p) * floor, translation(p) * floor),
            None => return Ok(()),
        };
        let mut local = vec![Quat::IDENTITY; skeleton.len()];
        for (k, pose) in poses.iter_mut().enumerate() {
            let t = translation(pose);
            if k > 0 {
                along += smooth(k - 1) * (t * floor - own);
            }
            own = t * floor;
            if k >= frames {
                let shift = along - own;
                pose.head.iter_mut().for_each(|h| *h += shift);
                continue;
            }
            let w = smooth(k);
            skeleton.local_from_pose(pose, &mut local)?;
            // Pose 0 keeps the identity exactly: forward kinematics then gives the rest pose bit
            // for bit (moved).
            for q in local.iter_mut() {
                *q = if k == 0 { Quat::IDENTITY } else { Quat::IDENTITY.slerp(*q, w) };
            }
            let root_at = along + Vec3::new(0.0, w * t.y, 0.0);
            skeleton.forward_kinematics(&local, root_at.into(), pose)?;
        }
        Ok(())
    }
}

/// Sparse per-vertex skinning weights: for vertex `v`, bones `bone[offsets[v]..offsets[v+1]]`
/// with weights summing to 1.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinWeights {
    offsets: Vec<u32>,
    bone: Vec<u16>,
    weight: Vec<f32>,
}

impl SkinWeights {
    /// Builds weights from `(vertex, bone, weight)` triples in any order. Repeated pairs add up;
    /// weights at or below zero are dropped; each vertex keeps its `max_influences` largest
    /// weights, normalised to sum to 1.
    ///
    /// # Errors
    /// [`Error::IndexOutOfRange`] for a vertex or bone out of range, [`Error::NonFinite`] for a
    /// NaN weight, [`Error::OutOfRange`] when a vertex ends with no positive weight.
    pub fn from_triples(
        n_vertices: usize,
        n_bones: usize,
        triples: &[(u32, u16, f32)],
        max_influences: usize,
    ) -> Result<SkinWeights> {
        let mut sorted: Vec<(u32, u16, f32)> = Vec::with_capacity(triples.len());
        for (k, &(v, b, w)) in triples.iter().enumerate() {
            if v as usize >= n_vertices {
                return Err(Error::IndexOutOfRange {
                    what: "skin weight vertex",
                    at: k,
                    index: v as usize,
                    len: n_vertices,
                });
            }
            if b as usize >= n_bones {
                return Err(Error::IndexOutOfRange {
                    what: "skin weight bone",
                    at: k,
                    index: b as usize,
                    len: n_bones,
                });
            }
            if !w.is_finite() {
                return Err(Error::NonFinite { what: "skin weight", index: k });
            }
            if w > 0.0 {
                sorted.push((v, b, w));
            }
        }
        sorted.sort_unstable_by_key(|t| (t.0, t.1));
        let mut out = SkinWeights { offsets: Vec::with_capacity(n_vertices + 1), bone: Vec::new(), weight: Vec::new() };
        out.offsets.push(0);
        let mut i = 0;
        let mut row: Vec<(u16, f32)> = Vec::new();
        for v in 0..n_vertices as u32 {
            row.clear();
            while i < sorted.len() && sorted[i].0 == v {
                match row.last_mut() {
                    Some(last) if last.0 == sorted[i].1 => last.1 += sorted[i].2,
                    _ => row.push((sorted[i].1, sorted[i].2)),
                }
                i += 1;
            }
            out.push_row(v as usize, &mut row, max_influences)?;
        }
        Ok(out)
    }

    /// Builds weights from dense rows: `dense[v * n_bones + b]` is the weight of bone `b` at
    /// vertex `v` (then as [`Self::from_triples`]).
    pub fn from_dense(n_bones: usize, dense: &[f32], max_influences: usize) -> Result<SkinWeights> {
        if n_bones == 0 || dense.len() / n_bones * n_bones != dense.len() {
            return Err(Error::SizeMismatch { what: "dense skin weights", expected: n_bones, got: dense.len() });
        }
        let n = dense.len() / n_bones;
        let mut out = SkinWeights { offsets: Vec::with_capacity(n + 1), bone: Vec::new(), weight: Vec::new() };
        out.offsets.push(0);
        let mut row = Vec::new();
        for v in 0..n {
            row.clear();
            for b in 0..n_bones {
                let w = dense[v * n_bones + b];
                if !w.is_finite() {
                    return Err(Error::NonFinite { what: "skin weight", index: v });
                }
                if w > 0.0 {
                    row.push((b as u16, w));
                }
            }
            out.push_row(v, &mut row, max_influences)?;
        }
        Ok(out)
    }

    fn push_row(&mut self, v: usize, row: &mut [(u16, f32)], max_influences: usize) -> Result<()> {
        row.sort_unstable_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let keep = &row[..row.len().min(max_influences.max(1))];
        let sum: f32 = keep.iter().map(|x| x.1).sum();
        if keep.is_empty() || sum <= 0.0 {
            return Err(Error::OutOfRange { what: "vertex without skin weights", index: v });
        }
        for &(b, w) in keep {
            self.bone.push(b);
            self.weight.push(w / sum);
        }
        self.offsets.push(self.bone.len() as u32);
        Ok(())
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    /// The `(bone, weight)` pairs of vertex `v`, largest weight first.
    pub fn influences(&self, v: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let (a, b) = (self.offsets[v] as usize, self.offsets[v + 1] as usize);
        self.bone[a..b].iter().zip(&self.weight[a..b]).map(|(&b, &w)| (b as usize, w))
    }
    /// The bone of largest weight at vertex `v`.
    pub fn dominant_bone(&self, v: usize) -> usize {
        self.bone[self.offsets[v] as usize] as usize
    }
    /// Weights for a subset of vertices (e.g. the `body` group of a larger mesh).
    pub fn select(&self, vertices: &[u32]) -> SkinWeights {
        let mut out = SkinWeights { offsets: vec![0], bone: Vec::new(), weight: Vec::new() };
        for &v in vertices {
            let (a, b) = (self.offsets[v as usize] as usize, self.offsets[v as usize + 1] as usize);
            out.bone.extend_from_slice(&self.bone[a..b]);
            out.weight.extend_from_slice(&self.weight[a..b]);
            out.offsets.push(out.bone.len() as u32);
        }
        out
    }
    /// Largest bone index referenced, plus one (0 when empty).
    pub fn bone_bound(&self) -> usize {
        self.bone.iter().map(|&b| b as usize + 1).max().unwrap_or(0)
    }
}

/// Per-bone affine transforms of a pose, stored as displacements from the identity:
/// `x' = x + m[b] * x + t[b]` (so the rest pose moves nothing, exactly). Compute once per frame
/// with [`SkinTransforms::update`], then skin any number of meshes.
#[derive(Clone, Debug, PartialEq)]
pub struct SkinTransforms {
    m: Vec<glam::Mat3>,
    t: Vec<Vec3>,
}

impl SkinTransforms {
    /// Identity transforms for `n_bones` bones.
    pub fn new(n_bones: usize) -> SkinTransforms {
        SkinTransforms { m: vec![glam::Mat3::ZERO; n_bones], t: vec![Vec3::ZERO; n_bones] }
    }
    /// Fills the transforms from a pose (no allocation).
    pub fn update(&mut self, skeleton: &Skeleton, pose: &Pose) -> Result<()> {
        let n = skeleton.len();
        if self.m.len() != n || pose.rotation.len() != n || pose.head.len() != n {
            return Err(Error::SizeMismatch { what: "skin transforms", expected: n, got: self.m.len() });
        }
        for (b, bone) in skeleton.bones().iter().enumerate() {
            let m = glam::Mat3::from_quat(pose.rotation[b]) - glam::Mat3::IDENTITY;
            self.m[b] = m;
            self.t[b] = (pose.head[b] - bone.head) - m * bone.head;
        }
        Ok(())
    }
}

/// Linear blend skinning: `out[v] = sum_b w_vb (R_b (rest[v] - head_b) + head'_b)`, into the
/// caller's buffer, without allocation.
///
/// # Errors
/// [`Error::SizeMismatch`] when `rest`, `out` and `weights` disagree on the vertex count, or
/// the weights name a bone the transforms lack.
pub fn skin(transforms: &SkinTransforms, weights: &SkinWeights, rest: &[[f32; 3]], out: &mut [[f32; 3]]) -> Result<()> {
    let n = weights.n_vertices();
    if rest.len() != n || out.len() != n {
        return Err(Error::SizeMismatch { what: "skinned vertices", expected: n, got: rest.len().min(out.len()) });
    }
    if weights.bone_bound() > transforms.m.len() {
        return Err(Error::SizeMismatch {
            what: "skin bones",
            expected: weights.bone_bound(),
            got: transforms.m.len(),
        });
    }
    for v in 0..n {
        let x = Vec3::from(rest[v]);
        let (a, b) = (weights.offsets[v] as usize, weights.offsets[v + 1] as usize);
        let mut m = glam::Mat3::ZERO;
        let mut t = Vec3::ZERO;
        for k in a..b {
            let (bone, w) = (weights.bone[k] as usize, weights.weight[k]);
            m += transforms.m[bone] * w;
            t += transforms.t[bone] * w;
        }
        out[v] = (x + (m * x + t)).into();
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests;
