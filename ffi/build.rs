//! Gives the shared library an ABI-versioned SONAME on ELF targets: `libhood_ffi.so.MAJOR`, and
//! for 0.x versions (where every minor version may break the ABI) `libhood_ffi.so.0.MINOR`.
//! `install.sh` installs the file as `libhood_ffi.so.MAJOR.MINOR.PATCH` with the SONAME and the
//! development name as links to it.

fn main() {
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let elf = matches!(os.as_str(), "linux" | "android" | "freebsd" | "netbsd" | "openbsd" | "dragonfly");
    if elf {
        let major = std::env::var("CARGO_PKG_VERSION_MAJOR").unwrap_or_default();
        let minor = std::env::var("CARGO_PKG_VERSION_MINOR").unwrap_or_default();
        let abi = if major == "0" { format!("0.{minor}") } else { major };
        println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,libhood_ffi.so.{abi}");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
