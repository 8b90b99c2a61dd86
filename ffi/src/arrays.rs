//! Checks of pointer arguments (NULL, alignment, array byte lengths, overlaps) and the slices and
//! out-parameter writes built on them.

use crate::status::{Failure, Result};
use hood::Error;

pub(crate) fn byte_len_ok<T>(n: usize) -> Result<()> {
    match n.checked_mul(size_of::<T>()) {
        Some(b) if b <= isize::MAX as usize => Ok(()),
        _ => Err(Error::OutOfRange { what: "array length", index: n }.into()),
    }
}

/// `n` elements at `p` (NULL allowed when `n == 0`).
///
/// # Safety
/// `p` is NULL or points to `n` readable, initialised `T`s that stay unchanged during the call.
pub(crate) unsafe fn slice<'a, T>(p: *const T, n: usize, what: &'static str) -> Result<&'a [T]> {
    if n == 0 {
        return Ok(&[]);
    }
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    aligned(p, what)?;
    byte_len_ok::<T>(n)?;
    // SAFETY: non-null, aligned, `n` elements readable (caller), total size checked above.
    Ok(unsafe { std::slice::from_raw_parts(p, n) })
}

/// `n` writable elements at `p` (NULL allowed when `n == 0`).
///
/// # Safety
/// `p` is NULL or points to `n` writable `T`s not aliased during the call.
pub(crate) unsafe fn slice_mut<'a, T>(p: *mut T, n: usize, what: &'static str) -> Result<&'a mut [T]> {
    if n == 0 {
        return Ok(&mut []);
    }
    if p.is_null() {
        return Err(Failure::Null(what));
    }
    aligned(p, what)?;
    byte_len_ok::<T>(n)?;
    // SAFETY: as in `slice`, and not aliased (caller).
    Ok(unsafe { std::slice::from_raw_parts_mut(p, n) })
}

/// Refuses a pointer that is not aligned for `T` (a slice over it would be undefined behaviour).
pub(crate) fn aligned<T>(p: *const T, what: &'static str) -> Result<()> {
    if p.is_aligned() {
        Ok(())
    } else {
        Err(Failure::Pointer(what, "is not aligned for its element type"))
    }
}

/// Refuses an output array of `out_len` elements of `T` that overlaps an input of `in_len`
/// (Rust may not hold a shared and a mutable view of the same memory at once).
pub(crate) fn disjoint<T>(
    input: *const T,
    in_len: usize,
    out: *const T,
    out_len: usize,
    what: &'static str,
) -> Result<()> {
    // A length whose byte size overflows is refused as such, not reported as an overlap.
    byte_len_ok::<T>(in_len)?;
    byte_len_ok::<T>(out_len)?;
    let size = size_of::<T>();
    let (a, b) = (input as usize, out as usize);
    let (a_end, b_end) = (a.saturating_add(in_len * size), b.saturating_add(out_len * size));
    if in_len == 0 || out_len == 0 || a_end <= b || b_end <= a {
        Ok(())
    } else {
        Err(Failure::Pointer(what, "overlaps an input array"))
    }
}

/// `n` points (3 floats each) at `p`.
///
/// # Safety
/// As [`slice()`] for `3 * n` floats.
pub(crate) unsafe fn points<'a>(p: *const f32, n: usize, what: &'static str) -> Result<&'a [[f32; 3]]> {
    // SAFETY: `[f32; 3]` has the alignment of f32 and no padding; caller guarantees 3n floats.
    unsafe { slice(p as *const [f32; 3], n, what) }
}

/// # Safety
/// As [`slice_mut`] for `3 * n` floats.
pub(crate) unsafe fn points_mut<'a>(p: *mut f32, n: usize, what: &'static str) -> Result<&'a mut [[f32; 3]]> {
    // SAFETY: as in `points`.
    unsafe { slice_mut(p as *mut [f32; 3], n, what) }
}

/// Writes an out-parameter (after the call's work succeeded).
///
/// # Safety
/// `out` is NULL (checked) or valid for a write of `T`.
pub(crate) unsafe fn write_out<T>(out: *mut T, v: T) {
    // SAFETY: callers check `out` for NULL first; validity is the caller's promise.
    unsafe { out.write(v) }
}

pub(crate) fn require<T>(p: *const T, what: &'static str) -> Result<()> {
    if p.is_null() {
        Err(Failure::Null(what))
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A length whose byte size overflows is refused as out of range wherever the arrays lie,
    /// never mistaken for an overlap (a saturated end would overlap everything above it).
    #[test]
    fn overflowing_lengths_are_out_of_range_not_overlaps() {
        let data = [0u64; 4];
        let (low, high) = (data.as_ptr(), data[3..].as_ptr());
        for (input, output) in [(low, high), (high, low)] {
            for (a, b) in [(1, usize::MAX / 4), (usize::MAX / 4, 1)] {
                let e = disjoint(input, a, output, b, "out").unwrap_err();
                assert!(matches!(e, Failure::Hood(Error::OutOfRange { .. })), "{a} {b}");
            }
        }
        assert!(disjoint(low, 3, high, 1, "out").is_ok());
        assert!(matches!(disjoint(low, 4, high, 1, "out"), Err(Failure::Pointer("out", _))));
    }
}
