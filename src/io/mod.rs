//! File formats (feature `std`): readers and writers that turn files into the crate's plain
//! arrays and back. Errors are [`crate::Error::Parse`] (with the 1-based line) and
//! [`crate::Error::Io`].

pub mod bvh;
pub mod json;
pub mod makehuman;
pub mod obj;
pub mod png;
pub mod safetensors;
pub mod zlib;
