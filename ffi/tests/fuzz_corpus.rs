//! The C ABI fuzz target's corpus (`fuzz/corpus/ffi_mesh/`) replayed through the target's own
//! entry function on the stable toolchain: garments and bodies of arbitrary arrays must give a
//! status, never a caught panic or a crash.

#[path = "../../fuzz/src/common.rs"]
#[allow(dead_code)]
mod common;
#[path = "../../fuzz/src/ffi.rs"]
mod ffi;

#[test]
fn fuzz_corpus_ffi_mesh_replays_without_panics() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/ffi_mesh");
    common::replay(&dir, ffi::mesh);
}
