//! One entry per input of the Rust API: each parses its bytes as a user's file would be parsed,
//! then uses what it got the way the runtime does. Errors are expected; a panic, an abort on
//! allocation or a sanitizer report is a bug.

use super::common::{step_once, tiny};
use hood::body::BodyMesh;
use hood::io::export::ObjTemplate;
use hood::io::obj::Obj;
use hood::io::safetensors::SafeTensors;
use hood::mesh::{Garment, GarmentDesc};
use hood::model::file::{FORMAT_VERSION, HEADER_LEN, MAGIC};
use hood::model::{ModelBytes, ModelSpec};
use hood::rig::fit::MhcloBinding;
use hood::sim::BodyDesc;

/// Larger meshes than this are only validated, not simulated (the step would dominate the run).
const MAX_STEPPED_VERTICES: usize = 2_000;

/// `.hood` model bytes: loaded, then stepped once on the tiny scene. The same bytes are tried
/// again with the header's checksum recomputed, so that mutations reach the archive's validation
/// and the spec checks instead of stopping at the checksum.
pub fn model(data: &[u8]) {
    load_and_step(data);
    if data.len() >= HEADER_LEN && data[..8] == MAGIC {
        let mut fixed = data.to_vec();
        fixed[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        let crc = hood::checksum::crc32(&fixed[HEADER_LEN..]);
        fixed[12..16].copy_from_slice(&crc.to_le_bytes());
        load_and_step(&fixed);
    }
}

fn load_and_step(data: &[u8]) {
    let bytes = ModelBytes::new(data);
    let Ok(model) = bytes.model() else { return };
    let _ = model.to_params();
    let t = tiny();
    step_once(&model, &t.garment, None);
    step_once(&model, &t.garment, Some(BodyDesc { mesh: &t.body, positions: &t.body_positions }));
}

/// Validates `positions` and `triangles` as a garment and as a body, and steps what is valid on
/// the tiny model.
fn use_mesh(positions: &[[f32; 3]], triangles: &[[u32; 3]]) {
    let t = tiny();
    let Ok(model) = t.model.model() else { return };
    let small = positions.len() <= MAX_STEPPED_VERTICES;
    if let Ok(garment) = Garment::new(GarmentDesc::new(positions, triangles)) {
        if small {
            step_once(&model, &garment, Some(BodyDesc { mesh: &t.body, positions: &t.body_positions }));
        }
    }
    if let Ok(body) = BodyMesh::new(positions.len(), triangles) {
        if body.survey(positions).is_ok() && small {
            step_once(&model, &t.garment, Some(BodyDesc { mesh: &body, positions }));
        }
    }
}

fn text(data: &[u8]) -> Option<&str> {
    std::str::from_utf8(data).ok()
}

/// OBJ text: read, its groups and components split, used as a garment and as a body, and kept as
/// an export template written back.
pub fn obj(data: &[u8]) {
    let Some(text) = text(data) else { return };
    if let Ok(obj) = Obj::parse(text) {
        if let Some(name) = obj.groups.first() {
            let _ = obj.extract_groups(&[name.as_str()]);
        }
        let _ = hood::io::obj::split_components(&obj.positions, &obj.triangles);
        use_mesh(&obj.positions, &obj.triangles);
    }
    if let Ok(template) = ObjTemplate::parse(text) {
        let positions = template.obj().positions.clone();
        let _ = template.write(std::io::sink(), &positions);
    }
}

/// BVH text: read, resampled to 30 Hz, its first frames posed.
pub fn bvh(data: &[u8]) {
    let Some(text) = text(data) else { return };
    let Ok(clip) = hood::io::bvh::parse(text) else { return };
    let Ok(clip) = clip.resample(30.0) else { return };
    let n = clip.joints().len();
    let (mut rot, mut pos) = (vec![glam::Quat::IDENTITY; n], vec![glam::Vec3::ZERO; n]);
    for f in 0..clip.n_frames().min(4) {
        clip.world(f, &mut rot, &mut pos);
    }
}

/// `.mhclo` text: read, checked against the tiny body and fitted onto it.
pub fn mhclo(data: &[u8]) {
    let Some(text) = text(data) else { return };
    let Ok(binding) = MhcloBinding::parse(text, 0.1) else { return };
    let t = tiny();
    if binding.check(t.body_positions.len()).is_ok() {
        let mut out = vec![[0.0f32; 3]; binding.vertices.len()];
        let _ = binding.fit(&t.body_positions, &t.body_positions, &mut out);
    }
}

/// JSON: the strict and lenient readers, a training config (read, written, read again), and the
/// MakeHuman rig, weights and pose readers against the tiny body.
pub fn json(data: &[u8]) {
    let Some(text) = text(data) else { return };
    let _ = hood::io::json::parse(text);
    let _ = hood::io::json::parse_lenient(text);
    #[cfg(feature = "train")]
    {
        use hood::train::config::{parse_carry, parse_supervised, TrainConfig};
        if let Ok(c) = TrainConfig::from_json(text) {
            let _ = TrainConfig::from_json(&c.to_json());
        }
        let _ = parse_supervised(text);
        let _ = parse_carry(text);
    }
    let t = tiny();
    let obj = Obj { positions: t.body_positions.clone(), ..Obj::default() };
    if let Ok(skeleton) = hood::io::makehuman::parse_rig(text, &obj, 0.0) {
        let _ = hood::io::makehuman::parse_weights(text, &skeleton, obj.positions.len());
        let _ = hood::io::makehuman::parse_pose(text, &skeleton);
    }
}

/// Safetensors bytes: every tensor read as every element type, and the file read as a
/// reference state dict and (feature `train`) as a training checkpoint.
pub fn safetensors(data: &[u8]) {
    let Ok(st) = SafeTensors::from_bytes(data.to_vec()) else { return };
    let names: Vec<String> = st.tensors().iter().map(|(n, _)| n.clone()).collect();
    for name in &names {
        if let Ok(info) = st.info(name) {
            let _ = info.numel();
        }
        let _ = st.bytes(name);
        if let Ok(t) = st.f32(name) {
            let _ = t.rows::<3>();
        }
        let _ = st.f64(name);
        let _ = st.i64(name);
    }
    if let Ok(h) = hood::model::reference::latent_width(&st) {
        if (1..=64).contains(&h) {
            let _ = hood::model::reference::params_from_state_dict(&st, &ModelSpec::hood(h));
        }
    }
    #[cfg(feature = "train")]
    let _ = hood::train::session::checkpoint_config(&st);
}

/// glTF bytes (GLB, or JSON with `data:` buffers): a skinned body read, a few frames of its
/// first animation posed and skinned, and its mesh used as a body.
pub fn gltf(data: &[u8]) {
    let Ok(body) = hood::io::gltf::GltfBody::from_slice(data) else { return };
    use_mesh(&body.positions, &body.triangles);
    if let Ok(poses) = body.poses(None, 30.0, 8) {
        let _ = hood::rig::motion::BodyMotion::skinned(&body.skeleton, &body.weights, &body.positions, &poses, 30.0);
    }
}
