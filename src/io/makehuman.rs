//! MakeHuman (MPFB2) assets: the `base.obj` body with its groups, the rig JSON (`rig.cmu_mb.json`,
//! including the CUBE strategy: a joint sits at the centroid of the named `joint-*` group, and the
//! MEAN strategy: the mean of listed vertices), the weights JSON and the pose JSON (T-pose).
//!
//! Units and frames: base.obj is in decimetres, y up, facing +z; everything returned here is in
//! **metres**, y up, shifted vertically so that the lowest vertex of the `body` group is at
//! y = 0. The JSON files use Blender's frame (z up; `(x, y, z)` there is `(x, -z, y)` here);
//! bone rolls and pose rotations are converted accordingly.

use crate::error::{Error, Result};
use crate::io::json::{self, Value};
use crate::io::obj::Obj;
use crate::mesh::repair::CompactedMesh;
use crate::rig::{BoneDesc, Skeleton, SkinWeights};
use glam::{Quat, Vec3};
use std::format;
use std::path::Path;
use std::string::{String, ToString};
use std::vec::Vec;

/// Metres per base.obj unit.
pub const METRES_PER_UNIT: f32 = 0.1;

/// The loaded MakeHuman body.
#[derive(Clone, Debug)]
pub struct MakeHuman {
    /// The whole base mesh (body, helpers, joint cubes) in metres, feet of `body` on y = 0.
    pub obj: Obj,
    /// The `body` group alone (its `remap` maps to `obj` vertex indices).
    pub body: CompactedMesh,
    /// The rig, metres.
    pub skeleton: Skeleton,
    /// Skinning weights of every base-mesh vertex (helpers included: garments bind to them).
    pub weights: SkinWeights,
    /// Skinning weights of the `body` group's vertices.
    pub body_weights: SkinWeights,
    /// Local rotations (one per bone) bringing the A-pose rig into the CMU T-pose.
    pub t_pose: Vec<Quat>,
    /// The vertical shift applied after scaling to metres (metres).
    pub floor_shift: f32,
}

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

impl MakeHuman {
    /// Loads `base.obj`, `rig.cmu_mb.json`, `weights.cmu_mb.json` and `cmu_mb_t-pose.json` from
    /// `dir` (the assets' `body/` folder).
    pub fn load(dir: impl AsRef<Path>) -> Result<MakeHuman> {
        let dir = dir.as_ref();
        let mut obj = Obj::read(dir.join("base.obj"))?;
        obj.scale(METRES_PER_UNIT);
        let body_tris = obj.triangles_in_groups(&["body"])?;
        let lowest = body_tris
            .iter()
            .flat_map(|&t| obj.triangles[t])
            .map(|v| obj.positions[v as usize][1])
            .fold(f32::INFINITY, f32::min);
        let floor_shift = -lowest;
        for p in &mut obj.positions {
            p[1] += floor_shift;
        }
        let body = obj.extract_groups(&["body"])?;
        let skeleton = parse_rig(&read_text(&dir.join("rig.cmu_mb.json"))?, &obj, floor_shift)?;
        let weights = parse_weights(&read_text(&dir.join("weights.cmu_mb.json"))?, &skeleton, obj.positions.len())?;
        let body_weights = weights.select(&body.remap.new_to_old);
        let t_pose = parse_pose(&read_text(&dir.join("cmu_mb_t-pose.json"))?, &skeleton)?;
        Ok(MakeHuman { obj, body, skeleton, weights, body_weights, t_pose, floor_shift })
    }
}

/// Blender (z up) to `hood` (y up) for directions: `(x, y, z) -> (x, z, -y)`.
fn blender_to_y_up() -> Quat {
    Quat::from_rotation_x(-core::f32::consts::FRAC_PI_2)
}

fn jerr(msg: impl Into<String>) -> Error {
    Error::parse("json", 0, msg)
}

/// Centroid of the vertices of group `name` (metres, as `obj`).
fn group_centroid(obj: &Obj, name: &str) -> Result<Vec3> {
    let tris = obj.triangles_in_groups(&[name])?;
    let mut seen = std::vec![false; obj.positions.len()];
    let (mut sum, mut n) = (glam::DVec3::ZERO, 0usize);
    for t in tris {
        for v in obj.triangles[t] {
            if !std::mem::replace(&mut seen[v as usize], true) {
                sum += Vec3::from(obj.positions[v as usize]).as_dvec3();
                n += 1;
            }
        }
    }
    Ok((sum / n.max(1) as f64).as_vec3())
}

/// One head or tail location of the rig JSON.
fn joint_position(j: &Value, obj: &Obj, floor_shift: f32, bone: &str) -> Result<Vec3> {
    let strategy = j.get("strategy").and_then(Value::as_str).unwrap_or("");
    match strategy {
        "CUBE" => {
            let cube = j
                .get("cube_name")
                .and_then(Value::as_str)
                .ok_or_else(|| jerr(format!("{bone}: CUBE without cube_name")))?;
            group_centroid(obj, cube)
        }
        "MEAN" => {
            let ids = j
                .get("vertex_indices")
                .and_then(json::f64_vec)
                .ok_or_else(|| jerr(format!("{bone}: MEAN without vertex_indices")))?;
            if ids.is_empty() {
                return Err(jerr(format!("{bone}: MEAN with no vertex")));
            }
            let mut sum = Vec3::ZERO;
            for &i in &ids {
                let p = obj
                    .positions
                    .get(i as usize)
                    .filter(|_| i >= 0.0 && i.fract() == 0.0)
                    .ok_or_else(|| jerr(format!("{bone}: vertex index {i} out of range")))?;
                sum += Vec3::from(*p);
            }
            Ok(sum / ids.len() as f32)
        }
        _ => {
            let d = j
                .get("default_position")
                .and_then(json::f64_vec)
                .filter(|d| d.len() == 3)
                .ok_or_else(|| jerr(format!("{bone}: no usable position (strategy '{strategy}')")))?;
            // Blender metres, z up.
            Ok(Vec3::new(d[0] as f32, d[2] as f32 + floor_shift, -d[1] as f32))
        }
    }
}

/// Parses a MakeHuman rig JSON (bone name -> head, tail, parent, roll) against the base mesh
/// `obj` (metres, already shifted by `floor_shift`).
pub fn parse_rig(text: &str, obj: &Obj, floor_shift: f32) -> Result<Skeleton> {
    let doc = json::parse(text)?;
    let bones = doc.as_object().ok_or_else(|| jerr("rig: not an object"))?;
    let c = blender_to_y_up();
    let mut list = Vec::with_capacity(bones.len());
    for (name, b) in bones {
        let head =
            joint_position(b.get("head").ok_or_else(|| jerr(format!("{name}: no head")))?, obj, floor_shift, name)?;
        let tail =
            joint_position(b.get("tail").ok_or_else(|| jerr(format!("{name}: no tail")))?, obj, floor_shift, name)?;
        let roll = b.get("roll").and_then(Value::as_f64).unwrap_or(0.0) as f32;
        let parent = b.get("parent").and_then(Value::as_str).map(str::to_string);
        // Blender's bone matrix (shortest arc from its +y, then roll) expressed in y-up axes.
        let d = tail - head;
        let arc = if d.length_squared() > 0.0 { Quat::from_rotation_arc(-Vec3::Z, d.normalize()) } else { c };
        let frame = (arc * c * Quat::from_rotation_y(roll)).normalize();
        let desc = BoneDesc { name: name.clone(), parent: None, head: head.into(), tail: tail.into(), frame };
        list.push((desc, parent));
    }
    Skeleton::from_named(list)
}

/// Parses a MakeHuman weights JSON (`{"weights": {bone: [[vertex, weight], ...]}}`) for a mesh
/// of `n_vertices` vertices; unknown bones are an error, each vertex keeps its 4 largest weights.
pub fn parse_weights(text: &str, skel: &Skeleton, n_vertices: usize) -> Result<SkinWeights> {
    let doc = json::parse(text)?;
    let w = doc.get("weights").and_then(Value::as_object).ok_or_else(|| jerr("weights: no 'weights' object"))?;
    let mut triples = Vec::new();
    for (bone, list) in w {
        let b = skel.find(bone).ok_or_else(|| jerr(format!("weights: unknown bone '{bone}'")))?;
        for pair in list.as_array().ok_or_else(|| jerr(format!("weights of '{bone}' are not a list")))? {
            let p = json::f64_vec(pair)
                .filter(|p| p.len() == 2)
                .ok_or_else(|| jerr(format!("weights of '{bone}': bad pair")))?;
            if p[0] < 0.0 || p[0].fract() != 0.0 {
                return Err(jerr(format!("weights of '{bone}': bad vertex index {}", p[0])));
            }
            triples.push((p[0] as u32, b as u16, p[1] as f32));
        }
    }
    SkinWeights::from_triples(n_vertices, skel.len(), &triples, 4)
}

/// Parses a MakeHuman pose JSON (`bone_rotations`: XYZ Euler angles in radians in each bone's
/// local frame) into local rotations, one per bone (identity for bones not listed).
pub fn parse_pose(text: &str, skel: &Skeleton) -> Result<Vec<Quat>> {
    let doc = json::parse(text)?;
    let mut local = std::vec![Quat::IDENTITY; skel.len()];
    let rots = doc.get("bone_rotations").and_then(Value::as_object).ok_or_else(|| jerr("pose: no 'bone_rotations'"))?;
    for (bone, e) in rots {
        let b = skel.find(bone).ok_or_else(|| jerr(format!("pose: unknown bone '{bone}'")))?;
        let e =
            json::f64_vec(e).filter(|e| e.len() == 3).ok_or_else(|| jerr(format!("pose: bad angles for '{bone}'")))?;
        // Blender's XYZ Euler mode applies X first: R = Rz * Ry * Rx.
        local[b] = Quat::from_rotation_z(e[2] as f32)
            * Quat::from_rotation_y(e[1] as f32)
            * Quat::from_rotation_x(e[0] as f32);
    }
    Ok(local)
}
