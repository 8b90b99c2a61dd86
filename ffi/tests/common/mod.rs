//! Shared by the hood-ffi integration tests: a small random model file, the built libraries, and
//! compiling C/C++ against the header.
#![allow(dead_code)]

use hood::model::{write_model, ModelSpec, Params};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The bytes of a small random model (latent width `h`) whose normalisers have seen unit-scale
/// rows, so that features and outputs stay in a sensible range (as in the main crate's tests).
pub fn random_model_bytes(h: usize, seed: u64) -> Vec<u8> {
    let spec = ModelSpec::hood(h);
    let mut p = Params::init(&spec, seed).unwrap();
    p.normalisers = hood::model::Normalisers::unit_scale(seed);
    write_model(&p, false, &[("kind", "random hood-ffi test model")]).unwrap()
}

/// A body descriptor of the current `struct_size` over `positions` and `faces` (no omitted
/// vertices); the arrays must outlive its use.
pub fn body_desc(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> hood_ffi::hood_body_desc {
    hood_ffi::hood_body_desc {
        struct_size: size_of::<hood_ffi::hood_body_desc>() as u32,
        positions: positions.as_ptr().cast(),
        n_vertices: positions.len(),
        indices: faces.as_ptr().cast(),
        n_faces: faces.len(),
        omitted: std::ptr::null(),
    }
}

/// A fresh scratch directory under the target directory.
pub fn scratch(name: &str) -> PathBuf {
    let d = target_dir().join("hood-ffi-tests").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Writes a random model file into `dir` and returns its path.
pub fn model_file(dir: &Path, h: usize, seed: u64) -> PathBuf {
    let p = dir.join(format!("random-h{h}.hood"));
    std::fs::write(&p, random_model_bytes(h, seed)).unwrap();
    p
}

/// `target/<profile>`: the test binary lives in its `deps/`.
pub fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.parent().and_then(Path::parent).unwrap().to_path_buf()
}

/// A library artifact of this crate that cargo built for this test run (`libhood_ffi.a`,
/// `libhood_ffi.so`): it sits beside the test binary in `deps/` (the copies in `target/<profile>`
/// come from `cargo build` and may be stale or of another profile).
pub fn artifact(file: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let p = exe.parent().unwrap().join(file);
    assert!(p.exists(), "{} is missing: cargo builds it with the crate's lib target", p.display());
    p
}

pub fn include_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/include"))
}

pub fn example(file: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples")).join(file)
}

/// Compiles `src` with `compiler` and `flags` against the header and the static library.
pub fn compile(compiler: &str, flags: &[&str], src: &Path, out: &Path) {
    let mut cmd = Command::new(compiler);
    cmd.args(flags).arg("-I").arg(include_dir()).arg(src).arg(artifact("libhood_ffi.a"));
    cmd.args(["-lpthread", "-ldl", "-lm", "-o"]).arg(out);
    let o = cmd.output().unwrap_or_else(|e| panic!("cannot run {compiler}: {e}"));
    assert!(
        o.status.success(),
        "{compiler} failed on {}:\n{}{}",
        src.display(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

pub const C_FLAGS: &[&str] = &["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2"];
pub const CXX_FLAGS: &[&str] = &["-std=c++17", "-Wall", "-Wextra", "-Werror", "-O2"];

pub fn on_path(tool: &str) -> bool {
    Command::new(tool).arg("--version").output().map(|o| o.status.success()).unwrap_or(false)
}

/// The default config, as the header's `hood_sim_config_default(&cfg)` gives it
/// (`hood_sim_config_init` with this struct's size).
pub fn default_config() -> hood_ffi::hood_sim_config {
    let mut c = std::mem::MaybeUninit::<hood_ffi::hood_sim_config>::zeroed();
    // SAFETY: a whole, writable struct; the library fills every field.
    unsafe {
        let s = hood_ffi::hood_sim_config_init(c.as_mut_ptr(), size_of::<hood_ffi::hood_sim_config>());
        assert_eq!(s, hood_ffi::HOOD_OK);
        c.assume_init()
    }
}

/// [`default_config`] with the network's step (`solver_iterations` 0).
pub fn network_config() -> hood_ffi::hood_sim_config {
    hood_ffi::hood_sim_config { solver_iterations: 0, ..default_config() }
}
