//! The entry functions of the fuzz targets, one per input a user or a file can give. The
//! stable-toolchain tests replay the committed corpora through the same functions
//! (`tests/fuzz_corpus.rs`, `ffi/tests/fuzz_corpus.rs`, which include these files), so a target
//! and its smoke test cannot drift apart.

pub mod common;
pub mod entries;
pub mod ffi;
