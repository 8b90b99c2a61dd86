//! File formats (feature `std`): readers and writers that turn files into the crate's plain
//! arrays and back. Errors are [`crate::Error::Parse`] (with the 1-based line) and
//! [`crate::Error::Io`].

pub mod json;
pub mod obj;
pub mod safetensors;
