//! A skinned glTF body wearing a garment of the user's: the body's rest (bind)
//! mesh is the reference shape the garment is modelled around; one of its animations moves it.

use super::own::OwnGarment;
use super::Scene;
use crate::body::BodyMesh;
use crate::error::Result;
use crate::io::gltf::GltfBody;
use crate::rig::motion::{BodyMotion, MODEL_FPS};

/// `body` wearing `garment` through its animation `animation` (`None`: the first), sampled at
/// 30 Hz, at most `max_frames` frames. The garment is skinned with weights diffused from the
/// body's; its pins ([`GarmentOptions::pins`](super::own::GarmentOptions::pins)) with it.
///
/// # Errors
/// Errors of [`GltfBody::poses`] (an unknown animation, a non-rigid joint), of the body mesh's
/// validation, of [`OwnGarment::garment`] and of the weight diffusion.
pub fn gltf_wearing(
    body: &GltfBody,
    animation: Option<&str>,
    garment: OwnGarment<'_>,
    max_frames: usize,
) -> Result<Scene> {
    let poses = body.poses(animation, MODEL_FPS, max_frames)?;
    let mesh = BodyMesh::new(body.positions.len(), &body.triangles)?;
    let g = garment.garment(&mesh, &body.positions)?;
    let motion = BodyMotion::skinned(&body.skeleton, &body.weights, &body.positions, &poses, MODEL_FPS)?;
    let clip = animation.or(body.animations.first().map(|s| s.as_str())).unwrap_or("its animation");
    let name = alloc::format!("{} on {clip}", garment.name);
    Scene::new(name, g, mesh, &body.positions, &body.weights, body.skeleton.clone(), poses, motion)
}
