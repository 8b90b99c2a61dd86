//! The fuzz targets' corpora (`fuzz/corpus/TARGET/`) replayed through the targets' own entry
//! functions on the stable toolchain: every file, found by the fuzzers or written as a seed, must
//! give errors, never a panic. The C ABI's target is replayed by `ffi/tests/fuzz_corpus.rs`.
#![cfg(feature = "tools")]

#[path = "../fuzz/src/common.rs"]
#[allow(dead_code)]
mod common;
#[path = "../fuzz/src/entries.rs"]
mod entries;

/// An entry function of a fuzz target.
type Entry = fn(&[u8]);

#[test]
fn fuzz_corpora_replay_without_panics() {
    let targets: [(&str, Entry); 7] = [
        ("model", entries::model),
        ("obj", entries::obj),
        ("bvh", entries::bvh),
        ("mhclo", entries::mhclo),
        ("json", entries::json),
        ("safetensors", entries::safetensors),
        ("gltf", entries::gltf),
    ];
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    for (target, entry) in targets {
        common::replay(&root.join(target), entry);
    }
}
