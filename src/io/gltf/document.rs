//! The document: a GLB container's chunks or a `.gltf`'s JSON, parsed and validated by the
//! `gltf` crate, with the few fixes that keep its validation from refusing what this reader
//! ignores or from panicking.

use super::{err, FORMAT};
use crate::error::{Error, Result};
use std::borrow::Cow;
use std::format;
use std::string::ToString;

/// The validated document of a `.glb` or `.gltf`, and the GLB binary chunk (if any).
pub(super) fn open(bytes: &[u8]) -> Result<(gltf::Document, Option<Cow<'_, [u8]>>)> {
    let (json, blob) = if bytes.starts_with(b"glTF") {
        let glb = glb(bytes)?;
        (glb.json, glb.bin)
    } else {
        (Cow::Borrowed(bytes), None)
    };
    let mut root =
        gltf::json::Root::from_slice(&json).map_err(|e| Error::parse(FORMAT, e.line(), format!("JSON: {e}")))?;
    prepare(&mut root)?;
    let doc = gltf::Document::from_json(root).map_err(|e| err(e.to_string()))?;
    Ok((doc, blob))
}

/// The chunks of a GLB container (`gltf::Glb`, which borrows them), after the header check that
/// the crate leaves out: a declared length under the 12-byte header would underflow there. Only
/// the declared length is handed over, so that bytes after it are ignored.
fn glb(bytes: &[u8]) -> Result<gltf::Glb<'_>> {
    let Some(&[a, b, c, d]) = bytes.get(8..12) else {
        return Err(err("GLB header truncated (12 bytes needed)"));
    };
    let length = u32::from_le_bytes([a, b, c, d]) as usize;
    if length < 12 || length > bytes.len() {
        return Err(err(format!("GLB header declares {length} bytes, the data has {}", bytes.len())));
    }
    gltf::Glb::from_slice(&bytes[..length]).map_err(|e| match e {
        gltf::Error::Binary(gltf::binary::Error::Version(v)) => err(format!("GLB version {v} (only 2 is supported)")),
        e => err(format!("GLB container: {e}")),
    })
}

/// Readies a document for validation: drops what this reader ignores but the `gltf` crate's
/// validation would refuse (application-specific `_NAME` vertex attributes, animation channels
/// with an unknown target path), and refuses a `POSITION` naming a missing accessor and an
/// animation channel naming a missing node or sampler, or a sampler a missing accessor (which
/// the crate would index without checking).
fn prepare(root: &mut gltf::json::Root) -> Result<()> {
    use gltf::json::validation::Checked;
    use gltf::mesh::Semantic;
    let n_accessors = root.accessors.len();
    for (m, mesh) in root.meshes.iter_mut().enumerate() {
        for (p, prim) in mesh.primitives.iter_mut().enumerate() {
            prim.attributes.retain(|k, _| matches!(k, Checked::Valid(_)));
            if let Some(a) = prim.attributes.get(&Checked::Valid(Semantic::Positions)) {
                if a.value() >= n_accessors {
                    return Err(err(format!(
                        "mesh {m} primitive {p}: POSITION names accessor {}, but the file has {n_accessors}",
                        a.value()
                    )));
                }
            }
        }
    }
    let n_nodes = root.nodes.len();
    for (a, anim) in root.animations.iter_mut().enumerate() {
        anim.channels.retain(|c| matches!(c.target.path, Checked::Valid(_)));
        let n_samplers = anim.samplers.len();
        for (c, ch) in anim.channels.iter().enumerate() {
            let (node, sampler) = (ch.target.node.value(), ch.sampler.value());
            if node >= n_nodes || sampler >= n_samplers {
                return Err(err(format!(
                    "animation {a} channel {c}: targets node {node} with sampler {sampler}, but the file has \
                     {n_nodes} node(s) and the animation {n_samplers} sampler(s)"
                )));
            }
        }
        for (k, smp) in anim.samplers.iter().enumerate() {
            let (input, output) = (smp.input.value(), smp.output.value());
            if input >= n_accessors || output >= n_accessors {
                return Err(err(format!(
                    "animation {a} sampler {k}: reads accessors {input} and {output}, but the file has {n_accessors}"
                )));
            }
        }
    }
    Ok(())
}
