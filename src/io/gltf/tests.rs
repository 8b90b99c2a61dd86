//! A two-bone "arm" built in the tests as glTF (JSON with a `data:` buffer, GLB, and JSON with an
//! external buffer): a root joint under a non-joint armature node with a translation, a turn and
//! a uniform 0.01 scale, the mesh in centimetres. Expected values are computed here from the
//! glTF matrices (`S_j = W_j * IBM_j`), independently of the reader.

use super::*;
use crate::rig::motion::MODEL_FPS;
use crate::rig::{skin, SkinTransforms};
use glam::{DMat4, DQuat, DVec3};
use serde_json::{json, Value};
use std::string::String;
use std::vec::Vec;

const FRAC_PI_2: f64 = core::f64::consts::FRAC_PI_2;

fn b64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            out.push(if k <= c.len() { A[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
        }
    }
    out
}

#[test]
fn base64_round_trips() {
    for n in 0..40u8 {
        let data: Vec<u8> = (0..n).map(|i| i.wrapping_mul(37).wrapping_add(n)).collect();
        assert_eq!(base64_decode(&b64(&data)).unwrap(), data);
    }
    assert_eq!(base64_decode("aGVsbG8=").unwrap(), b"hello");
    assert!(base64_decode("aGV*").is_none());
}

// ---------------------------------------------------------------------------------------------
// The scene.

/// The armature node at rest: metres, turned 30 degrees about y, scaled by 0.01 (cm to m).
fn arm_t() -> DVec3 {
    DVec3::new(0.3, 0.05, -0.2)
}
fn arm_r(deg: f64) -> DQuat {
    DQuat::from_rotation_y(deg.to_radians())
}
const ARM_S: f64 = 0.01;
/// The upper joint's rest translation (cm) and rotation.
fn upper_t() -> DVec3 {
    DVec3::new(0.0, 100.0, 0.0)
}
fn upper_r() -> DQuat {
    DQuat::from_rotation_x(10f64.to_radians())
}
/// The lower joint's rest translation (cm); its rest rotation is the identity.
fn lower_t() -> DVec3 {
    DVec3::new(0.0, 30.0, 0.0)
}

fn trs(t: DVec3, r: DQuat, s: f64) -> DMat4 {
    DMat4::from_scale_rotation_translation(DVec3::splat(s), r, t)
}

/// Inverse bind matrices in skin order (Lower, Upper): the mesh, in the armature's space (cm),
/// is bound where the nodes rest, so `IBM_j = W_j^-1 * armature = (armature-local joint)^-1`.
fn ibms() -> [DMat4; 2] {
    let upper = trs(upper_t(), upper_r(), 1.0);
    let lower = upper * trs(lower_t(), DQuat::IDENTITY, 1.0);
    [lower.inverse(), upper.inverse()]
}

/// Raw vertex data: a 6 cm square tube from y = 100 to 160 cm, 5 rings of 4 vertices.
struct Raw {
    positions: Vec<[f32; 3]>,
    indices: Vec<u16>,
    joints0: Vec<[u8; 4]>,
    weights0: Vec<[f32; 4]>,
    joints1: Vec<[u16; 4]>,
    /// Normalised 16-bit.
    weights1: Vec<[u16; 4]>,
}

fn raw() -> Raw {
    let corners = [[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]];
    let mut r = Raw {
        positions: Vec::new(),
        indices: Vec::new(),
        joints0: Vec::new(),
        weights0: Vec::new(),
        joints1: Vec::new(),
        weights1: Vec::new(),
    };
    for ring in 0..5 {
        for c in corners {
            r.positions.push([c[0], 100.0 + 15.0 * ring as f32, c[1]]);
            // Skin joints: 0 = Lower, 1 = Upper.
            let (j, w) = match ring {
                0 | 1 => ([1, 0, 0, 0], [1.0, 0.0, 0.0, 0.0]),
                // Not normalised: the reader normalises.
                2 => ([0, 1, 0, 0], [0.3, 0.3, 0.0, 0.0]),
                // A zero weight naming another joint is dropped.
                _ => ([0, 1, 0, 0], [1.0, 0.0, 0.0, 0.0]),
            };
            r.joints0.push(j);
            r.weights0.push(w);
            r.joints1.push([0; 4]);
            r.weights1.push([0; 4]);
        }
    }
    // A second influence set on vertex 8: Upper again, 0.2 (13107 / 65535).
    r.joints1[8] = [1, 0, 0, 0];
    r.weights1[8] = [13107, 0, 0, 0];
    for ring in 0..4u16 {
        for c in 0..4u16 {
            let (a, b) = (ring * 4 + c, ring * 4 + (c + 1) % 4);
            r.indices.extend_from_slice(&[a, b, b + 4, a, b + 4, a + 4]);
        }
    }
    r
}

/// The normalised weights of vertex `v` per skin joint, from the raw data.
fn raw_weights(r: &Raw, v: usize) -> [f64; 2] {
    let mut w = [0.0; 2];
    for c in 0..4 {
        w[r.joints0[v][c] as usize] += r.weights0[v][c] as f64;
        w[r.joints1[v][c] as usize] += r.weights1[v][c] as f64 / 65535.0;
    }
    let sum = w[0] + w[1];
    [w[0] / sum, w[1] / sum]
}

/// A document under construction: its JSON and its binary buffer.
struct Doc {
    json: Value,
    bin: Vec<u8>,
}

fn bytes_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}
fn bytes_u16(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

impl Doc {
    fn view(&mut self, data: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(data);
        let views = self.json["bufferViews"].as_array_mut().unwrap();
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len()}));
        views.len() - 1
    }
    fn accessor(&mut self, data: &[u8], component: u32, ty: &str, count: usize, extra: Value) -> usize {
        let view = self.view(data);
        let mut a = json!({"bufferView": view, "componentType": component, "type": ty, "count": count});
        if let Value::Object(m) = extra {
            a.as_object_mut().unwrap().extend(m);
        }
        let accessors = self.json["accessors"].as_array_mut().unwrap();
        accessors.push(a);
        accessors.len() - 1
    }
    fn floats(&mut self, v: &[f32], ty: &str, width: usize) -> usize {
        self.accessor(&bytes_f32(v), 5126, ty, v.len() / width, json!({}))
    }
    /// A `.gltf` document with the buffer as a base64 `data:` URI.
    fn gltf(&self) -> Vec<u8> {
        let mut j = self.json.clone();
        j["buffers"] = json!([{
            "byteLength": self.bin.len(),
            "uri": format!("data:application/octet-stream;base64,{}", b64(&self.bin)),
        }]);
        serde_json::to_vec_pretty(&j).unwrap()
    }
    /// The same as a `.glb`: the buffer is the binary chunk.
    fn glb(&self) -> Vec<u8> {
        let mut j = self.json.clone();
        j["buffers"] = json!([{ "byteLength": self.bin.len() }]);
        let mut json = serde_json::to_vec(&j).unwrap();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let mut bin = self.bin.clone();
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&json);
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
        out
    }
}

fn quat(q: DQuat) -> Vec<f32> {
    q.to_array().iter().map(|&x| x as f32).collect()
}
fn vec3(v: DVec3) -> Vec<f32> {
    v.to_array().iter().map(|&x| x as f32).collect()
}

/// The cubic translation keys of "Bend" (upper joint, cm): times and (in-tangent, value,
/// out-tangent) per key.
const CUBIC_TIMES: [f32; 3] = [0.0, 0.5, 1.0];
fn cubic_keys() -> [[DVec3; 3]; 3] {
    let z = DVec3::ZERO;
    [
        [z, upper_t(), DVec3::new(20.0, 0.0, 0.0)],
        [DVec3::new(0.0, 10.0, 0.0), DVec3::new(5.0, 100.0, 2.0), DVec3::new(0.0, 10.0, 0.0)],
        [DVec3::new(-20.0, 0.0, 0.0), upper_t(), z],
    ]
}

/// The upper joint's translation at `t` seconds in "Bend": the Hermite spline of the glTF spec.
fn cubic_at(t: f64) -> DVec3 {
    let k = cubic_keys();
    let times = CUBIC_TIMES.map(|x| x as f64);
    if t <= times[0] {
        return k[0][1];
    }
    if t >= times[2] {
        return k[2][1];
    }
    let i = if t < times[1] { 0 } else { 1 };
    let td = times[i + 1] - times[i];
    let s = (t - times[i]) / td;
    let (p0, m0, p1, m1) = (k[i][1], k[i][2] * td, k[i + 1][1], k[i + 1][0] * td);
    p0 * (2.0 * s.powi(3) - 3.0 * s * s + 1.0)
        + m0 * (s.powi(3) - 2.0 * s * s + s)
        + p1 * (-2.0 * s.powi(3) + 3.0 * s * s)
        + m1 * (s.powi(3) - s * s)
}

fn build(r: &Raw) -> Doc {
    let mut d = Doc {
        json: json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [
                {"name": "Armature", "translation": vec3(arm_t()), "rotation": quat(arm_r(30.0)),
                 "scale": [ARM_S, ARM_S, ARM_S], "children": [1, 3]},
                {"name": "Upper", "translation": vec3(upper_t()), "rotation": quat(upper_r()), "children": [2]},
                {"name": "Lower", "translation": vec3(lower_t())},
                // The skinned mesh node's own transform is ignored (glTF spec).
                {"name": "Body", "mesh": 0, "skin": 0, "translation": [5.0, 5.0, 5.0]}
            ],
            "bufferViews": [],
            "accessors": [],
        }),
        bin: Vec::new(),
    };
    let flat: Vec<f32> = r.positions.iter().flatten().copied().collect();
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in &r.positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let pos = d.accessor(&bytes_f32(&flat), 5126, "VEC3", r.positions.len(), json!({"min": lo, "max": hi}));
    let idx = d.accessor(&bytes_u16(&r.indices), 5123, "SCALAR", r.indices.len(), json!({}));
    let j0: Vec<u8> = r.joints0.iter().flatten().copied().collect();
    let j0 = d.accessor(&j0, 5121, "VEC4", r.joints0.len(), json!({}));
    let w0: Vec<f32> = r.weights0.iter().flatten().copied().collect();
    let w0 = d.floats(&w0, "VEC4", 4);
    let j1: Vec<u16> = r.joints1.iter().flatten().copied().collect();
    let j1 = d.accessor(&bytes_u16(&j1), 5123, "VEC4", r.joints1.len(), json!({}));
    let w1: Vec<u16> = r.weights1.iter().flatten().copied().collect();
    let w1 = d.accessor(&bytes_u16(&w1), 5123, "VEC4", r.weights1.len(), json!({"normalized": true}));
    d.json["meshes"] = json!([{"name": "Arm", "primitives": [{
        "attributes": {"POSITION": pos, "JOINTS_0": j0, "WEIGHTS_0": w0, "JOINTS_1": j1, "WEIGHTS_1": w1,
                       "_CUSTOM": w0},
        "indices": idx,
    }]}]);
    let ibm: Vec<f32> = ibms().iter().flat_map(|m| m.to_cols_array()).map(|x| x as f32).collect();
    let ibm = d.floats(&ibm, "MAT4", 16);
    // Joints listed child first: the reader puts parents first.
    d.json["skins"] = json!([{"joints": [2, 1], "inverseBindMatrices": ibm}]);

    // "Bend": the lower joint turns 90 degrees about z over 1 s (LINEAR), the upper joint's
    // translation follows a CUBICSPLINE.
    let t01 = d.floats(&[0.0, 1.0], "SCALAR", 1);
    let rot: Vec<f32> = [quat(DQuat::IDENTITY), quat(DQuat::from_rotation_z(FRAC_PI_2))].concat();
    let rot = d.floats(&rot, "VEC4", 4);
    let tc = d.floats(&CUBIC_TIMES, "SCALAR", 1);
    let cubic: Vec<f32> = cubic_keys().iter().flatten().flat_map(|&v| vec3(v)).collect();
    let cubic = d.floats(&cubic, "VEC3", 3);
    // "Sway": the armature (not a joint) turns by steps and moves linearly over 0.5 s; its
    // scale is animated, uniform and constant.
    let ts = d.floats(&[0.0, 0.25, 0.5], "SCALAR", 1);
    let steps: Vec<f32> = [quat(arm_r(30.0)), quat(arm_r(45.0)), quat(arm_r(60.0))].concat();
    let steps = d.floats(&steps, "VEC4", 4);
    let th = d.floats(&[0.0, 0.5], "SCALAR", 1);
    let moves: Vec<f32> = [vec3(arm_t()), vec3(arm_t() + DVec3::new(0.2, 0.0, 0.0))].concat();
    let moves = d.floats(&moves, "VEC3", 3);
    let scales = d.floats(&[0.01; 6], "VEC3", 3);
    d.json["animations"] = json!([
        {"name": "Bend",
         "samplers": [{"input": t01, "output": rot}, {"input": tc, "output": cubic, "interpolation": "CUBICSPLINE"}],
         "channels": [{"sampler": 0, "target": {"node": 2, "path": "rotation"}},
                      {"sampler": 1, "target": {"node": 1, "path": "translation"}}]},
        {"name": "Sway",
         "samplers": [{"input": ts, "output": steps, "interpolation": "STEP"},
                      {"input": th, "output": moves}, {"input": th, "output": scales}],
         "channels": [{"sampler": 0, "target": {"node": 0, "path": "rotation"}},
                      {"sampler": 1, "target": {"node": 0, "path": "translation"}},
                      {"sampler": 2, "target": {"node": 0, "path": "scale"}}]}
    ]);
    d
}

fn body() -> GltfBody {
    GltfBody::from_slice(&build(&raw()).gltf()).unwrap()
}

/// The skinning matrices (skin order: Lower, Upper) of an animation at `t` seconds, from the
/// node transforms written out here.
fn skinning(anim: &str, t: f64) -> [DMat4; 2] {
    let (mut arm, mut up_t, mut low_r) = (trs(arm_t(), arm_r(30.0), ARM_S), upper_t(), DQuat::IDENTITY);
    match anim {
        "Bend" => {
            up_t = cubic_at(t);
            low_r = DQuat::from_rotation_z(FRAC_PI_2 * t.clamp(0.0, 1.0));
        }
        "Sway" => {
            let deg = if t < 0.25 {
                30.0
            } else if t < 0.5 {
                45.0
            } else {
                60.0
            };
            arm = trs(arm_t() + DVec3::new(0.2 * (t / 0.5).clamp(0.0, 1.0), 0.0, 0.0), arm_r(deg), ARM_S);
        }
        _ => {}
    }
    let w_upper = arm * trs(up_t, upper_r(), 1.0);
    let w_lower = w_upper * trs(lower_t(), low_r, 1.0);
    let ibm = ibms();
    [w_lower * ibm[0], w_upper * ibm[1]]
}

/// Skins the body's rest mesh with `pose` through the crate's rig.
fn skinned(b: &GltfBody, pose: &Pose) -> Vec<[f32; 3]> {
    let mut tf = SkinTransforms::new(b.skeleton.len());
    tf.update(&b.skeleton, pose).unwrap();
    let mut out = vec![[0.0; 3]; b.positions.len()];
    skin(&tf, &b.weights, &b.positions, &mut out).unwrap();
    out
}

fn assert_matches_gltf(b: &GltfBody, pose: &Pose, anim: &str, t: f64) {
    let r = raw();
    let s = skinning(anim, t);
    let got = skinned(b, pose);
    for (v, p) in r.positions.iter().enumerate() {
        let w = raw_weights(&r, v);
        let x = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let want = s[0].transform_point3(x) * w[0] + s[1].transform_point3(x) * w[1];
        let d = (Vec3::from(got[v]).as_dvec3() - want).length();
        assert!(d < 1e-5, "{anim} at {t} s, vertex {v}: got {:?}, want {want:?} (off by {d:e} m)", got[v]);
    }
}

// ---------------------------------------------------------------------------------------------
// Tests.

#[test]
fn gltf_rest_mesh_is_in_metres_and_the_skeleton_parents_first() {
    let b = body();
    let r = raw();
    assert!((b.scale() - 0.01).abs() < 1e-6, "scale {}", b.scale());
    assert_eq!(b.positions.len(), 20);
    assert_eq!(b.triangles.len(), 32);
    for (p, q) in b.positions.iter().zip(&r.positions) {
        for k in 0..3 {
            assert!((p[k] - 0.01 * q[k]).abs() < 1e-6, "{p:?} vs {q:?} cm");
        }
    }
    assert_eq!(b.triangles[0], [0, 1, 5]);
    // Skin order was (Lower, Upper); bones are parents first.
    let names: Vec<&str> = b.skeleton.bones().iter().map(|x| x.name.as_str()).collect();
    assert_eq!(names, ["Upper", "Lower"]);
    assert_eq!(b.skeleton.bones()[0].parent, None, "the armature is not a joint");
    assert_eq!(b.skeleton.bones()[1].parent, Some(0));
    // Heads: the joints' bind-space origins (inverse IBM), in metres.
    let ibm = ibms();
    for (bone, j) in [(0, 1), (1, 0)] {
        let want = ibm[j].inverse().w_axis.truncate() * 0.01;
        let got = b.skeleton.bones()[bone].head.as_dvec3();
        assert!((got - want).length() < 1e-6, "bone {bone}: head {got} vs {want}");
    }
    let upper = &b.skeleton.bones()[0];
    assert!((upper.head - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-6);
    // The upper bone's tail is its child's head; its frame is the joint's rest rotation.
    assert!((upper.tail - b.skeleton.bones()[1].head).length() < 1e-6);
    assert!(upper.frame.dot(upper_r().as_quat()).abs() > 1.0 - 1e-6, "{}", upper.frame);
    assert!(b.skeleton.bones()[1].length() > 0.0);
    // Weights: normalised, zero weights dropped, the two influence sets summed.
    let w8: Vec<(usize, f32)> = b.weights.influences(8).collect();
    assert_eq!(w8.len(), 2);
    assert_eq!(w8[0].0, 0, "Upper (0.3 + 0.2) is the larger");
    assert!((w8[0].1 - 0.625).abs() < 1e-6 && (w8[1].1 - 0.375).abs() < 1e-6, "{w8:?}");
    assert_eq!(b.weights.influences(19).collect::<Vec<_>>(), [(1, 1.0)]);
    assert_eq!(b.animations, ["Bend", "Sway"]);
}

#[test]
fn gltf_scene_pose_skins_to_the_world_placement() {
    let b = body();
    let pose = b.scene_pose().unwrap();
    assert_matches_gltf(&b, &pose, "rest", 0.0);
    // The first bone's head is the armature's placement of the upper joint (metres).
    let want = trs(arm_t(), arm_r(30.0), ARM_S).transform_point3(upper_t());
    assert!((pose.head[0].as_dvec3() - want).length() < 1e-6);
}

#[test]
fn gltf_bend_poses_skin_to_the_gltf_skinning_matrices() {
    let b = body();
    // The cubic channel is a spline, not the line between keys.
    let lerp = upper_t().lerp(cubic_keys()[1][1], 0.5);
    assert!((cubic_at(0.25) - lerp).length() > 1.0);
    let poses = b.poses(Some("Bend"), MODEL_FPS, usize::MAX).unwrap();
    assert_eq!(poses.len(), 31, "1 s at 30 Hz");
    assert!((b.duration(Some("Bend")).unwrap() - 1.0).abs() < 1e-6);
    for k in [0, 4, 7, 15, 22, 30] {
        assert_matches_gltf(&b, &poses[k], "Bend", k as f64 / 30.0);
    }
    // The lower bone has turned 90 degrees about z (and the armature's 30 about y) at the end.
    let want = (arm_r(30.0) * upper_r() * DQuat::from_rotation_z(FRAC_PI_2) * upper_r().inverse()).as_quat();
    assert!(poses[30].rotation[1].dot(want).abs() > 1.0 - 1e-6);
    // None is the first animation; max_frames caps the count.
    assert_eq!(b.poses(None, MODEL_FPS, usize::MAX).unwrap(), poses);
    assert_eq!(b.poses(Some("Bend"), MODEL_FPS, 10).unwrap()[..], poses[..10]);
    assert_eq!(b.poses(Some("Bend"), 10.0, usize::MAX).unwrap().len(), 11);
}

#[test]
fn gltf_sway_animates_a_non_joint_ancestor_by_steps() {
    let b = body();
    let poses = b.poses(Some("Sway"), 30.0, usize::MAX).unwrap();
    assert_eq!(poses.len(), 16, "0.5 s at 30 Hz");
    for k in [0, 5, 7, 8, 14, 15] {
        assert_matches_gltf(&b, &poses[k], "Sway", k as f64 / 30.0);
    }
    // STEP holds a key until the next: frames 7 (0.233 s) and 8 (0.267 s) straddle 0.25 s.
    assert_eq!(poses[0].rotation[1], poses[7].rotation[1]);
    assert_ne!(poses[7].rotation[1], poses[8].rotation[1]);
}

#[test]
fn gltf_unknown_animation_names_the_file_s_animations() {
    let b = body();
    match b.poses(Some("Run"), 30.0, usize::MAX) {
        Err(Error::Parse { format: "gltf", message, .. }) => {
            assert!(message.contains("'Run'") && message.contains("'Bend'") && message.contains("'Sway'"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(b.poses(None, 0.0, 10), Err(Error::OutOfRange { what: "frame rate", .. })));
    assert!(matches!(b.poses(None, 30.0, 0), Err(Error::OutOfRange { what: "max frames", .. })));
    let mut d = build(&raw());
    d.json.as_object_mut().unwrap().remove("animations");
    let b = GltfBody::from_slice(&d.gltf()).unwrap();
    assert!(b.animations.is_empty());
    assert!(matches!(b.poses(None, 30.0, 10), Err(Error::Empty { .. })));
}

#[test]
fn gltf_glb_and_external_buffer_read_the_same_body() {
    let d = build(&raw());
    let a = body();
    let g = GltfBody::from_slice(&d.glb()).unwrap();
    assert_eq!(
        (&g.positions, &g.triangles, &g.skeleton, &g.weights),
        (&a.positions, &a.triangles, &a.skeleton, &a.weights)
    );
    assert_eq!(g.poses(Some("Bend"), 30.0, 100).unwrap(), a.poses(Some("Bend"), 30.0, 100).unwrap());

    // A .gltf with its buffer in a file beside it (with a percent-encoded name).
    let dir = std::env::temp_dir().join(format!("hood-gltf-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut j = d.json.clone();
    j["buffers"] = json!([{ "byteLength": d.bin.len(), "uri": "arm%20data.bin" }]);
    std::fs::write(dir.join("arm data.bin"), &d.bin).unwrap();
    let text = serde_json::to_vec(&j).unwrap();
    std::fs::write(dir.join("arm.gltf"), &text).unwrap();
    let e = GltfBody::read(dir.join("arm.gltf")).unwrap();
    assert_eq!((&e.positions, &e.weights), (&a.positions, &a.weights));
    // From memory, an external buffer cannot be found.
    let err = GltfBody::from_slice(&text).unwrap_err();
    assert!(matches!(&err, Error::Parse { message, .. } if message.contains("arm%20data.bin")), "{err}");
    let missing = GltfBody::read(dir.join("nothing.glb")).unwrap_err();
    assert!(matches!(missing, Error::Io { .. }));
    std::fs::remove_dir_all(&dir).ok();
}

fn parse_message(bytes: &[u8]) -> String {
    match GltfBody::from_slice(bytes) {
        Err(Error::Parse { format: "gltf", message, .. }) => message,
        other => panic!("expected a glTF parse error, got {:?}", other.map(|b| b.positions.len())),
    }
}

#[test]
fn gltf_non_rigid_joints_are_refused() {
    // A non-uniform scale on a joint.
    let mut d = build(&raw());
    d.json["nodes"][2]["scale"] = json!([1.0, 2.0, 1.0]);
    let m = parse_message(&d.gltf());
    assert!(m.contains("'Lower'") && m.contains("not a rotation"), "{m}");
    // ... or on the armature (the uniform scale is fine, as above).
    let mut d = build(&raw());
    d.json["nodes"][0]["scale"] = json!([0.01, 0.01, 0.02]);
    let m = parse_message(&d.gltf());
    assert!(m.contains("not a rotation"), "{m}");
    // A mirror.
    let mut d = build(&raw());
    d.json["nodes"][0]["scale"] = json!([-0.01, 0.01, 0.01]);
    let m = parse_message(&d.gltf());
    assert!(m.contains("not a rotation"), "{m}");
    // An animated non-uniform scale is refused when sampled, naming the joint and the time.
    let mut d = build(&raw());
    let s = d.floats(&[0.01, 0.01, 0.01, 0.01, 0.02, 0.01], "VEC3", 3);
    let sampler_input = d.json["animations"][1]["samplers"][2]["input"].clone();
    d.json["animations"][1]["samplers"][2] = json!({"input": sampler_input, "output": s});
    let b = GltfBody::from_slice(&d.gltf()).unwrap();
    assert!(b.poses(Some("Bend"), 30.0, usize::MAX).is_ok());
    match b.poses(Some("Sway"), 30.0, usize::MAX) {
        Err(Error::Parse { message, .. }) => {
            assert!(message.contains("'Sway'") && message.contains(" s "), "{message}")
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn gltf_out_of_range_indices_are_refused() {
    let mut r = raw();
    r.indices[5] = 99;
    let m = parse_message(&build(&r).gltf());
    assert!(m.contains("names vertex 99"), "{m}");

    let mut r = raw();
    r.joints0[3] = [7, 0, 0, 0];
    let m = parse_message(&build(&r).gltf());
    assert!(m.contains("joint 7"), "{m}");

    // A buffer view past its buffer, an accessor past its view, a missing accessor.
    let mut d = build(&raw());
    d.json["bufferViews"][0]["byteLength"] = json!(1_000_000);
    assert!(parse_message(&d.gltf()).contains("outside buffer"));
    let mut d = build(&raw());
    d.json["accessors"][0]["count"] = json!(21);
    assert!(parse_message(&d.gltf()).contains("past the end"));
    let mut d = build(&raw());
    d.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(999);
    parse_message(&d.gltf());
    let mut d = build(&raw());
    d.json["skins"][0]["joints"] = json!([2, 1, 40]);
    parse_message(&d.gltf());
    // An animation channel on a missing node or sampler, a sampler on a missing accessor (the
    // first a crash the glTF fuzz target found: the crate's validation lets it through and its
    // reader indexes without checking).
    let mut d = build(&raw());
    d.json["animations"][0]["channels"][0]["target"]["node"] = json!(5);
    assert!(parse_message(&d.gltf()).contains("targets node 5"));
    let mut d = build(&raw());
    d.json["animations"][0]["channels"][0]["sampler"] = json!(9);
    assert!(parse_message(&d.gltf()).contains("sampler 9"));
    let mut d = build(&raw());
    d.json["animations"][0]["samplers"][0]["output"] = json!(999);
    assert!(parse_message(&d.gltf()).contains("accessors"));
    // Absurd counts are refused before anything is allocated.
    let mut d = build(&raw());
    d.json["accessors"][0]["count"] = json!(1u64 << 40);
    assert!(matches!(GltfBody::from_slice(&d.gltf()), Err(Error::CapacityExceeded { .. })));
}

#[test]
fn gltf_malformed_content_is_refused() {
    // A vertex without weight.
    let mut r = raw();
    r.weights0[6] = [0.0; 4];
    assert!(parse_message(&build(&r).gltf()).contains("vertex 6 has no positive skin weight"));
    // NaN positions.
    let mut r = raw();
    r.positions[2][1] = f32::NAN;
    assert!(parse_message(&build(&r).gltf()).contains("NaN"));
    // Not triangles.
    let mut d = build(&raw());
    d.json["meshes"][0]["primitives"][0]["mode"] = json!(1);
    assert!(parse_message(&d.gltf()).contains("triangle"));
    // Keys out of order.
    let mut d = build(&raw());
    let t = d.floats(&[0.0, 0.5, 0.4], "SCALAR", 1);
    d.json["animations"][1]["samplers"][0]["input"] = json!(t);
    assert!(parse_message(&d.gltf()).contains("strictly increasing"));
    // The wrong number of cubic outputs.
    let mut d = build(&raw());
    d.json["animations"][0]["samplers"][1]["interpolation"] = json!("LINEAR");
    assert!(parse_message(&d.gltf()).contains("output values"));
    // No skin.
    let mut d = build(&raw());
    d.json["nodes"][3].as_object_mut().unwrap().remove("skin");
    assert!(matches!(GltfBody::from_slice(&d.gltf()), Err(Error::Empty { .. })));
    // Not JSON, a bad GLB header, a JSON syntax error with its line.
    assert!(GltfBody::from_slice(b"").is_err());
    assert!(GltfBody::from_slice(b"glTF\x02\0\0\0\x05\0\0\0").is_err());
    assert!(matches!(GltfBody::from_slice(b"{\n\"asset\": }"), Err(Error::Parse { line: 2, .. })));
}

#[test]
fn gltf_sparse_accessor_overrides_elements() {
    let mut d = build(&raw());
    let idx = d.view(&3u32.to_le_bytes());
    let val = d.view(&bytes_f32(&[1.0, 2.0, 3.0]));
    d.json["accessors"][0]["sparse"] =
        json!({"count": 1, "indices": {"bufferView": idx, "componentType": 5125}, "values": {"bufferView": val}});
    let b = GltfBody::from_slice(&d.gltf()).unwrap();
    assert_eq!(b.positions[3], [0.01, 0.02, 0.03]);
    assert_eq!(b.positions[4], body().positions[4]);
    // A sparse index past the count is refused.
    let bad = d.view(&50u32.to_le_bytes());
    d.json["accessors"][0]["sparse"]["indices"]["bufferView"] = json!(bad);
    assert!(parse_message(&d.gltf()).contains("sparse index 50"));
}

#[test]
fn gltf_damaged_files_give_errors_not_panics() {
    let d = build(&raw());
    let (glb, text) = (d.glb(), d.gltf());
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let try_all = |bytes: &[u8]| {
        if let Ok(b) = GltfBody::from_slice(bytes) {
            let _ = b.poses(None, 30.0, 4);
            let _ = b.scene_pose();
        }
    };
    for n in (0..glb.len()).step_by(7) {
        try_all(&glb[..n]);
    }
    for _ in 0..1500 {
        let mut g = glb.clone();
        for _ in 0..1 + next() % 4 {
            let at = (next() % g.len() as u64) as usize;
            g[at] ^= 1 << (next() % 8);
        }
        try_all(&g);
    }
    for _ in 0..300 {
        let mut t = text.clone();
        let at = (next() % t.len() as u64) as usize;
        t[at] = b"0123456789-.,:{}[]e\" "[(next() % 21) as usize];
        try_all(&t);
    }
}

#[test]
fn gltf_reads_the_file_in_hood_test_glb() {
    let Some(path) = std::env::var_os("HOOD_TEST_GLB") else {
        std::println!("gltf_reads_the_file_in_hood_test_glb: SKIPPED (set HOOD_TEST_GLB to a skinned .glb or .gltf)");
        return;
    };
    let b = GltfBody::read(&path).unwrap();
    std::println!(
        "{}: {} vertices, {} triangles, {} bones, scale {}, animations {:?}",
        std::path::Path::new(&path).display(),
        b.positions.len(),
        b.triangles.len(),
        b.skeleton.len(),
        b.scale(),
        b.animations
    );
    let poses = if b.animations.is_empty() { vec![b.scene_pose().unwrap()] } else { b.poses(None, 30.0, 60).unwrap() };
    for pose in &poses {
        assert!(skinned(&b, pose).iter().flatten().all(|c| c.is_finite()));
    }
}

#[test]
fn gltf_accessors_the_crate_readers_would_panic_on_are_refused() {
    let msg = |d: &Doc| match GltfBody::from_slice(&d.gltf()) {
        Err(e) => std::format!("{e}"),
        Ok(_) => String::from("OK"),
    };
    // POSITION of 16-bit integers (read as floats by the crate's reader).
    let mut d = build(&raw());
    d.json["accessors"][0]["componentType"] = json!(5123);
    let m = msg(&d);
    assert!(m.contains("component type"), "{m}");
    // Weights of a type the crate's reader does not expect (unreachable! there).
    let mut d = build(&raw());
    d.json["accessors"][3]["componentType"] = json!(5120);
    let m = msg(&d);
    assert!(m.contains("component type"), "{m}");
    // A rotation output of u32.
    let mut d = build(&raw());
    let out = d.json["animations"][0]["samplers"][0]["output"].as_u64().unwrap() as usize;
    d.json["accessors"][out]["componentType"] = json!(5125);
    let m = msg(&d);
    assert!(m.contains("component type"), "{m}");
    // Inverse bind matrices as MAT3.
    let mut d = build(&raw());
    let ibm = d.json["skins"][0]["inverseBindMatrices"].as_u64().unwrap() as usize;
    d.json["accessors"][ibm]["type"] = json!("MAT3");
    let m = msg(&d);
    assert!(m.contains("expected Mat4"), "{m}");
    // Counts of zero (an underflow in the crate's reader).
    for a in 0..d.json["accessors"].as_array().unwrap().len() {
        let mut d = build(&raw());
        d.json["accessors"][a]["count"] = json!(0);
        let m = msg(&d);
        assert!(m != "OK", "accessor {a}");
    }
    // A stride shorter than the element.
    let mut d = build(&raw());
    d.json["bufferViews"][0]["byteStride"] = json!(4);
    let m = msg(&d);
    assert!(m.contains("stride 4"), "{m}");
    // Huge offsets.
    let mut d = build(&raw());
    d.json["accessors"][0]["byteOffset"] = json!(u64::MAX - 3);
    assert!(msg(&d).contains("past the end"));
    let mut d = build(&raw());
    d.json["bufferViews"][0]["byteOffset"] = json!(u64::MAX - 3);
    assert!(msg(&d).contains("outside buffer"));
    // Sparse: no element, indices not increasing, a stride shorter than an index.
    let mut base = build(&raw());
    let idx = base.view(&[3u32, 2].map(u32::to_le_bytes).concat());
    let val = base.view(&bytes_f32(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
    base.json["accessors"][0]["sparse"] =
        json!({"count": 2, "indices": {"bufferView": idx, "componentType": 5125}, "values": {"bufferView": val}});
    let m = msg(&base);
    assert!(m.contains("not strictly increasing"), "{m}");
    let mut d = Doc { json: base.json.clone(), bin: base.bin.clone() };
    d.json["accessors"][0]["sparse"]["count"] = json!(0);
    let m = msg(&d);
    assert!(m.contains("0 sparse elements"), "{m}");
    let mut d = Doc { json: base.json.clone(), bin: base.bin.clone() };
    d.json["bufferViews"][idx]["byteStride"] = json!(4);
    d.json["accessors"][0]["sparse"]["indices"]["componentType"] = json!(5125);
    d.json["bufferViews"][val]["byteStride"] = json!(8);
    let m = msg(&d);
    assert!(m.contains("stride 8"), "{m}");
    // A sparse accessor without a view: zeros, with the sparse values.
    let mut d = build(&raw());
    let idx = d.view(&[0u8, 1, 2, 3]);
    let w: Vec<f32> = [[1.0f32, 0.0, 0.0, 0.0]; 4].concat();
    let val = d.view(&bytes_f32(&w));
    d.json["accessors"][3].as_object_mut().unwrap().remove("bufferView");
    d.json["accessors"][3]["sparse"] =
        json!({"count": 4, "indices": {"bufferView": idx, "componentType": 5121}, "values": {"bufferView": val}});
    let m = msg(&d);
    assert!(m.contains("vertex 4 has no positive skin weight"), "{m}");
    // GLB: a declared length under the header, an unsupported version.
    let mut g = build(&raw()).glb();
    g[8..12].copy_from_slice(&5u32.to_le_bytes());
    assert!(parse_message(&g).contains("declares 5 bytes"));
    let mut g = build(&raw()).glb();
    g[4] = 1;
    assert!(parse_message(&g).contains("version 1"));
    // Trailing bytes after the declared length are ignored.
    let mut g = build(&raw()).glb();
    g.extend_from_slice(b"trailing");
    assert_eq!(GltfBody::from_slice(&g).unwrap().positions, body().positions);
    // Unpadded base64 and a percent-encoded data URI.
    let d = build(&raw());
    let mut j = d.json.clone();
    j["buffers"] = json!([{"byteLength": d.bin.len(), "uri": std::format!("data:,{}", d.bin.iter().map(|b| std::format!("%{b:02X}")).collect::<String>())}]);
    assert_eq!(GltfBody::from_slice(&serde_json::to_vec(&j).unwrap()).unwrap().positions, body().positions);
    assert_eq!(base64_decode("aGVsbG8").unwrap(), b"hello");
}

/// A sleeve band around the arm's lower end, worn through the "Bend" clip by
/// [`crate::scene::gltf_wearing`]: the scene has one body frame per pose, each the body skinned
/// at that pose, and the pinned band rides rigidly with the joint it sits on.
#[test]
fn gltf_body_wears_a_garment_through_its_animation() {
    use crate::scene::own::{GarmentOptions, OwnGarment, Pins};
    let b = body();
    // Rings 3 and 4 of the arm (vertices 12..20), pushed 2 cm out from the ring's axis.
    let source: Vec<usize> = (12..20).collect();
    let centre =
        |ring: usize| (0..4).map(|c| DVec3::from(b.positions[ring * 4 + c].map(f64::from))).sum::<DVec3>() / 4.0;
    let band: Vec<[f32; 3]> = source
        .iter()
        .map(|&v| {
            let (p, c) = (DVec3::from(b.positions[v].map(f64::from)), centre(v / 4));
            (c + (p - c) * 1.5).as_vec3().to_array()
        })
        .collect();
    let mut triangles = Vec::new();
    for c in 0..4u32 {
        let (a, d) = (c, (c + 1) % 4);
        triangles.extend_from_slice(&[[a, d, d + 4], [a, d + 4, a + 4]]);
    }
    let options = GarmentOptions { pins: Pins::Vertices((0..8).collect()), ..Default::default() };
    let own = OwnGarment { name: "band", positions: &band, triangles: &triangles, options: &options };
    let scene = crate::scene::gltf_wearing(&b, Some("Bend"), own, 40).unwrap();
    let poses = b.poses(Some("Bend"), MODEL_FPS, 40).unwrap();
    assert_eq!(scene.n_frames(), poses.len());
    assert!(scene.name.contains("band on Bend"), "{}", scene.name);
    let mut x = vec![[0.0; 3]; 8];
    for f in [0, poses.len() / 2, poses.len() - 1] {
        let body_f = skinned(&b, &poses[f]);
        for (got, want) in scene.body_frame(f).iter().zip(&body_f) {
            assert!((0..3).all(|k| (got[k] - want[k]).abs() < 1e-6), "frame {f}: {got:?} vs {want:?}");
        }
        scene.skinned_garment(f, &mut x).unwrap();
        for (k, &v) in source.iter().enumerate() {
            let d = |p: [f32; 3], q: [f32; 3]| (glam::Vec3::from(p) - glam::Vec3::from(q)).length();
            let (now, rest) = (d(x[k], body_f[v]), d(scene.garment.rest()[k], b.positions[v]));
            assert!((now - rest).abs() < 5e-3, "frame {f}, band vertex {k}: {now} m from the arm, {rest} m at rest");
        }
    }
}
