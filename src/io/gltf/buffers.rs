//! The document's buffers: the GLB binary chunk, `data:` URIs (base64 through the `base64`
//! crate, or percent-encoded) and files beside a `.gltf` (percent-encoded names decoded by the
//! `percent-encoding` crate), each cut to its declared length; and the lookup through which the
//! `gltf` crate's readers see them.

use super::err;
use crate::error::{Error, Result};
use base64::Engine as _;
use gltf::buffer::Source;
use percent_encoding::{percent_decode, percent_decode_str};
use std::borrow::Cow;
use std::format;
use std::path::Path;
use std::vec::Vec;

/// The bytes of every buffer of the document (`blob`: the GLB binary chunk; `base`: the folder
/// of a `.gltf` read from a file), each exactly its declared length.
pub(super) fn load<'a>(
    doc: &gltf::Document,
    blob: Option<Cow<'a, [u8]>>,
    base: Option<&Path>,
) -> Result<Vec<Cow<'a, [u8]>>> {
    let mut out = Vec::new();
    for b in doc.buffers() {
        let i = b.index();
        let mut data: Cow<'a, [u8]> = match b.source() {
            Source::Bin => {
                blob.clone().ok_or_else(|| err(format!("buffer {i} has no uri and there is no GLB binary chunk")))?
            }
            Source::Uri(uri) if uri.starts_with("data:") => {
                Cow::Owned(data_uri(uri).ok_or_else(|| err(format!("buffer {i}: malformed data URI")))?)
            }
            Source::Uri(uri) => {
                let Some(dir) = base else {
                    return Err(err(format!(
                        "buffer {i} is the external file '{uri}': read the document from its file \
                         (GltfBody::read) so that it can be found"
                    )));
                };
                let name = percent_decode_str(uri)
                    .decode_utf8()
                    .map_err(|_| err(format!("buffer {i}: uri '{uri}' is not UTF-8 once decoded")))?;
                let path = dir.join(&*name);
                Cow::Owned(std::fs::read(&path).map_err(|e| Error::io(&path, e))?)
            }
        };
        let len = b.length();
        if data.len() < len {
            return Err(err(format!("buffer {i} declares {len} bytes, its data has {}", data.len())));
        }
        match &mut data {
            Cow::Borrowed(s) => *s = &s[..len],
            Cow::Owned(v) => v.truncate(len),
        }
        out.push(data);
    }
    Ok(out)
}

/// The bytes of a `data:[<media type>][;base64],<data>` URI.
fn data_uri(uri: &str) -> Option<Vec<u8>> {
    let (head, body) = uri.strip_prefix("data:")?.split_once(',')?;
    if head.ends_with(";base64") {
        base64_decode(body)
    } else {
        Some(percent_decode(body.as_bytes()).collect())
    }
}

/// Standard base64, padded or not, unused bits of the last symbol ignored.
pub(super) fn base64_decode(s: &str) -> Option<Vec<u8>> {
    use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
    const LENIENT: GeneralPurpose = GeneralPurpose::new(
        &base64::alphabet::STANDARD,
        GeneralPurposeConfig::new()
            .with_decode_padding_mode(DecodePaddingMode::Indifferent)
            .with_decode_allow_trailing_bits(true),
    );
    LENIENT.decode(s).ok()
}

/// The buffer lookup that the `gltf` crate's readers take.
pub(super) fn lookup<'s>(buffers: &'s [Cow<'s, [u8]>]) -> impl Fn(gltf::Buffer<'_>) -> Option<&'s [u8]> + Clone + 's {
    move |b| buffers.get(b.index()).map(|d| &**d)
}
