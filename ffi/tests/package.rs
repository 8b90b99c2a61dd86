//! `install.sh` as a user runs it (on the libraries of this test build): the installed layout,
//! the shared library's SONAME, the pkg-config file, and a CMake project that finds the package
//! (`find_package(hood)`, `hood::hood` and `hood::hood_static`) and builds and runs the drape
//! examples. The checks that need readelf, pkg-config or cmake say SKIPPED without them.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The SONAME: `libhood_ffi.so.MAJOR`, `libhood_ffi.so.0.MINOR` before 1.0.
fn soname() -> String {
    let (major, minor) = (env!("CARGO_PKG_VERSION_MAJOR"), env!("CARGO_PKG_VERSION_MINOR"));
    if major == "0" {
        format!("libhood_ffi.so.0.{minor}")
    } else {
        format!("libhood_ffi.so.{major}")
    }
}

fn run(cmd: &mut Command) -> String {
    let o = cmd.output().unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(o.status.success(), "{cmd:?} failed:\n{out}{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// Installs into a fresh prefix from this build's libraries.
fn install(name: &str) -> PathBuf {
    let prefix = scratch(name).join("prefix");
    let libs = artifact("libhood_ffi.so").parent().unwrap().to_path_buf();
    let script = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/install.sh"));
    run(Command::new("bash").arg(script).arg(&prefix).env("HOOD_FFI_LIB_DIR", libs));
    prefix
}

#[test]
fn install_lays_out_libraries_header_cmake_and_pkg_config() {
    let prefix = install("package_layout");
    let lib = prefix.join("lib");
    for f in [
        "include/hood.h".to_string(),
        "lib/libhood_ffi.a".to_string(),
        format!("lib/libhood_ffi.so.{VERSION}"),
        "lib/cmake/hood/hoodConfig.cmake".to_string(),
        "lib/cmake/hood/hoodConfigVersion.cmake".to_string(),
        "lib/pkgconfig/hood.pc".to_string(),
    ] {
        assert!(prefix.join(&f).is_file(), "{f} is not installed");
    }
    // The SONAME link and the development link lead to the versioned file.
    let link = |name: &str| std::fs::read_link(lib.join(name)).unwrap().to_string_lossy().into_owned();
    assert_eq!(link(&soname()), format!("libhood_ffi.so.{VERSION}"));
    assert_eq!(link("libhood_ffi.so"), soname());
    assert_eq!(
        std::fs::read(prefix.join("include/hood.h")).unwrap(),
        std::fs::read(include_dir().join("hood.h")).unwrap()
    );
    if on_path("readelf") {
        let dynamic = run(Command::new("readelf").arg("-d").arg(lib.join(format!("libhood_ffi.so.{VERSION}"))));
        assert!(dynamic.contains(&format!("Library soname: [{}]", soname())), "{dynamic}");
    } else {
        println!("SKIPPED the SONAME check: readelf is not on PATH");
    }
    if on_path("pkg-config") {
        let pc = |args: &[&str]| {
            run(Command::new("pkg-config").args(args).arg("hood").env("PKG_CONFIG_PATH", lib.join("pkgconfig")))
        };
        assert_eq!(pc(&["--modversion"]).trim(), VERSION);
        assert_eq!(pc(&["--cflags"]).trim(), format!("-I{}", prefix.join("include").display()));
        assert!(pc(&["--libs"]).contains("-lhood_ffi"));
        assert!(pc(&["--static", "--libs"]).contains("-ldl"));
    } else {
        println!("SKIPPED the pkg-config checks: pkg-config is not on PATH");
    }
}

/// Configures, builds and runs `examples/cmake` against `prefix` (shared or static library).
fn cmake_drape(prefix: &Path, dir: &Path, statik: bool, model: &Path) -> String {
    let build = dir.join(if statik { "build-static" } else { "build-shared" });
    run(Command::new("cmake")
        .arg("-S")
        .arg(example("cmake"))
        .arg("-B")
        .arg(&build)
        .arg(format!("-DCMAKE_PREFIX_PATH={}", prefix.display()))
        .arg(format!("-DHOOD_STATIC={}", if statik { "ON" } else { "OFF" })));
    run(Command::new("cmake").arg("--build").arg(&build));
    let c = run(Command::new(build.join("drape")).arg(model).arg("6"));
    let cpp = run(Command::new(build.join("drape_cpp")).arg(model).arg("6"));
    let bbox = |s: &str| s.lines().find(|l| l.starts_with("bbox: ")).map(str::to_string);
    assert!(bbox(&c).is_some() && bbox(&c) == bbox(&cpp), "C and C++ disagree:\n{c}\n{cpp}");
    if !statik && on_path("ldd") {
        let deps = run(Command::new("ldd").arg(build.join("drape")));
        assert!(deps.contains(&format!("{} => {}", soname(), prefix.join("lib").display())), "{deps}");
    }
    c
}

#[test]
fn a_cmake_project_finds_the_installed_package_and_runs_drape() {
    if !on_path("cmake") {
        println!("SKIPPED a_cmake_project_finds_the_installed_package_and_runs_drape: cmake is not on PATH");
        return;
    }
    let prefix = install("package_cmake");
    let dir = scratch("package_cmake_builds");
    let model = model_file(&dir, 8, 31);
    let shared = cmake_drape(&prefix, &dir, false, &model);
    let statik = cmake_drape(&prefix, &dir, true, &model);
    let bbox = |s: &str| s.lines().find(|l| l.starts_with("bbox: ")).map(str::to_string);
    assert_eq!(bbox(&shared), bbox(&statik), "the shared and static libraries disagree");
}
