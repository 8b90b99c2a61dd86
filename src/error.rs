//! The crate's one error type. Every fallible function returns [`Result`]; the C ABI mirrors the
//! variants as status codes (see [`Error::code`]).

use alloc::string::String;
use core::fmt;

/// Everything that can go wrong in `hood`, with the offending index or size inside.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Error {
    /// An index refers past the end of what it indexes (e.g. a face naming a vertex that does
    /// not exist).
    IndexOutOfRange {
        /// What holds the bad index ("face", "pinned vertex", ...).
        what: &'static str,
        /// Position of the offending element in its list (e.g. the face number).
        at: usize,
        /// The bad index.
        index: usize,
        /// The number of valid indices.
        len: usize,
    },
    /// A coordinate or parameter is NaN or infinite.
    NonFinite {
        /// What holds the bad value ("rest position", "body vertex", ...).
        what: &'static str,
        /// Index of the offending element.
        index: usize,
    },
    /// A triangle has (numerically) zero area.
    DegenerateFace {
        /// Face index.
        face: usize,
    },
    /// A triangle names the same vertex twice.
    RepeatedVertex {
        /// Face index.
        face: usize,
        /// The repeated vertex.
        vertex: usize,
    },
    /// A vertex belongs to no triangle (it would have zero mass).
    UnusedVertex {
        /// Vertex index.
        vertex: usize,
    },
    /// Something that must not be empty is (a mesh without faces, ...).
    Empty {
        /// What is empty.
        what: &'static str,
    },
    /// A caller-provided buffer or array has the wrong length.
    SizeMismatch {
        /// Which buffer.
        what: &'static str,
        /// The length required.
        expected: usize,
        /// The length given.
        got: usize,
    },
    /// A value is outside its documented range.
    OutOfRange {
        /// Which value.
        what: &'static str,
        /// Index of the element, where there is one (else 0).
        index: usize,
    },
    /// A fixed capacity chosen at creation, or a documented bound of [`crate::limits`], was
    /// exceeded.
    CapacityExceeded {
        /// Which capacity.
        what: &'static str,
        /// The capacity.
        capacity: usize,
        /// What was asked for.
        needed: usize,
    },
    /// The model cannot run this garment/body/config (widths, levels, effects).
    IncompatibleModel {
        /// Why.
        reason: &'static str,
    },
    /// The scene asks for an effect that the model was not trained with, that the configuration
    /// excludes, or that this build lacks.
    UnsupportedEffect {
        /// Which effect.
        effect: &'static str,
    },
    /// A model file (or other binary input) failed validation: truncated, corrupt, or of another
    /// version.
    CorruptData {
        /// Why.
        reason: &'static str,
    },
    /// A text input (OBJ, BVH, JSON, ...) could not be parsed.
    Parse {
        /// Which input kind ("obj", "bvh", ...).
        format: &'static str,
        /// 1-based line number, or 0 when not applicable.
        line: usize,
        /// What was wrong.
        message: String,
    },
    /// A closed mesh is wound inside out (its faces clockwise seen from outside, as a change of
    /// handedness gives): its normals point inwards.
    InsideOut {
        /// Which mesh ("body", ...).
        what: &'static str,
    },
    /// An operating-system I/O failure (only produced under the `std` feature).
    Io {
        /// The path or resource.
        path: String,
        /// The OS error text.
        message: String,
    },
}

/// `core::result::Result` with [`Error`].
pub type Result<T> = core::result::Result<T, Error>;

/// Checks that a buffer named `what` has `got` entries where `expected` are needed.
///
/// # Errors
/// [`Error::SizeMismatch`] when they differ.
pub fn check_len(what: &'static str, got: usize, expected: usize) -> Result<()> {
    if got == expected {
        Ok(())
    } else {
        Err(Error::SizeMismatch { what, expected, got })
    }
}

/// Checks that a buffer named `what` has `got` entries where at least `expected` are needed.
///
/// # Errors
/// [`Error::SizeMismatch`] when it is shorter.
pub fn check_at_least(what: &'static str, got: usize, expected: usize) -> Result<()> {
    if got >= expected {
        Ok(())
    } else {
        Err(Error::SizeMismatch { what, expected, got })
    }
}

impl Error {
    /// The stable numeric status code of this error, as the C ABI reports it. Codes are never
    /// reused; 0 is success.
    pub fn code(&self) -> u32 {
        match self {
            Error::IndexOutOfRange { .. } => 1,
            Error::NonFinite { .. } => 2,
            Error::DegenerateFace { .. } => 3,
            Error::RepeatedVertex { .. } => 4,
            Error::UnusedVertex { .. } => 5,
            Error::Empty { .. } => 6,
            Error::SizeMismatch { .. } => 7,
            Error::OutOfRange { .. } => 8,
            Error::CapacityExceeded { .. } => 9,
            Error::IncompatibleModel { .. } => 10,
            Error::UnsupportedEffect { .. } => 11,
            Error::CorruptData { .. } => 12,
            Error::Parse { .. } => 13,
            Error::Io { .. } => 14,
            Error::InsideOut { .. } => 15,
        }
    }

    /// Shorthand for a [`Error::Parse`].
    pub fn parse(format: &'static str, line: usize, message: impl Into<String>) -> Self {
        Error::Parse { format, line, message: message.into() }
    }

    /// An [`Error::Io`] for `path` (feature `std`).
    #[cfg(feature = "std")]
    pub fn io(path: &std::path::Path, e: std::io::Error) -> Self {
        use alloc::string::ToString;
        Error::Io { path: path.display().to_string(), message: e.to_string() }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::IndexOutOfRange { what, at, index, len } => {
                write!(f, "{what} {at} refers to index {index}, but only {len} exist")
            }
            Error::NonFinite { what, index } => write!(f, "{what} {index} is NaN or infinite"),
            Error::DegenerateFace { face } => write!(f, "face {face} has zero area"),
            Error::RepeatedVertex { face, vertex } => {
                write!(f, "face {face} names vertex {vertex} more than once")
            }
            Error::UnusedVertex { vertex } => {
                write!(f, "vertex {vertex} belongs to no triangle (it would have zero mass)")
            }
            Error::Empty { what } => write!(f, "{what} is empty"),
            Error::SizeMismatch { what, expected, got } => {
                write!(f, "{what}: expected length {expected}, got {got}")
            }
            Error::OutOfRange { what, index } => write!(f, "{what} (element {index}) is out of range"),
            Error::CapacityExceeded { what, capacity, needed } => {
                write!(f, "{what}: capacity {capacity} exceeded (needed {needed})")
            }
            Error::IncompatibleModel { reason } => write!(f, "incompatible model: {reason}"),
            Error::UnsupportedEffect { effect } => write!(f, "unsupported effect: {effect}"),
            Error::CorruptData { reason } => write!(f, "corrupt or unsupported data: {reason}"),
            Error::Parse { format, line, message } => {
                if *line > 0 {
                    write!(f, "{format} line {line}: {message}")
                } else {
                    write!(f, "{format}: {message}")
                }
            }
            Error::Io { path, message } => write!(f, "{path}: {message}"),
            Error::InsideOut { what } => write!(
                f,
                "the {what} mesh is inside out (signed volume negative: faces clockwise seen from outside); \
                 reverse the order of every face's vertices"
            ),
        }
    }
}

impl core::error::Error for Error {}
