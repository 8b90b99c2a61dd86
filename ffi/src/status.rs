//! Status codes, why a call failed ([`Failure`]) with the code and message that report it, and
//! `hood_status_string`.

use hood::Error;
use std::ffi::{c_char, CStr};

/// A status code: [`HOOD_OK`] or an error (codes 1-15 are [`Error::code`]).
pub type hood_status = u32;

/// Success.
pub const HOOD_OK: hood_status = 0;
/// [`Error::IndexOutOfRange`].
pub const HOOD_ERR_INDEX_OUT_OF_RANGE: hood_status = 1;
/// [`Error::NonFinite`].
pub const HOOD_ERR_NON_FINITE: hood_status = 2;
/// [`Error::DegenerateFace`].
pub const HOOD_ERR_DEGENERATE_FACE: hood_status = 3;
/// [`Error::RepeatedVertex`].
pub const HOOD_ERR_REPEATED_VERTEX: hood_status = 4;
/// [`Error::UnusedVertex`].
pub const HOOD_ERR_UNUSED_VERTEX: hood_status = 5;
/// [`Error::Empty`].
pub const HOOD_ERR_EMPTY: hood_status = 6;
/// [`Error::SizeMismatch`].
pub const HOOD_ERR_SIZE_MISMATCH: hood_status = 7;
/// [`Error::OutOfRange`].
pub const HOOD_ERR_OUT_OF_RANGE: hood_status = 8;
/// [`Error::CapacityExceeded`].
pub const HOOD_ERR_CAPACITY_EXCEEDED: hood_status = 9;
/// [`Error::IncompatibleModel`].
pub const HOOD_ERR_INCOMPATIBLE_MODEL: hood_status = 10;
/// [`Error::UnsupportedEffect`].
pub const HOOD_ERR_UNSUPPORTED_EFFECT: hood_status = 11;
/// [`Error::CorruptData`].
pub const HOOD_ERR_CORRUPT_DATA: hood_status = 12;
/// [`Error::Parse`].
pub const HOOD_ERR_PARSE: hood_status = 13;
/// [`Error::Io`].
pub const HOOD_ERR_IO: hood_status = 14;
/// [`Error::InsideOut`].
pub const HOOD_ERR_INSIDE_OUT: hood_status = 15;
/// A required pointer argument is NULL.
pub const HOOD_ERR_NULL_POINTER: hood_status = 100;
/// Not a live handle of the expected kind.
pub const HOOD_ERR_INVALID_HANDLE: hood_status = 101;
/// `hood_model_free` on a model that live sims use.
pub const HOOD_ERR_MODEL_IN_USE: hood_status = 102;
/// A panic was caught at the boundary.
pub const HOOD_ERR_PANIC: hood_status = 103;
/// A pointer argument is misaligned for its element type, or an output array overlaps an input.
pub const HOOD_ERR_BAD_POINTER: hood_status = 104;
/// The sim is in use by a call on another thread (a step, or a free while it steps).
pub const HOOD_ERR_BUSY: hood_status = 105;
/// A struct's `struct_size` is not one this library accepts: the caller was built against another
/// header (the rule is in the header's Conventions).
pub const HOOD_ERR_STRUCT_SIZE: hood_status = 106;

/// `hood_set_allocator` after the library has allocated.
pub const HOOD_ERR_TOO_LATE: hood_status = 107;

/// Why a call failed.
pub(crate) enum Failure {
    Hood(Error),
    Null(&'static str),
    /// A pointer argument that is misaligned or overlaps another: (which, why).
    Pointer(&'static str, &'static str),
    Handle(&'static str),
    InUse(usize),
    /// A sim used by a call on another thread.
    Busy(&'static str),
    /// A `struct_size` this library does not accept: the whole message.
    StructSize(String),
    /// A call that must come before the library's first allocation.
    TooLate(&'static str),
}

impl From<Error> for Failure {
    fn from(e: Error) -> Self {
        Failure::Hood(e)
    }
}

impl Failure {
    pub(crate) fn code(&self) -> hood_status {
        match self {
            Failure::Hood(e) => e.code(),
            Failure::Null(_) => HOOD_ERR_NULL_POINTER,
            Failure::Pointer(..) => HOOD_ERR_BAD_POINTER,
            Failure::Handle(_) => HOOD_ERR_INVALID_HANDLE,
            Failure::InUse(_) => HOOD_ERR_MODEL_IN_USE,
            Failure::Busy(_) => HOOD_ERR_BUSY,
            Failure::StructSize(_) => HOOD_ERR_STRUCT_SIZE,
            Failure::TooLate(_) => HOOD_ERR_TOO_LATE,
        }
    }

    pub(crate) fn message(&self) -> String {
        match self {
            Failure::Hood(e) => e.to_string(),
            Failure::Null(what) => format!("{what} is NULL"),
            Failure::Pointer(what, why) => format!("{what} {why}"),
            Failure::Handle(what) => format!("{what} is not a live handle (already freed, or never created)"),
            Failure::InUse(n) => format!("the model is still used by {n} sim(s); free them first"),
            Failure::Busy(what) => {
                format!(
                    "{what} is in use by another call: one on another thread (one thread at a time per sim), or, \
                     for a model or garment, one that is reading it"
                )
            }
            Failure::StructSize(msg) => msg.clone(),
            Failure::TooLate(what) => format!("{what}: the library has allocated already (call it before any other)"),
        }
    }
}

pub(crate) type Result<T> = std::result::Result<T, Failure>;

/// The name and meaning of a status code, as the header's comment on it states them (checked by
/// `tests/header.rs`); "unknown status" for a code this library does not have.
fn status_text(code: hood_status) -> &'static CStr {
    match code {
        HOOD_OK => c"HOOD_OK: success",
        HOOD_ERR_INDEX_OUT_OF_RANGE => c"HOOD_ERR_INDEX_OUT_OF_RANGE: an index (e.g. in a face) refers past the end",
        HOOD_ERR_NON_FINITE => c"HOOD_ERR_NON_FINITE: a coordinate or parameter is NaN or infinite",
        HOOD_ERR_DEGENERATE_FACE => c"HOOD_ERR_DEGENERATE_FACE: a garment triangle has zero area",
        HOOD_ERR_REPEATED_VERTEX => c"HOOD_ERR_REPEATED_VERTEX: a triangle names the same vertex twice",
        HOOD_ERR_UNUSED_VERTEX => c"HOOD_ERR_UNUSED_VERTEX: a garment vertex belongs to no triangle",
        HOOD_ERR_EMPTY => c"HOOD_ERR_EMPTY: something that must not be empty is",
        HOOD_ERR_SIZE_MISMATCH => c"HOOD_ERR_SIZE_MISMATCH: an array has the wrong length",
        HOOD_ERR_OUT_OF_RANGE => c"HOOD_ERR_OUT_OF_RANGE: a value is outside its documented range",
        HOOD_ERR_CAPACITY_EXCEEDED => c"HOOD_ERR_CAPACITY_EXCEEDED: a capacity fixed at creation, or a bound such as HOOD_MAX_VERTICES, was exceeded",
        HOOD_ERR_INCOMPATIBLE_MODEL => c"HOOD_ERR_INCOMPATIBLE_MODEL: the model cannot run this garment/body/config",
        HOOD_ERR_UNSUPPORTED_EFFECT => c"HOOD_ERR_UNSUPPORTED_EFFECT: an effect the model, the configuration or this build does not support",
        HOOD_ERR_CORRUPT_DATA => {
            c"HOOD_ERR_CORRUPT_DATA: model bytes corrupt, truncated, misaligned, other version"
        }
        HOOD_ERR_PARSE => c"HOOD_ERR_PARSE: a text input could not be parsed",
        HOOD_ERR_IO => c"HOOD_ERR_IO: an operating-system I/O failure",
        HOOD_ERR_INSIDE_OUT => c"HOOD_ERR_INSIDE_OUT: the body mesh is wound inside out (reverse every face)",
        HOOD_ERR_NULL_POINTER => c"HOOD_ERR_NULL_POINTER: a required pointer argument is NULL",
        HOOD_ERR_INVALID_HANDLE => c"HOOD_ERR_INVALID_HANDLE: not a live handle of that kind (freed, or never made)",
        HOOD_ERR_MODEL_IN_USE => c"HOOD_ERR_MODEL_IN_USE: hood_model_free on a model that live sims still use",
        HOOD_ERR_PANIC => c"HOOD_ERR_PANIC: an internal error (a bug in hood); the handle may be unusable",
        HOOD_ERR_BAD_POINTER => {
            c"HOOD_ERR_BAD_POINTER: a pointer misaligned for its type, or an output overlapping an input"
        }
        HOOD_ERR_BUSY => c"HOOD_ERR_BUSY: the handle is in use by another call: a sim on another thread, or a model or garment being read",
        HOOD_ERR_STRUCT_SIZE => {
            c"HOOD_ERR_STRUCT_SIZE: struct_size is not one this library knows: the caller was built against another header"
        }
        HOOD_ERR_TOO_LATE => {
            c"HOOD_ERR_TOO_LATE: hood_set_allocator after the library has allocated (call it first)"
        }
        _ => c"unknown status",
    }
}

/// The name and meaning of a status code ("unknown status" for others): a NUL-terminated string
/// with static storage. Never fails, and leaves `hood_last_error` alone.
#[no_mangle]
pub extern "C" fn hood_status_string(code: hood_status) -> *const c_char {
    status_text(code).as_ptr()
}
