//! The skeleton of a skin: the node tree, the joints ordered parents first, the uniform scale
//! factored out of their skinning matrices, the rest bones (heads, tails, frames) and the poses
//! of world matrices.

use super::{accessor, buffers, err, MAX_JOINTS, RIGID_TOLERANCE};
use crate::error::{Error, Result};
use crate::limits;
use crate::rig::{BoneDesc, Pose, Skeleton};
use glam::{DMat3, DMat4, DQuat, DVec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::scene::Transform;
use std::borrow::Cow;
use std::format;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

/// The skeleton of a skin, as [`read`] gives it.
pub(super) struct Bones {
    /// One bone per joint, parents first.
    pub(super) skeleton: Skeleton,
    pub(super) rig: Rig,
    /// The bone of each joint of the skin (in the skin's order).
    pub(super) bone_of_joint: Vec<usize>,
}

/// The skeleton of `skin`: bones parents first, named after their nodes, with the uniform scale
/// of the skinning matrices at the file's rest factored out (refusing joints whose skinning
/// matrix is not a rotation times that scale).
pub(super) fn read(doc: &gltf::Document, skin: &gltf::Skin, buffers: &[Cow<'_, [u8]>]) -> Result<Bones> {
    let (parent, depth) = node_tree(doc)?;
    let rest: Vec<Local> = doc.nodes().map(|n| local_of(&n)).collect::<Result<_>>()?;
    let joint_nodes: Vec<usize> = skin.joints().map(|n| n.index()).collect();
    let nj = joint_nodes.len();
    if nj == 0 {
        return Err(Error::Empty { what: "glTF skin joints" });
    }
    limits::within("glTF skin joints", nj, MAX_JOINTS)?;
    let mut joint_of_node: Vec<Option<usize>> = vec![None; rest.len()];
    for (j, &n) in joint_nodes.iter().enumerate() {
        if joint_of_node[n].replace(j).is_some() {
            return Err(err(format!("skin {}: node {n} is listed twice among its joints", skin.index())));
        }
    }
    let ibm: Vec<DMat4> = match skin.inverse_bind_matrices() {
        Some(acc) => {
            let what = accessor::label("inverse bind matrices", &acc);
            let n = accessor::check(buffers, &acc, &what, Dimensions::Mat4, &[DataType::F32], MAX_JOINTS)?;
            let reader = skin.reader(buffers::lookup(buffers));
            let m = accessor::collect(n, &what, || reader.read_inverse_bind_matrices())?;
            accessor::finite(m.as_flattened().as_flattened(), 16, &what)?;
            if m.len() < nj {
                return Err(err(format!("skin {}: {} inverse bind matrices for {nj} joints", skin.index(), m.len())));
            }
            m.iter().take(nj).map(|c| DMat4::from_cols_array_2d(&c.map(|col| col.map(f64::from)))).collect()
        }
        None => vec![DMat4::IDENTITY; nj],
    };

    // Bones: joints by depth (stable), so that every parent comes first.
    let mut order: Vec<usize> = (0..nj).collect();
    order.sort_by_key(|&j| depth[joint_nodes[j]]);
    let mut bone_of_joint = vec![0usize; nj];
    for (b, &j) in order.iter().enumerate() {
        bone_of_joint[j] = b;
    }
    let joint_node: Vec<usize> = order.iter().map(|&j| joint_nodes[j]).collect();
    let bone_ibm: Vec<DMat4> = order.iter().map(|&j| ibm[j]).collect();

    // The chain: every node on a joint's path to its root, parents first.
    let mut in_chain = vec![false; rest.len()];
    for &n in &joint_nodes {
        let mut at = Some(n);
        while let Some(a) = at {
            if std::mem::replace(&mut in_chain[a], true) {
                break;
            }
            at = parent[a];
        }
    }
    let mut chain: Vec<usize> = (0..rest.len()).filter(|&n| in_chain[n]).collect();
    chain.sort_by_key(|&n| depth[n]);

    let mut rig = Rig { parent, rest, chain, joint_node, ibm: bone_ibm, scale: 1.0 };

    // Names, unique.
    let mut names: Vec<String> = Vec::with_capacity(nj);
    for &n in &rig.joint_node {
        let node_name = doc.nodes().nth(n).and_then(|x| x.name().map(str::to_string)).unwrap_or_default();
        let mut name = if node_name.is_empty() { format!("node{n}") } else { node_name };
        while names.contains(&name) {
            name = format!("{name}.{n}");
        }
        names.push(name);
    }

    // The uniform scale, from the skinning matrices of the stored node transforms.
    let mut world = vec![DMat4::IDENTITY; rig.rest.len()];
    rig.world(&rig.rest, &mut world);
    let mut scales = Vec::with_capacity(nj);
    for (b, &n) in rig.joint_node.iter().enumerate() {
        if rig.ibm[b].determinant().abs() < 1e-30 {
            return Err(err(format!("joint '{}' (node {n}): inverse bind matrix is singular", names[b])));
        }
        let det = DMat3::from_mat4(world[n] * rig.ibm[b]).determinant();
        if !(det > 0.0 && det.is_finite()) {
            return Err(err(not_rigid_message(&names[b], n, f64::INFINITY, "at the file's rest")));
        }
        scales.push(det.cbrt());
    }
    // The median, so that the joint named in an error is the odd one out.
    scales.sort_unstable_by(f64::total_cmp);
    rig.scale = scales[(nj - 1) / 2];
    rig.pose(&world)
        .map_err(|(b, dev)| err(not_rigid_message(&names[b], rig.joint_node[b], dev, "at the file's rest")))?;
    let s = rig.scale;

    // Rest heads and frames (bind space times the scale), tails.
    let mut heads = Vec::with_capacity(nj);
    let mut frames = Vec::with_capacity(nj);
    for b in 0..nj {
        let bind = rig.ibm[b].inverse();
        let head = bind.w_axis.truncate() * s;
        if !head.is_finite() {
            return Err(err(format!("joint '{}': inverse bind matrix is not invertible", names[b])));
        }
        heads.push(head);
        frames.push(orthonormal_rotation(DMat3::from_mat4(bind)));
    }
    let bone_parent: Vec<Option<usize>> = rig
        .joint_node
        .iter()
        .map(|&n| {
            let mut at = rig.parent[n];
            while let Some(a) = at {
                if let Some(j) = joint_of_node[a] {
                    return Some(bone_of_joint[j]);
                }
                at = rig.parent[a];
            }
            None
        })
        .collect();
    let mut descs = Vec::with_capacity(nj);
    for b in 0..nj {
        let head = heads[b];
        let children: Vec<DVec3> = (0..nj).filter(|&c| bone_parent[c] == Some(b)).map(|c| heads[c]).collect();
        let mean = children.iter().copied().sum::<DVec3>() / children.len().max(1) as f64;
        let eps = 1e-6;
        let tail = if !children.is_empty() && (mean - head).length() > eps {
            mean
        } else if let Some(c) = children.iter().find(|c| (**c - head).length() > eps) {
            *c
        } else if let Some(p) = bone_parent[b].filter(|&p| (head - heads[p]).length() > eps) {
            head + (head - heads[p]) * 0.5
        } else {
            head + frames[b] * DVec3::new(0.0, 0.1, 0.0)
        };
        descs.push(BoneDesc {
            name: names[b].clone(),
            parent: bone_parent[b],
            head: head.as_vec3().into(),
            tail: tail.as_vec3().into(),
            frame: frames[b].as_quat(),
        });
    }
    let skeleton = Skeleton::new(descs)?;

    Ok(Bones { skeleton, rig, bone_of_joint })
}

/// The node tree and the joints of the skin: what posing the skeleton needs from the document.
#[derive(Clone, Debug)]
pub(super) struct Rig {
    /// Parent of every node of the file.
    parent: Vec<Option<usize>>,
    /// Local transform of every node as stored (no animation).
    pub(super) rest: Vec<Local>,
    /// The nodes on the joints' paths to their roots, parents first.
    chain: Vec<usize>,
    /// Node of each bone.
    pub(super) joint_node: Vec<usize>,
    /// Inverse bind matrix of each bone.
    ibm: Vec<DMat4>,
    /// Uniform scale factored out of the skinning matrices (metres per bind-space unit).
    pub(super) scale: f64,
}

/// A node's local transform.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Local {
    Trs { t: DVec3, r: DQuat, s: DVec3 },
    Matrix(DMat4),
}

impl Local {
    pub(super) fn matrix(&self) -> DMat4 {
        match *self {
            Local::Trs { t, r, s } => DMat4::from_scale_rotation_translation(s, r, t),
            Local::Matrix(m) => m,
        }
    }
}

impl Rig {
    /// World matrices of the chain's nodes from local transforms (one per node of the file).
    pub(super) fn world(&self, locals: &[Local], world: &mut [DMat4]) {
        for &n in &self.chain {
            let m = locals[n].matrix();
            world[n] = match self.parent[n] {
                Some(p) => world[p] * m,
                None => m,
            };
        }
    }

    /// The pose of the world matrices of the chain, or the first bone whose skinning matrix is
    /// not a rotation times `scale` (with its deviation).
    pub(super) fn pose(&self, world: &[DMat4]) -> core::result::Result<Pose, (usize, f64)> {
        let n = self.joint_node.len();
        let mut pose = Pose { rotation: Vec::with_capacity(n), head: Vec::with_capacity(n) };
        for (b, &node) in self.joint_node.iter().enumerate() {
            let w = world[node];
            let skinning = w * self.ibm[b];
            let r = rotation_of(DMat3::from_mat4(skinning), self.scale).map_err(|dev| (b, dev))?;
            pose.rotation.push(r.as_quat());
            pose.head.push(w.w_axis.truncate().as_vec3());
        }
        Ok(pose)
    }

    /// Whether each node of the file is on the chain.
    pub(super) fn in_chain(&self) -> Vec<bool> {
        let mut out = vec![false; self.rest.len()];
        for &n in &self.chain {
            out[n] = true;
        }
        out
    }
}

/// The rotation `m / scale`, or its deviation from one (see [`RIGID_TOLERANCE`]; infinite for a
/// mirror or NaNs).
fn rotation_of(m: DMat3, scale: f64) -> core::result::Result<DQuat, f64> {
    let l = m * (1.0 / scale);
    let e = l.transpose() * l - DMat3::IDENTITY;
    let dev = e.to_cols_array().iter().fold(0.0f64, |a, x| a.max(x.abs()));
    if !dev.is_finite() || l.determinant() <= 0.0 {
        return Err(f64::INFINITY);
    }
    if dev > RIGID_TOLERANCE {
        return Err(dev);
    }
    Ok(DQuat::from_mat3(&l).normalize())
}

/// The rotation nearest the columns of `m` (Gram-Schmidt from x then y), identity when they are
/// degenerate.
fn orthonormal_rotation(m: DMat3) -> DQuat {
    let x = m.x_axis.normalize_or_zero();
    let y = (m.y_axis - x * x.dot(m.y_axis)).normalize_or_zero();
    if x == DVec3::ZERO || y == DVec3::ZERO {
        return DQuat::IDENTITY;
    }
    let q = DQuat::from_mat3(&DMat3::from_cols(x, y, x.cross(y))).normalize();
    if q.is_finite() {
        q
    } else {
        DQuat::IDENTITY
    }
}

pub(super) fn not_rigid_message(bone: &str, node: usize, deviation: f64, when: &str) -> String {
    format!(
        "joint '{bone}' (node {node}) {when}: its skinning matrix is not a rotation times the file's one \
         uniform scale (deviation {deviation:.2e}; non-uniform or changing scale, shear or mirroring \
         cannot be represented by the rig)"
    )
}

fn local_of(node: &gltf::Node) -> Result<Local> {
    let i = node.index();
    let local = match node.transform() {
        Transform::Matrix { matrix } => Local::Matrix(DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from)))),
        Transform::Decomposed { translation, rotation, scale } => {
            let r = DQuat::from_array(rotation.map(f64::from));
            if r.length_squared() <= 1e-12 {
                return Err(err(format!("node {i}: rotation is not a unit quaternion")));
            }
            Local::Trs {
                t: DVec3::from_array(translation.map(f64::from)),
                r: r.normalize(),
                s: DVec3::from_array(scale.map(f64::from)),
            }
        }
    };
    let finite = match local {
        Local::Trs { t, r, s } => t.is_finite() && r.is_finite() && s.is_finite(),
        Local::Matrix(m) => m.is_finite(),
    };
    if !finite {
        return Err(err(format!("node {i}: transform is NaN or infinite")));
    }
    Ok(local)
}

/// Parents and depths of the nodes (refusing a node with two parents and cycles).
fn node_tree(doc: &gltf::Document) -> Result<(Vec<Option<usize>>, Vec<usize>)> {
    let n = doc.nodes().len();
    let mut parent = vec![None; n];
    for node in doc.nodes() {
        for c in node.children() {
            if c.index() == node.index() || parent[c.index()].replace(node.index()).is_some() {
                return Err(err(format!("node {} is the child of more than one node (or of itself)", c.index())));
            }
        }
    }
    let mut depth: Vec<Option<usize>> = vec![None; n];
    let mut path = Vec::new();
    for i in 0..n {
        path.clear();
        let mut at = Some(i);
        let base = loop {
            match at {
                None => break 0,
                Some(a) => {
                    if let Some(d) = depth[a] {
                        break d + 1;
                    }
                    if path.len() > n {
                        return Err(err(format!("node {i} is its own ancestor (the node tree has a cycle)")));
                    }
                    path.push(a);
                    at = parent[a];
                }
            }
        };
        for (k, &a) in path.iter().rev().enumerate() {
            depth[a] = Some(base + k);
        }
    }
    Ok((parent, depth.into_iter().map(|d| d.unwrap_or(0)).collect()))
}
