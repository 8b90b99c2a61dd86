//! glTF 2.0 skinned bodies: the mesh, skeleton and skinning weights of one skin of a `.glb`, or
//! of a `.gltf` with embedded (`data:`) or external buffers, and its animations sampled into
//! [`Pose`]s, all in the crate's own rig types, so that a glTF character drives a simulation
//! exactly as the MakeHuman body ([`crate::io::makehuman`]) does.
//!
//! # Units and frames
//!
//! glTF is metres, y up, right-handed, as `hood` is: nothing is rotated. Skinned vertices are in
//! the skin's *bind space*: as the glTF spec says, the skinned mesh node's own transform is
//! ignored, and joint `j` carries a vertex into the world by its skinning matrix
//! `S_j(t) = W_j(t) * IBM_j`, the joint's world matrix (every node on its path to the root
//! counts, joint or not) times its inverse bind matrix.
//!
//! A file made in other units scales a node instead (an armature scaled by 0.01 around a mesh
//! in centimetres), so that every `S_j` is a rotation times one uniform scale `s` (plus a
//! translation). The reader factors `s` out ([`GltfBody::scale`], measured on the node
//! transforms as stored, without animation): rest positions and rest heads are the bind-space
//! ones times `s`, in metres; a posed bone has the world rotation `R_j` of `S_j / s` and the
//! posed head at the origin of `W_j(t)`. Skinning the rest mesh with such a pose
//! (`x' = head' + R (x - head)`, see [`crate::rig`]) gives exactly glTF's `S_j(t) v`: the body in
//! the glTF world, metres.
//!
//! The rest frame is therefore the bind space scaled to metres, not the world: a file whose
//! armature node is moved or turned has the body moved or turned by the same amount in every
//! pose, the first frame included.
//!
//! # What is read
//!
//! * The skin of the first node (in file order) that has both a mesh and a skin; every mesh
//!   skinned by that skin is read once, all its primitives merged in order (vertices and
//!   triangles appended).
//! * Per primitive: `POSITION` (float), the triangle list (`indices`, or consecutive vertices
//!   without them) and every `JOINTS_n`/`WEIGHTS_n` pair (`n` = 0, 1, ...); weights are
//!   normalised per vertex, zero weights dropped ([`SkinWeights::from_triples`]).
//! * Accessors with strides, sparse storage and normalised integer components, in any buffer:
//!   the GLB binary chunk, base64 or percent-encoded `data:` URIs, or files beside a `.gltf`.
//!   The `gltf` crate parses the container and the document and reads the accessors; `hood`
//!   checks every accessor's type, count and byte ranges first, so that a damaged file gives an
//!   error, never a panic or a silently wrong body.
//! * Bones: one per joint of the skin, parents first (joints sorted by depth in the node tree);
//!   a bone's parent is the nearest ancestor node that is also a joint of the skin; names are
//!   the node names (made unique with `.<node index>`, `node<index>` when unnamed).
//! * Animations: translation, rotation and scale channels on any node on a joint's path to the
//!   root, with `STEP`, `LINEAR` (rotations by shortest-arc slerp) and `CUBICSPLINE`
//!   (Hermite splines through the keys with their tangents) interpolation; before the first and
//!   after the last key a channel holds its end value. A clip runs from the earliest to the
//!   latest key of all its channels.
//!
//! # Not supported
//!
//! * Morph targets: `targets` are not applied and `weights` channels are ignored (they still
//!   count for the clip's time range).
//! * Primitive modes other than triangles, a skinning matrix that is not a rotation times the
//!   file's one uniform scale (non-uniform or changing scale, shear, mirroring), and animation
//!   channels on a node given by a `matrix`: refused with [`Error::Parse`].
//! * Compressed or quantised geometry (`KHR_draco_mesh_compression`,
//!   `EXT_meshopt_compression`, `KHR_mesh_quantization`): files that require an extension are
//!   refused when the document is validated.
//! * Other skins of the file (only the first skinned node's skin is read), and the file's
//!   materials, textures, cameras and lights.

mod accessor;
mod animation;
mod buffers;
mod document;
mod mesh;
mod skeleton;

use crate::error::{Error, Result};
use crate::limits;
use crate::rig::{Pose, Skeleton, SkinWeights};
use animation::Clip;
use glam::{DMat4, Vec3};
use skeleton::Rig;
use std::format;
use std::path::Path;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

#[cfg(test)]
use buffers::base64_decode;

/// Largest deviation from a rotation accepted in a skinning matrix once the file's uniform scale
/// is divided out: the largest entry of `Rᵀ R - I` (about twice the relative error of a scale,
/// or the angle of a shear, in radians).
pub const RIGID_TOLERANCE: f64 = 1e-3;

/// Most joints of a skin: bone indices are 16-bit in [`SkinWeights`].
pub const MAX_JOINTS: usize = u16::MAX as usize;

const FORMAT: &str = "gltf";

fn err(message: impl Into<String>) -> Error {
    Error::parse(FORMAT, 0, message)
}

/// A skinned body read from a glTF 2.0 file: rest mesh, skeleton and weights in metres (see the
/// [module documentation](self) for the frames), and the file's animations, sampled on demand
/// with [`GltfBody::poses`].
#[derive(Clone, Debug)]
pub struct GltfBody {
    /// Rest (bind) positions of every vertex of the skinned meshes, metres, y up.
    pub positions: Vec<[f32; 3]>,
    /// Triangles (indices into `positions`), counter-clockwise seen from outside as glTF winds
    /// them.
    pub triangles: Vec<[u32; 3]>,
    /// One bone per joint of the skin, parents first; heads, tails and frames at rest, metres.
    pub skeleton: Skeleton,
    /// Skinning weights of every vertex (bone indices into `skeleton`).
    pub weights: SkinWeights,
    /// Names of the file's animations in file order (`animation <index>` for an unnamed one).
    pub animations: Vec<String>,
    /// The node tree and the joints, as sampling a pose needs them.
    rig: Rig,
    /// One per animation of the file.
    clips: Vec<Clip>,
}

impl GltfBody {
    /// Reads a `.glb` or `.gltf` file; external buffers are looked up beside it.
    ///
    /// # Errors
    /// [`Error::Io`] when the file or an external buffer cannot be read; as
    /// [`GltfBody::from_slice`].
    pub fn read(path: impl AsRef<Path>) -> Result<GltfBody> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        parse(&bytes, Some(path.parent().unwrap_or(Path::new(""))))
    }

    /// Reads a `.glb` (binary) or `.gltf` (JSON) document from memory. Its buffers must be the
    /// GLB binary chunk or `data:` URIs: an external buffer is refused (use [`GltfBody::read`]).
    ///
    /// # Errors
    /// [`Error::Parse`] (format `"gltf"`; the JSON line where there is one) for a malformed
    /// document or GLB container, a buffer, view or accessor out of range or of the wrong
    /// type, an index naming a vertex or joint that does not exist, NaNs, a vertex without a
    /// positive weight, a primitive that is not a triangle list, a skinning matrix that is not
    /// a rotation times one uniform scale, or unusable animation keys;
    /// [`Error::Empty`] when no node has both a mesh and a skin, or the skin has no joint;
    /// [`Error::CapacityExceeded`] beyond [`crate::limits::body`] or [`MAX_JOINTS`], before
    /// the arrays are allocated.
    pub fn from_slice(bytes: &[u8]) -> Result<GltfBody> {
        parse(bytes, None)
    }

    /// Metres per bind-space unit: the uniform scale factored out of the skinning matrices
    /// (0.01 for a mesh in centimetres under an armature scaled by 0.01; 1 for most files).
    pub fn scale(&self) -> f32 {
        self.rig.scale as f32
    }

    /// Duration of an animation (`None`: the first), seconds from its earliest to its latest
    /// key.
    ///
    /// # Errors
    /// As [`GltfBody::poses`] for an unknown name or a file without animations.
    pub fn duration(&self, animation: Option<&str>) -> Result<f32> {
        let clip = &self.clips[self.find_animation(animation)?];
        Ok((clip.end - clip.start) as f32)
    }

    /// The pose of the node transforms as stored in the file, without animation (often, but not
    /// always, the bind pose).
    ///
    /// # Errors
    /// None in practice: the stored transforms were checked when the file was read.
    pub fn scene_pose(&self) -> Result<Pose> {
        let mut world = vec![DMat4::IDENTITY; self.rig.rest.len()];
        self.rig.world(&self.rig.rest, &mut world);
        self.rig.pose(&world).map_err(|(b, dev)| self.not_rigid(b, dev, "at the file's rest"))
    }

    /// Samples an animation (`None`: the first of the file) at `fps` frames per second from its
    /// first key to its last, at most `max_frames` frames: frame `k` is at `start + k / fps`
    /// seconds, and a clip of duration `d` gives `floor(d * fps) + 1` frames. Each [`Pose`]
    /// holds per bone of [`GltfBody::skeleton`] the world rotation from rest and the posed
    /// head (metres, glTF world); skinning [`GltfBody::positions`] with it gives the animated
    /// body. Use [`crate::rig::motion::MODEL_FPS`] (30) for the simulation.
    ///
    /// # Errors
    /// [`Error::Parse`] naming the file's animations for an unknown name, or naming the joint
    /// and time where a skinning matrix is not a rotation times the file's uniform scale (an
    /// animated non-uniform or changing scale); [`Error::Empty`] when the file has no
    /// animation; [`Error::OutOfRange`] for a rate that is not positive or `max_frames == 0`;
    /// [`Error::CapacityExceeded`] for more than [`crate::limits::MAX_MOTION_SAMPLES`] bone
    /// samples (frames x bones), before anything is allocated.
    pub fn poses(&self, animation: Option<&str>, fps: f32, max_frames: usize) -> Result<Vec<Pose>> {
        let a = self.find_animation(animation)?;
        if !(fps > 0.0 && fps.is_finite()) {
            return Err(Error::OutOfRange { what: "frame rate", index: 0 });
        }
        if max_frames == 0 {
            return Err(Error::OutOfRange { what: "max frames", index: 0 });
        }
        let clip = &self.clips[a];
        let fps = fps as f64;
        let full = ((clip.end - clip.start) * fps + 1e-6).floor() + 1.0;
        let frames = if full >= max_frames as f64 { max_frames } else { full as usize };
        limits::within(
            "glTF pose samples (frames x bones)",
            frames.saturating_mul(self.skeleton.len()),
            limits::MAX_MOTION_SAMPLES,
        )?;
        let mut locals = self.rig.rest.clone();
        let mut world = vec![DMat4::IDENTITY; locals.len()];
        let mut out = Vec::with_capacity(frames);
        for k in 0..frames {
            let t = clip.start + k as f64 / fps;
            for ch in &clip.channels {
                ch.apply(t, &mut locals[ch.node]);
            }
            self.rig.world(&locals, &mut world);
            let pose = self.rig.pose(&world).map_err(|(b, dev)| {
                self.not_rigid(b, dev, &format!("at {t:.4} s of animation '{}'", self.animations[a]))
            })?;
            out.push(pose);
        }
        Ok(out)
    }

    fn find_animation(&self, name: Option<&str>) -> Result<usize> {
        if self.animations.is_empty() {
            return Err(Error::Empty { what: "glTF animations" });
        }
        let Some(name) = name else { return Ok(0) };
        self.animations.iter().position(|a| a == name).ok_or_else(|| {
            let list: Vec<String> = self.animations.iter().map(|a| format!("'{a}'")).collect();
            err(format!("no animation named '{name}'; the file has {}", list.join(", ")))
        })
    }

    fn not_rigid(&self, bone: usize, deviation: f64, when: &str) -> Error {
        err(skeleton::not_rigid_message(&self.skeleton.bones()[bone].name, self.rig.joint_node[bone], deviation, when))
    }
}

fn parse(bytes: &[u8], base: Option<&Path>) -> Result<GltfBody> {
    let (doc, blob) = document::open(bytes)?;
    let buffers = buffers::load(&doc, blob, base)?;

    // The skin of the first skinned node, and every mesh it skins.
    let skin = doc.nodes().find_map(|n| n.mesh().and(n.skin())).ok_or(Error::Empty { what: "glTF skinned mesh" })?;
    let mut meshes: Vec<gltf::Mesh> = Vec::new();
    for n in doc.nodes() {
        if let (Some(m), Some(s)) = (n.mesh(), n.skin()) {
            if s.index() == skin.index() && meshes.iter().all(|x| x.index() != m.index()) {
                meshes.push(m);
            }
        }
    }
    let bones = skeleton::read(&doc, &skin, &buffers)?;
    let (rig, nj) = (bones.rig, bones.skeleton.len());

    // The mesh, in metres, and its weights by bone.
    let raw = mesh::read(&buffers, &meshes, nj)?;
    let s = rig.scale;
    let positions: Vec<[f32; 3]> =
        raw.positions.iter().map(|p| (Vec3::from(*p).as_dvec3() * s).as_vec3().into()).collect();
    let triples: Vec<(u32, u16, f32)> =
        raw.triples.iter().map(|&(v, j, w)| (v, bones.bone_of_joint[j as usize] as u16, w)).collect();
    let weights = SkinWeights::from_triples(positions.len(), nj, &triples, raw.max_influences)?;

    // Animations.
    let in_chain = rig.in_chain();
    let (mut animations, mut clips) = (Vec::new(), Vec::new());
    for (i, anim) in doc.animations().enumerate() {
        let name = anim.name().map_or_else(|| format!("animation {i}"), str::to_string);
        clips.push(animation::read(&buffers, &anim, &name, &in_chain, &rig.rest)?);
        animations.push(name);
    }
    Ok(GltfBody { positions, triangles: raw.triangles, skeleton: bones.skeleton, weights, animations, rig, clips })
}

#[cfg(test)]
mod tests;
