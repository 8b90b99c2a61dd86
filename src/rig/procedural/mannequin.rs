//! The procedural mannequin: a rig with the CMU MotionBuilder bone names (so CMU clips retarget
//! onto it), a smooth closed body mesh extracted from a blended signed distance function by
//! marching tetrahedra, and skinning weights diffused over the mesh from the nearest bone.

use super::sdf::{Primitive, Shape};
use crate::error::{Error, Result};
use crate::rig::{rest_frame, BoneDesc, Skeleton, SkinWeights};
use alloc::collections::BTreeMap;
use alloc::string::ToString;
use alloc::vec;
use alloc::vec::Vec;
use glam::Vec3;

/// Default grid spacing of the mesh extraction, metres (about 9,500 vertices).
pub const DEFAULT_SPACING: f32 = 0.027;

/// A closed, smooth body mesh with a rig and skinning weights. Metres, y up, facing +z, feet on
/// y = 0, A-pose.
#[derive(Clone, Debug)]
pub struct Mannequin {
    skeleton: Skeleton,
    weights: SkinWeights,
    rest: Vec<[f32; 3]>,
    faces: Vec<[u32; 3]>,
    shape: Shape,
    arm: Vec<bool>,
}

const S: f32 = core::f32::consts::FRAC_1_SQRT_2;

/// `(name, parent, head, tail)` of the right-handed half and the spine; the right side mirrors
/// the left in x.
fn bone_table() -> Vec<(&'static str, Option<&'static str>, Vec3, Vec3)> {
    let v = Vec3::new;
    let pelvis = v(0.0, 0.95, 0.0);
    let mut t = vec![
        ("Hips", None, pelvis, v(0.0, 1.05, 0.0)),
        ("LowerBack", Some("Hips"), v(0.0, 1.05, 0.0), v(0.0, 1.18, 0.0)),
        ("Spine", Some("LowerBack"), v(0.0, 1.18, 0.0), v(0.0, 1.32, 0.0)),
        ("Spine1", Some("Spine"), v(0.0, 1.32, 0.0), v(0.0, 1.46, 0.0)),
        ("Neck", Some("Spine1"), v(0.0, 1.46, 0.0), v(0.0, 1.53, 0.0)),
        ("Neck1", Some("Neck"), v(0.0, 1.53, 0.0), v(0.0, 1.59, 0.0)),
        ("Head", Some("Neck1"), v(0.0, 1.59, 0.0), v(0.0, 1.76, 0.0)),
    ];
    let shoulder = v(0.17, 1.43, 0.0);
    let down = v(S, -S, 0.0);
    let elbow = shoulder + down * 0.28;
    let wrist = elbow + down * 0.25;
    let hip = v(0.09, 0.90, 0.0);
    let knee = v(0.10, 0.50, 0.01);
    let ankle = v(0.10, 0.085, -0.01);
    let ball = v(0.10, 0.025, 0.12);
    let left: [(&str, &str, Vec3, Vec3); 9] = [
        ("LeftShoulder", "Spine1", v(0.03, 1.42, 0.0), shoulder),
        ("LeftArm", "LeftShoulder", shoulder, elbow),
        ("LeftForeArm", "LeftArm", elbow, wrist),
        ("LeftHand", "LeftForeArm", wrist, wrist + down * 0.09),
        ("LHipJoint", "Hips", pelvis, hip),
        ("LeftUpLeg", "LHipJoint", hip, knee),
        ("LeftLeg", "LeftUpLeg", knee, ankle),
        ("LeftFoot", "LeftLeg", ankle, ball),
        ("LeftToeBase", "LeftFoot", ball, v(0.10, 0.02, 0.19)),
    ];
    let right_names = [
        ("RightShoulder", "Spine1"),
        ("RightArm", "RightShoulder"),
        ("RightForeArm", "RightArm"),
        ("RightHand", "RightForeArm"),
        ("RHipJoint", "Hips"),
        ("RightUpLeg", "RHipJoint"),
        ("RightLeg", "RightUpLeg"),
        ("RightFoot", "RightLeg"),
        ("RightToeBase", "RightFoot"),
    ];
    let m = |p: Vec3| v(-p.x, p.y, p.z);
    for (n, p, h, tl) in left {
        t.push((n, Some(p), h, tl));
    }
    for ((_, _, h, tl), (n, p)) in left.iter().zip(right_names) {
        t.push((n, Some(p), m(*h), m(*tl)));
    }
    t
}

fn build_skeleton() -> Skeleton {
    let table = bone_table();
    let descs = table
        .iter()
        .map(|(name, parent, head, tail)| BoneDesc {
            name: name.to_string(),
            parent: parent.map(|p| table.iter().position(|b| b.0 == p).unwrap_or(0)),
            head: (*head).into(),
            tail: (*tail).into(),
            frame: rest_frame((*head).into(), (*tail).into(), 0.0, Vec3::Y),
        })
        .collect();
    // The table lists parents first, so this cannot fail.
    Skeleton::new(descs).unwrap_or_else(|_| unreachable!("the mannequin table lists parents first"))
}

/// The blended primitives, each with its bone; the flag marks arm pieces.
fn build_shape(skel: &Skeleton) -> (Shape, Vec<bool>) {
    let v = Vec3::new;
    let b = |n: &str| skel.find(n).unwrap_or(0);
    let head = |n: &str| skel.bones()[b(n)].head;
    let tail = |n: &str| skel.bones()[b(n)].tail;
    let cap = |a: Vec3, bb: Vec3, ra: f32, rb: f32| Primitive::Capsule { a, b: bb, ra, rb };
    let ell = |c: Vec3, r: Vec3| Primitive::Ellipsoid { c, r };
    let mut prims = vec![
        (ell(v(0.0, 0.93, -0.005), v(0.165, 0.12, 0.11)), b("Hips"), false),
        (ell(v(0.0, 1.10, 0.0), v(0.145, 0.12, 0.095)), b("LowerBack"), false),
        (ell(v(0.0, 1.24, 0.0), v(0.155, 0.12, 0.10)), b("Spine"), false),
        (ell(v(0.0, 1.35, 0.005), v(0.17, 0.12, 0.11)), b("Spine1"), false),
        (ell(v(0.0, 1.43, -0.01), v(0.16, 0.06, 0.085)), b("Spine1"), false),
        (cap(v(0.0, 1.42, -0.005), v(0.0, 1.60, 0.0), 0.056, 0.05), b("Neck"), false),
        (ell(v(0.0, 1.67, 0.015), v(0.075, 0.105, 0.095)), b("Head"), false),
    ];
    for side in ["Left", "Right"] {
        let n = |s: &str| alloc::format!("{side}{s}");
        let sx = if side == "Left" { 1.0 } else { -1.0 };
        prims.push((ell(v(0.13 * sx, 1.42, -0.005), v(0.07, 0.05, 0.055)), b(&n("Shoulder")), false));
        prims.push((cap(head(&n("Arm")), tail(&n("Arm")), 0.048, 0.038), b(&n("Arm")), true));
        prims.push((cap(head(&n("ForeArm")), tail(&n("ForeArm")), 0.037, 0.027), b(&n("ForeArm")), true));
        prims.push((cap(head(&n("Hand")), tail(&n("Hand")), 0.03, 0.024), b(&n("Hand")), true));
        prims.push((cap(head(&n("UpLeg")), tail(&n("UpLeg")), 0.078, 0.052), b(&n("UpLeg")), false));
        prims.push((cap(head(&n("Leg")), tail(&n("Leg")), 0.05, 0.032), b(&n("Leg")), false));
        prims.push((cap(v(0.10 * sx, 0.045, -0.03), v(0.10 * sx, 0.03, 0.15), 0.04, 0.028), b(&n("Foot")), false));
        prims.push((cap(v(0.10 * sx, 0.025, 0.14), v(0.10 * sx, 0.022, 0.2), 0.025, 0.02), b(&n("ToeBase")), false));
    }
    let arm = prims.iter().map(|p| p.2).collect();
    (Shape { prims: prims.into_iter().map(|(p, b, _)| (p, b)).collect(), blend: 0.025 }, arm)
}

impl Default for Mannequin {
    fn default() -> Self {
        Self::new()
    }
}

impl Mannequin {
    /// The mannequin at [`DEFAULT_SPACING`].
    pub fn new() -> Mannequin {
        Self::with_spacing(DEFAULT_SPACING).unwrap_or_else(|_| unreachable!("the default spacing is valid"))
    }

    /// The mannequin with the mesh extracted on a grid of spacing `h` metres (vertex count about
    /// `3.6 / h^2`).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] unless `0.005 <= h <= 0.05`.
    pub fn with_spacing(h: f32) -> Result<Mannequin> {
        if !(0.005..=0.05).contains(&h) {
            return Err(Error::OutOfRange { what: "mannequin grid spacing", index: 0 });
        }
        let skeleton = build_skeleton();
        let (shape, arm) = build_shape(&skeleton);
        let (mut rest, faces) =
            marching_tetrahedra(&shape, Vec3::new(-0.72, -0.04, -0.18), Vec3::new(0.72, 1.84, 0.28), h);
        smooth_onto_surface(&shape, &mut rest, &faces, 4);
        let weights = diffused_bone_weights(&shape, &skeleton, &rest, &faces, 12)?;
        Ok(Mannequin { skeleton, weights, rest, faces, shape, arm })
    }

    /// The rig.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }
    /// Skinning weights of the body vertices.
    pub fn weights(&self) -> &SkinWeights {
        &self.weights
    }
    /// Rest vertex positions, metres.
    pub fn rest(&self) -> &[[f32; 3]] {
        &self.rest
    }
    /// Triangles, counter-clockwise seen from outside.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
    /// Signed distance of `p` to the analytic rest shape (the mesh follows it to within about
    /// `h^2 / 10`), metres, negative inside.
    pub fn signed_distance(&self, p: [f32; 3]) -> f32 {
        self.shape.distance(p.into())
    }
    /// Signed distance to the shape without the arms (for garments that hang around the trunk).
    pub(crate) fn trunk_distance(&self, p: Vec3) -> f32 {
        self.shape.distance_filtered(p, |i| !self.arm[i])
    }
}

/// The zero level set of `shape` over the box `lo..hi` on a grid of spacing `h`, by marching
/// tetrahedra (6 tetrahedra per cube around its main diagonal, face-compatible between cubes),
/// so the result is a closed 2-manifold when the shape stays inside the box.
fn marching_tetrahedra(shape: &Shape, lo: Vec3, hi: Vec3, h: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let n = ((hi - lo) / h).ceil().as_uvec3() + glam::UVec3::ONE;
    let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
    let id = |i: usize, j: usize, k: usize| (k * ny + j) * nx + i;
    let node = |i: usize, j: usize, k: usize| lo + Vec3::new(i as f32, j as f32, k as f32) * h;
    let mut f = vec![0.0f32; nx * ny * nz];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let d = shape.distance(node(i, j, k));
                // No value exactly zero: the level set then never passes through a node.
                f[id(i, j, k)] = if d.abs() < 1e-7 { 1e-7 } else { d };
            }
        }
    }
    let corners = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]];
    // Kuhn triangulation: paths 000 -> e_a -> e_a + e_b -> 111 (corner indices as bit masks).
    let axes = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut verts: Vec<[f32; 3]> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut on_edge: BTreeMap<(usize, usize), u32> = BTreeMap::new();
    let mut edge_vertex = |a: usize, pa: Vec3, b: usize, pb: Vec3, f: &[f32], verts: &mut Vec<[f32; 3]>| -> u32 {
        let key = (a.min(b), a.max(b));
        *on_edge.entry(key).or_insert_with(|| {
            let t = f[a] / (f[a] - f[b]);
            verts.push((pa + (pb - pa) * t).into());
            (verts.len() - 1) as u32
        })
    };
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let cid: [usize; 8] = core::array::from_fn(|c| {
                    let [dx, dy, dz] = corners[c];
                    id(i + dx, j + dy, k + dz)
                });
                if cid.iter().all(|&c| f[c] < 0.0) || cid.iter().all(|&c| f[c] > 0.0) {
                    continue;
                }
                for ax in axes {
                    let m1 = 1 << ax[0];
                    let m2 = m1 | (1 << ax[1]);
                    let tet = [0usize, m1, m2, 7];
                    let g = tet.map(|c| cid[c]);
                    let p = tet.map(|c| {
                        let [dx, dy, dz] = corners[c];
                        node(i + dx, j + dy, k + dz)
                    });
                    let inside: Vec<usize> = (0..4).filter(|&q| f[g[q]] < 0.0).collect();
                    let outside: Vec<usize> = (0..4).filter(|&q| f[g[q]] >= 0.0).collect();
                    let tris: Vec<[(usize, usize); 3]> = match (inside.len(), outside.len()) {
                        (1, 3) => {
                            let a = inside[0];
                            vec![[(a, outside[0]), (a, outside[1]), (a, outside[2])]]
                        }
                        (3, 1) => {
                            let a = outside[0];
                            vec![[(inside[0], a), (inside[1], a), (inside[2], a)]]
                        }
                        (2, 2) => {
                            let (a, b, c, d) = (inside[0], inside[1], outside[0], outside[1]);
                            vec![[(a, c), (a, d), (b, d)], [(a, c), (b, d), (b, c)]]
                        }
                        _ => continue,
                    };
                    let centre_out = outside.iter().map(|&q| p[q]).sum::<Vec3>() / outside.len() as f32;
                    let centre_in = inside.iter().map(|&q| p[q]).sum::<Vec3>() / inside.len() as f32;
                    let outward = centre_out - centre_in;
                    for tri in tris {
                        let ids = tri.map(|(a, b)| edge_vertex(g[a], p[a], g[b], p[b], &f, &mut verts));
                        let q = ids.map(|v| Vec3::from(verts[v as usize]));
                        let normal = (q[1] - q[0]).cross(q[2] - q[0]);
                        faces.push(if normal.dot(outward) >= 0.0 { ids } else { [ids[0], ids[2], ids[1]] });
                    }
                }
            }
        }
    }
    (verts, faces)
}

/// Vertex neighbours from triangles, as CSR `(offsets, neighbours)`.
pub(crate) fn vertex_neighbours(n: usize, faces: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(faces.len() * 6);
    for f in faces {
        for k in 0..3 {
            pairs.push((f[k], f[(k + 1) % 3]));
            pairs.push((f[(k + 1) % 3], f[k]));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    let mut offsets = vec![0u32; n + 1];
    for &(a, _) in &pairs {
        offsets[a as usize + 1] += 1;
    }
    for v in 0..n {
        offsets[v + 1] += offsets[v];
    }
    (offsets, pairs.into_iter().map(|p| p.1).collect())
}

/// Damped Laplacian smoothing, each pass followed by Newton projection back onto the surface:
/// evens out the slivers of marching tetrahedra without changing the connectivity.
fn smooth_onto_surface(shape: &Shape, pos: &mut [[f32; 3]], faces: &[[u32; 3]], passes: usize) {
    let (off, nb) = vertex_neighbours(pos.len(), faces);
    let mut next = pos.to_vec();
    for _ in 0..passes {
        for v in 0..pos.len() {
            let (a, b) = (off[v] as usize, off[v + 1] as usize);
            let mean = nb[a..b].iter().map(|&u| Vec3::from(pos[u as usize])).sum::<Vec3>() / (b - a).max(1) as f32;
            let mut p = Vec3::from(pos[v]).lerp(mean, 0.5);
            for _ in 0..3 {
                let g = shape.gradient(p);
                let g2 = g.length_squared();
                if g2 < 1e-12 {
                    break;
                }
                p -= g * (shape.distance(p) / g2);
            }
            next[v] = p.into();
        }
        pos.copy_from_slice(&next);
    }
}

/// Weights: each vertex starts fully on the bone of its nearest primitive, then `passes`
/// rounds of averaging with its mesh neighbours blend across joints (along the surface, so an
/// arm never borrows from the torso beside it); at most 4 influences are kept.
fn diffused_bone_weights(
    shape: &Shape,
    skel: &Skeleton,
    pos: &[[f32; 3]],
    faces: &[[u32; 3]],
    passes: usize,
) -> Result<SkinWeights> {
    let nb = skel.len();
    let n = pos.len();
    let mut w = vec![0.0f32; n * nb];
    for v in 0..n {
        w[v * nb + shape.nearest_bone(pos[v].into())] = 1.0;
    }
    let (off, nbr) = vertex_neighbours(n, faces);
    let mut next = w.clone();
    for _ in 0..passes {
        for v in 0..n {
            let (a, b) = (off[v] as usize, off[v + 1] as usize);
            let k = 0.5 / (b - a).max(1) as f32;
            for bone in 0..nb {
                let mut s = 0.5 * w[v * nb + bone];
                for &u in &nbr[a..b] {
                    s += k * w[u as usize * nb + bone];
                }
                next[v * nb + bone] = s;
            }
        }
        core::mem::swap(&mut w, &mut next);
    }
    SkinWeights::from_dense(nb, &w, 4)
}
