//! Structs versioned by a leading `struct_size` ([`Extensible`]): reading the caller's inputs and
//! writing its outputs by the openat2 rule.

use crate::arrays::{aligned, require, write_out};
use crate::status::{Failure, Result};
use hood::Error;

/// A struct whose first field is `struct_size: u32`, the size of the struct in the header the
/// caller was built against: passed in (`hood_sim_config`, `hood_body_desc`, `hood_executor`,
/// `hood_material`) or filled in (`hood_model_info`, `hood_refinement`, `hood_body_survey`). It
/// lets the structs grow without old and new callers silently misreading each other;
/// [`read_extensible`] and [`write_extensible`] apply the rule.
///
/// # Safety
/// Implementors are `#[repr(C)]`, start with `struct_size: u32`, and have no invalid bit
/// patterns (integers, floats, raw pointers, optional function pointers), so that reading any
/// caller bytes as one is sound.
pub(crate) unsafe trait Extensible: Copy {
    /// The C name, for messages.
    const NAME: &'static str;
    /// The smallest `struct_size` accepted: the struct's size in the first release that had
    /// `struct_size` (fields added since read as [`Extensible::absent_fields`] gives them).
    const MIN_SIZE: usize = size_of::<Self>();

    /// What a field takes when the caller's struct ends before it (an older header): zero,
    /// "unset", unless an implementor overrides it for a field whose zero means something.
    fn absent_fields() -> Self {
        // SAFETY: all-zero bytes are a valid `Self` (the trait's contract).
        unsafe { std::mem::MaybeUninit::<Self>::zeroed().assume_init() }
    }
}

/// The `struct_size` of `T` in this library (what `hood_sim_config_default` writes).
pub(crate) const fn struct_size<T: Extensible>() -> u32 {
    size_of::<T>() as u32
}

/// Largest `struct_size` accepted (a page, as openat2 limits its struct): a garbage size must not
/// make the library scan megabytes of the caller's memory for nonzero bytes.
const MAX_STRUCT_SIZE: usize = 4096;

/// Reads an extensible struct through a caller pointer: the leading `struct_size` first, then,
/// if it is acceptable, the prefix this library knows. The rule is that of Linux's openat2 and
/// clone3, which lets callers built against an older or a newer header be told apart from
/// current ones instead of being misread:
///
/// - smaller than `size_of::<T>()`: an older header, whose fields this library would read past
///   the end of: refused;
/// - equal: the current header;
/// - larger: a newer header. Its extra fields are accepted only if every byte past
///   `size_of::<T>()` (up to `struct_size`) is zero, the value a newer field must give for
///   "unset" (a field set to anything else asks for something this library cannot do, so it is
///   refused rather than ignored);
/// - larger than [`MAX_STRUCT_SIZE`], or not a multiple of `T`'s alignment (which every C
///   `sizeof` is, and which keeps the elements of an array aligned): refused.
///
/// `stride` is `None` for a lone struct or the first element of an array (whose `struct_size`
/// becomes the array's stride), and the stride for the other elements, which must carry exactly
/// that `struct_size` (checked before any byte past it is read, so a bad element never makes
/// the library read beyond the array). `index` names the element in messages. Returns the value
/// and the caller's `struct_size`. Every refusal is [`HOOD_ERR_STRUCT_SIZE`] except a NULL
/// pointer ([`HOOD_ERR_NULL_POINTER`]) and a misaligned one ([`HOOD_ERR_BAD_POINTER`]).
///
/// # Safety
/// `p` is NULL or points to a struct whose leading `u32` is readable and which has at least
/// as many readable bytes as that `u32` says (`stride` for array elements), unchanged during
/// the call.
///
/// [`HOOD_ERR_STRUCT_SIZE`]: crate::HOOD_ERR_STRUCT_SIZE
/// [`HOOD_ERR_NULL_POINTER`]: crate::HOOD_ERR_NULL_POINTER
/// [`HOOD_ERR_BAD_POINTER`]: crate::HOOD_ERR_BAD_POINTER
pub(crate) unsafe fn read_extensible<T: Extensible>(
    p: *const T,
    index: Option<usize>,
    stride: Option<usize>,
    what: &'static str,
) -> Result<(T, usize)> {
    require(p, what)?;
    // `T` starts with a u32, so this also aligns the leading read.
    aligned(p, what)?;
    // SAFETY: non-null and aligned; the leading u32 is readable (caller).
    let size = unsafe { p.cast::<u32>().read() } as usize;
    let refuse = |why: String| {
        let name = match index {
            Some(i) => format!("{}[{i}]", T::NAME),
            None => T::NAME.to_string(),
        };
        Err(Failure::StructSize(format!(
            "{name}.struct_size is {size}: {why} (the caller was built against another hood.h; \
             sizeof({}) is {} in this library)",
            T::NAME,
            size_of::<T>()
        )))
    };
    if let Some(stride) = stride {
        if size != stride {
            return refuse(format!("every element must carry the first element's struct_size, {stride}"));
        }
    }
    if let Some(why) = size_problem::<T>(size) {
        return refuse(why);
    }
    if size < size_of::<T>() {
        // An older header: its fields, and `T::absent_fields()` for those added since.
        let mut t = T::absent_fields();
        // SAFETY: `size` bytes are readable (caller) and fit in `t`; any bytes are valid for `T`
        // (`Extensible`). The caller's struct_size, its first bytes, stays as it wrote it.
        unsafe { std::ptr::copy_nonoverlapping(p.cast::<u8>(), std::ptr::addr_of_mut!(t).cast::<u8>(), size) };
        return Ok((t, size));
    }
    // SAFETY: `size` bytes are readable (caller) and `size_of::<T>() <= size`, so the tail
    // `size_of::<T>()..size` is inside them.
    let tail = unsafe { std::slice::from_raw_parts(p.cast::<u8>().add(size_of::<T>()), size - size_of::<T>()) };
    if let Some(k) = tail.iter().position(|&b| b != 0) {
        return refuse(format!(
            "byte {} is not zero, past the {} bytes this library knows (a field it does not have is set)",
            size_of::<T>() + k,
            size_of::<T>()
        ));
    }
    // SAFETY: aligned, and at least `size_of::<T>()` readable bytes; any bytes are a valid `T`
    // (`Extensible`).
    Ok((unsafe { p.read() }, size))
}

/// Why `size` cannot be a `struct_size` of `T` (see [`read_extensible`]), or `None`.
pub(crate) fn size_problem<T: Extensible>(size: usize) -> Option<String> {
    if size < T::MIN_SIZE {
        Some(format!("smaller than the oldest header this library reads ({} bytes)", T::MIN_SIZE))
    } else if size > MAX_STRUCT_SIZE {
        Some(format!("larger than {MAX_STRUCT_SIZE} bytes"))
    } else if !size.is_multiple_of(align_of::<T>()) {
        Some(format!("not a multiple of the struct's alignment, {}", align_of::<T>()))
    } else {
        None
    }
}

/// One extensible struct (see [`read_extensible`]).
///
/// # Safety
/// As [`read_extensible`].
pub(crate) unsafe fn read_struct<T: Extensible>(p: *const T, what: &'static str) -> Result<T> {
    // SAFETY: the caller's promise.
    Ok(unsafe { read_extensible(p, None, None, what)? }.0)
}

/// An array of `n` extensible structs (NULL allowed when `n == 0`). The caller's element size is
/// `p[0].struct_size`, which every element must carry (see [`read_extensible`]).
///
/// # Safety
/// `p` is NULL or points to `n` elements of `p[0].struct_size` bytes each, readable and
/// unchanged during the call.
pub(crate) unsafe fn read_struct_array<T: Extensible>(p: *const T, n: usize, what: &'static str) -> Result<Vec<T>> {
    if n == 0 {
        return Ok(Vec::new());
    }
    // SAFETY: element 0 is readable (caller).
    let (first, stride) = unsafe { read_extensible(p, Some(0), None, what)? };
    match n.checked_mul(stride) {
        Some(b) if b <= isize::MAX as usize => {}
        _ => return Err(Error::OutOfRange { what: "array length", index: n }.into()),
    }
    let mut out = Vec::with_capacity(n);
    out.push(first);
    for i in 1..n {
        // SAFETY: inside the caller's `n * stride` bytes (checked not to overflow above); the
        // stride is a multiple of `T`'s alignment, so the element is aligned.
        let e = unsafe { p.byte_add(i * stride) };
        // SAFETY: the element's `stride` bytes are readable (caller); a different
        // `struct_size` is refused before any byte past `stride` is read.
        out.push(unsafe { read_extensible(e, Some(i), Some(stride), what)? }.0);
    }
    Ok(out)
}

/// Writes `v` into a caller's struct of `size` bytes: `v` with `struct_size` set to `size`, then
/// zeros up to `size` (a newer header's fields, "unset"); for an older header's smaller struct,
/// only its first `size` bytes. `size` must pass [`size_problem`].
///
/// # Safety
/// `out` is non-null, aligned and points to `size >= T::MIN_SIZE` writable bytes.
pub(crate) unsafe fn write_sized<T: Extensible>(out: *mut T, v: T, size: usize) {
    let known = size_of::<T>();
    // SAFETY: `size` writable bytes at an aligned `out` (caller); `T` starts with the `u32`
    // struct_size (`Extensible`).
    unsafe {
        if size >= known {
            write_out(out, v);
            std::ptr::write_bytes(out.cast::<u8>().add(known), 0, size - known);
        } else {
            std::ptr::copy_nonoverlapping((&v as *const T).cast::<u8>(), out.cast::<u8>(), size);
        }
        out.cast::<u32>().write(size as u32);
    }
}

/// Writes an extensible output struct (`hood_model_info`, `hood_refinement`, `hood_body_survey`)
/// whose `struct_size` the caller has set: checked as [`read_extensible`] checks an input's
/// (so an older header's smaller struct is never overrun), then filled by [`write_sized`].
///
/// # Safety
/// `out` is NULL or points to a struct whose leading `u32` is readable and which has at least as
/// many writable bytes as that `u32` says.
pub(crate) unsafe fn write_extensible<T: Extensible>(out: *mut T, v: T, what: &'static str) -> Result<()> {
    // SAFETY: the caller's promise; `read_extensible`'s checks of the size and alignment.
    let size = unsafe { struct_size_of(out, what)? };
    // SAFETY: checked above; `size` writable bytes (caller).
    unsafe { write_sized(out, v, size) };
    Ok(())
}

/// The caller's `struct_size` of an output struct at `out`, checked (see [`write_extensible`]).
///
/// # Safety
/// As [`write_extensible`].
unsafe fn struct_size_of<T: Extensible>(out: *const T, what: &'static str) -> Result<usize> {
    require(out, what)?;
    aligned(out, what)?;
    // SAFETY: non-null and aligned; the leading u32 is readable (caller).
    let size = unsafe { out.cast::<u32>().read() } as usize;
    match size_problem::<T>(size) {
        None => Ok(size),
        Some(why) => Err(Failure::StructSize(format!(
            "{}.struct_size is {size}: {why} (set it to sizeof({}) before the call; it is {} in this library)",
            T::NAME,
            T::NAME,
            size_of::<T>()
        ))),
    }
}
