//! What `hood` checks of an accessor before one of the `gltf` crate's readers reads it, and the
//! collection of what that reader gives.
//!
//! The readers (`Primitive::reader`, `Skin::reader`, `Channel::reader`) take a document as its
//! validation leaves it, which checks neither the accessors' types against their use nor their
//! byte ranges: on such an accessor they panic (`unreachable!` on an unexpected component type,
//! slice indexing or an assertion on an element shorter than its type, an arithmetic underflow
//! for a count of zero) or quietly read other bytes (a `POSITION` of 16-bit integers read as
//! floats, sparse indices out of order skipped). [`check`] refuses all of that with an error, so
//! that the readers only ever see accessors they read in full.

use super::err;
use crate::error::Result;
use crate::limits;
use gltf::accessor::sparse::IndexType;
use gltf::accessor::util::{ItemIter, SparseIndicesIter};
use gltf::accessor::{DataType, Dimensions};
use std::borrow::Cow;
use std::format;
use std::string::String;
use std::vec::Vec;

/// How an accessor is named in errors: its use and its index.
pub(super) fn label(what: &str, acc: &gltf::Accessor) -> String {
    format!("{what} (accessor {})", acc.index())
}

/// Checks that `acc` (named `what`, see [`label`]) holds elements of `dims` with components of
/// one of `types`, at most `max_count` of them, and that every byte the `gltf` crate's reader
/// will read lies within its buffer views and buffers: the elements, and the sparse indices
/// (strictly increasing, each naming an element) and values. Returns the element count.
pub(super) fn check(
    buffers: &[Cow<'_, [u8]>],
    acc: &gltf::Accessor,
    what: &str,
    dims: Dimensions,
    types: &[DataType],
    max_count: usize,
) -> Result<usize> {
    if acc.dimensions() != dims {
        return Err(err(format!("{what}: type {:?}, expected {dims:?}", acc.dimensions())));
    }
    let ty = acc.data_type();
    if !types.contains(&ty) {
        return Err(err(format!("{what}: component type {ty:?}, expected one of {types:?}")));
    }
    let n = acc.count();
    limits::within("glTF accessor elements", n, max_count)?;
    if n == 0 {
        return Ok(0);
    }
    let size = acc.size();
    if let Some(view) = acc.view() {
        elements(buffers, &view, acc.offset(), n, size, what)?;
    }
    if let Some(sparse) = acc.sparse() {
        let k = sparse.count();
        if k == 0 || k > n {
            return Err(err(format!("{what}: {k} sparse elements for {n} elements")));
        }
        let (indices, values) = (sparse.indices(), sparse.values());
        elements(buffers, &values.view(), values.offset(), k, size, what)?;
        let ty = indices.index_type();
        let (bytes, stride) = elements(buffers, &indices.view(), indices.offset(), k, ty.size(), what)?;
        let iter = match ty {
            IndexType::U8 => SparseIndicesIter::U8(ItemIter::new(bytes, stride)),
            IndexType::U16 => SparseIndicesIter::U16(ItemIter::new(bytes, stride)),
            IndexType::U32 => SparseIndicesIter::U32(ItemIter::new(bytes, stride)),
        };
        let mut next = 0;
        for i in iter.map(|i| i as usize) {
            if i >= n {
                return Err(err(format!("{what}: sparse index {i} out of range ({n} elements)")));
            }
            if i < next {
                return Err(err(format!("{what}: sparse index {i} after {}, not strictly increasing", next - 1)));
            }
            next = i + 1;
        }
    }
    Ok(n)
}

/// As [`check`] for integers (indices, joints), which must not be marked normalised.
pub(super) fn check_integers(
    buffers: &[Cow<'_, [u8]>],
    acc: &gltf::Accessor,
    what: &str,
    dims: Dimensions,
    types: &[DataType],
    max_count: usize,
) -> Result<usize> {
    if acc.normalized() {
        return Err(err(format!("{what}: integers marked normalized")));
    }
    check(buffers, acc, what, dims, types, max_count)
}

/// The `n` elements that a reader of the `gltf` crate gives for an accessor that passed
/// [`check`]; `read` is not called for an empty accessor, which that reader cannot take.
pub(super) fn collect<T, I: Iterator<Item = T>>(
    n: usize,
    what: &str,
    read: impl FnOnce() -> Option<I>,
) -> Result<Vec<T>> {
    if n == 0 {
        return Ok(Vec::new());
    }
    let v: Vec<T> = read().ok_or_else(|| err(format!("{what}: no data to read")))?.collect();
    if v.len() != n {
        return Err(err(format!("{what}: {} elements read, {n} expected", v.len())));
    }
    Ok(v)
}

/// Refuses NaNs and infinities among `values`, `width` components per element.
pub(super) fn finite(values: &[f32], width: usize, what: &str) -> Result<()> {
    match values.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(err(format!("{what}: element {} is NaN or infinite", i / width))),
        None => Ok(()),
    }
}

/// The bytes of a buffer view, checked against its buffer.
fn view_bytes<'b>(buffers: &'b [Cow<'_, [u8]>], view: &gltf::buffer::View) -> Result<&'b [u8]> {
    let b = view.buffer().index();
    let buf = buffers.get(b).ok_or_else(|| err(format!("buffer view {} names a missing buffer", view.index())))?;
    let start = view.offset();
    start.checked_add(view.length()).and_then(|end| buf.get(start..end)).ok_or_else(|| {
        err(format!(
            "buffer view {} (bytes {start}, length {}) lies outside buffer {b} ({} bytes)",
            view.index(),
            view.length(),
            buf.len()
        ))
    })
}

/// The bytes of `count` (at least one) elements of `size` bytes from `offset` in `view`, the
/// view's stride (or `size`) apart, and that stride: the range the `gltf` crate's reader slices,
/// checked here without overflow.
fn elements<'b>(
    buffers: &'b [Cow<'_, [u8]>],
    view: &gltf::buffer::View,
    offset: usize,
    count: usize,
    size: usize,
    what: &str,
) -> Result<(&'b [u8], usize)> {
    let data = view_bytes(buffers, view)?;
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(err(format!("{what}: stride {stride} is less than the element size {size}")));
    }
    let end = stride.checked_mul(count - 1).and_then(|x| x.checked_add(offset)).and_then(|x| x.checked_add(size));
    let bytes = end.and_then(|end| data.get(offset..end)).ok_or_else(|| {
        err(format!(
            "{what}: {count} elements from byte {offset} (stride {stride}) run past the end of buffer view {} ({} bytes)",
            view.index(),
            data.len()
        ))
    })?;
    Ok((bytes, stride))
}
