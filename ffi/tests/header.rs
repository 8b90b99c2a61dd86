//! `include/hood.h` is hand-written; this test fails when it and the Rust exports disagree:
//! the prototypes (names and C types) parsed from the header equal those derived from the
//! `#[no_mangle] extern "C"` functions in the files of `src/`, which equal the symbols the shared
//! library exports, and all of which `src/lib.rs` re-exports; a generated C++ file then checks
//! every function's type, every constant's value and every struct's layout with the compiler. The linkage and calling-convention macros are checked
//! by what they expand to and, on a 32-bit x86 build whose default convention is stdcall, by the
//! compiler; every status code's `hood_status_string` against the header's comment on it.

mod common;

use common::*;
use std::collections::BTreeMap;
use std::process::Command;

const HEADER: &str = include_str!("../include/hood.h");

/// Every `.rs` file under `src/` with its text, in path order: the exports and constants are
/// defined across its modules.
fn sources() -> Vec<(std::path::PathBuf, String)> {
    fn collect(dir: &std::path::Path, files: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.unwrap().path();
            if path.is_dir() {
                collect(&path, files);
            } else if path.extension().is_some_and(|x| x == "rs") {
                files.push(path);
            }
        }
    }
    let mut files = Vec::new();
    collect(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/src")), &mut files);
    files.sort();
    assert!(files.iter().any(|f| f.ends_with("src/lib.rs")), "src/lib.rs not found in {files:?}");
    files.into_iter().map(|f| (f.clone(), std::fs::read_to_string(f).unwrap())).collect()
}

/// The text of all the files of [`sources`].
fn source() -> String {
    sources().into_iter().map(|(_, text)| text + "\n").collect()
}

/// The crate root, whose `pub use` lists re-export the items of the modules.
const LIB: &str = include_str!("../src/lib.rs");

/// A C type as tokens (`const float *` -> ["const", "float", "*"]).
type CType = Vec<String>;

/// The linkage and calling-convention macros: not part of a C type.
const MACROS: [&str; 2] = ["HOOD_API", "HOOD_CALL"];

fn c_tokens(s: &str) -> CType {
    s.replace('*', " * ").split_whitespace().filter(|t| !MACROS.contains(t)).map(str::to_string).collect()
}

fn strip_c_comments(s: &str) -> String {
    let mut out = String::new();
    let mut rest = s;
    while let Some(i) = rest.find("/*") {
        out.push_str(&rest[..i]);
        let j = rest[i..].find("*/").expect("unterminated comment") + i + 2;
        rest = &rest[j..];
    }
    out.push_str(rest);
    out.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

/// Function prototypes of the header: name -> (return type, parameter types). Every one must
/// start with `HOOD_API` and have `HOOD_CALL` just before its name, and every function pointer
/// declarator must be `(HOOD_CALL *`.
fn header_prototypes() -> BTreeMap<String, (CType, Vec<CType>)> {
    let text = strip_c_comments(HEADER);
    // Drop preprocessor lines and the C++ guard's braces, then struct bodies.
    let lines: Vec<&str> = text
        .lines()
        .filter(|l| !l.trim_start().starts_with('#') && l.trim() != "extern \"C\" {" && l.trim() != "}")
        .collect();
    let mut flat = String::new();
    let mut depth = 0;
    for c in lines.join("\n").chars() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            _ if depth == 0 => flat.push(c),
            _ => {}
        }
    }
    for line in &lines {
        let l = line.split_whitespace().collect::<Vec<_>>().join(" ");
        assert!(!l.contains("(*") && !l.contains("( *"), "a function pointer without HOOD_CALL: `{}`", line.trim());
    }
    let mut out = BTreeMap::new();
    for decl in flat.split(';') {
        let decl = decl.split_whitespace().collect::<Vec<_>>().join(" ");
        if decl.is_empty() || decl.starts_with("typedef") || !decl.contains('(') {
            continue;
        }
        let open = decl.find('(').unwrap();
        let close = decl.rfind(')').unwrap();
        let raw: Vec<&str> = decl[..open].split_whitespace().collect();
        assert!(
            raw.first() == Some(&"HOOD_API") && raw.len() >= 3 && raw[raw.len() - 2].ends_with("HOOD_CALL"),
            "`{decl}`: a function declaration is `HOOD_API <type> HOOD_CALL <name>(...)`"
        );
        let head = c_tokens(&decl[..open]);
        let (name, ret) = head.split_last().unwrap();
        let params: Vec<CType> = decl[open + 1..close]
            .split(',')
            .map(c_tokens)
            .filter(|t| t.as_slice() != ["void"])
            .map(|mut t| {
                assert!(t.len() > 1, "{name}: unnamed parameter");
                t.pop(); // the parameter's name
                t
            })
            .collect();
        assert!(out.insert(name.clone(), (ret.to_vec(), params)).is_none(), "{name} declared twice");
    }
    out
}

/// The C spelling of a Rust FFI type.
fn rust_to_c(ty: &str) -> CType {
    let ty = ty.trim();
    if let Some(inner) = ty.strip_prefix("*const ") {
        let mut t = rust_to_c(inner);
        if !t.contains(&"*".to_string()) {
            t.insert(0, "const".into());
        }
        t.push("*".into());
        return t;
    }
    if let Some(inner) = ty.strip_prefix("*mut ") {
        let mut t = rust_to_c(inner);
        t.push("*".into());
        return t;
    }
    let base = match ty {
        "u32" => "uint32_t",
        "u64" => "uint64_t",
        "u8" => "uint8_t",
        "usize" => "size_t",
        "f32" => "float",
        "c_char" => "char",
        "c_void" => "void",
        t if t.starts_with("hood_") => t,
        t => panic!("no C spelling for the Rust type `{t}` in an export"),
    };
    vec![base.to_string()]
}

/// Exported functions of the files of `src/`: name -> (return type, parameter types), in C
/// spelling.
fn rust_exports() -> BTreeMap<String, (CType, Vec<CType>)> {
    let mut out = BTreeMap::new();
    let source = source();
    let mut rest = source.as_str();
    while let Some(i) = rest.find("#[no_mangle]") {
        rest = &rest[i + "#[no_mangle]".len()..];
        let f = rest.find("extern \"C\" fn ").expect("#[no_mangle] without an extern fn") + "extern \"C\" fn ".len();
        let sig = &rest[f..rest.find('{').unwrap()];
        let open = sig.find('(').unwrap();
        let close = sig.rfind(')').unwrap();
        let name = sig[..open].trim().to_string();
        let params: Vec<CType> = sig[open + 1..close]
            .split(',')
            .filter(|p| !p.trim().is_empty())
            .map(|p| rust_to_c(p.split_once(':').expect("parameter without a type").1))
            .collect();
        let ret = match sig[close + 1..].trim().strip_prefix("->") {
            Some(r) => rust_to_c(r),
            None => vec!["void".to_string()],
        };
        assert!(out.insert(name.clone(), (ret, params)).is_none(), "{name} exported twice");
    }
    out
}

fn c_spelling(t: &CType) -> String {
    t.join(" ").replace(" *", "*")
}

#[test]
fn header_prototypes_equal_rust_exports() {
    let header = header_prototypes();
    let rust = rust_exports();
    assert!(rust.len() >= 20, "parsed only {} exports", rust.len());
    let only_h: Vec<_> = header.keys().filter(|k| !rust.contains_key(*k)).collect();
    let only_r: Vec<_> = rust.keys().filter(|k| !header.contains_key(*k)).collect();
    assert!(
        only_h.is_empty() && only_r.is_empty(),
        "declared but not exported: {only_h:?}; exported but not declared: {only_r:?}"
    );
    for (name, (ret, params)) in &rust {
        let (hret, hparams) = &header[name];
        assert_eq!(ret, hret, "{name}: return type");
        assert_eq!(params.len(), hparams.len(), "{name}: parameter count");
        for (k, (a, b)) in params.iter().zip(hparams).enumerate() {
            assert_eq!(a, b, "{name}: parameter {k} is `{}` in Rust, `{}` in the header", c_spelling(a), c_spelling(b));
        }
    }
}

/// The identifiers that `src/lib.rs` re-exports (its `pub use` lists).
fn reexported() -> std::collections::BTreeSet<&'static str> {
    let mut out = std::collections::BTreeSet::new();
    let mut rest = LIB;
    while let Some(i) = rest.find("pub use ") {
        rest = &rest[i + "pub use ".len()..];
        let end = rest.find(';').expect("a `pub use` without `;`");
        out.extend(rest[..end].split(|c: char| !(c.is_alphanumeric() || c == '_')).filter(|w| !w.is_empty()));
        rest = &rest[end..];
    }
    out
}

/// Every function, constant and type with a `hood_` or `HOOD_` name that a module of `src/`
/// defines is re-exported by `src/lib.rs`, so that Rust callers of the rlib find it at the crate
/// root.
#[test]
fn module_items_are_reexported_at_the_crate_root() {
    let reexported = reexported();
    let mut defined = Vec::new();
    for (path, text) in sources().iter().filter(|(p, _)| !p.ends_with("src/lib.rs")) {
        for line in text.lines() {
            // Items at the top level of a module only (not indented).
            let Some(item) = line.strip_prefix("pub ") else { continue };
            let item = item.strip_prefix("unsafe ").unwrap_or(item);
            let Some(rest) =
                ["const ", "struct ", "type ", "extern \"C\" fn "].iter().find_map(|k| item.strip_prefix(k))
            else {
                continue;
            };
            let name = rest.split(|c: char| !(c.is_alphanumeric() || c == '_')).next().unwrap_or_default();
            if name.starts_with("hood_") || name.starts_with("HOOD_") {
                defined.push((name.to_string(), path.display().to_string()));
            }
        }
    }
    assert!(defined.len() > rust_exports().len(), "parsed only {} items", defined.len());
    let missing: Vec<_> = defined.iter().filter(|(name, _)| !reexported.contains(name.as_str())).collect();
    assert!(missing.is_empty(), "defined in a module but not re-exported by src/lib.rs: {missing:?}");
}

#[test]
fn shared_library_exports_exactly_the_header() {
    if !on_path("nm") {
        println!("shared_library_exports_exactly_the_header: skipped, nm is not on PATH");
        return;
    }
    let so = artifact("libhood_ffi.so");
    let o = Command::new("nm").args(["-D", "--defined-only"]).arg(&so).output().unwrap();
    assert!(o.status.success());
    let mut exported: Vec<String> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().nth(2))
        .filter(|s| s.starts_with("hood_"))
        .map(str::to_string)
        .collect();
    exported.sort();
    let declared: Vec<String> = header_prototypes().into_keys().collect();
    assert_eq!(exported, declared);
}

macro_rules! constants {
    ($($name:ident),* $(,)?) => {
        vec![$((stringify!($name), hood_ffi::$name as u64)),*]
    };
}

macro_rules! layout {
    ($out:ident, $ty:ident { $($field:ident),* $(,)? }) => {
        $out.push_str(&format!(
            "static_assert(sizeof({0}) == {1} && alignof({0}) == {2}, \"{0} size\");\n",
            stringify!($ty),
            std::mem::size_of::<hood_ffi::$ty>(),
            std::mem::align_of::<hood_ffi::$ty>()
        ));
        $(
            $out.push_str(&format!(
                "static_assert(offsetof({0}, {1}) == {2}, \"{0}.{1} offset\");\n",
                stringify!($ty),
                stringify!($field),
                std::mem::offset_of!(hood_ffi::$ty, $field)
            ));
        )*
    };
}

/// Every constant of the Rust side and the header, with its Rust value (the tests below check
/// that no constant is missing from it).
fn checked_constants() -> Vec<(&'static str, u64)> {
    constants![
        HOOD_OK,
        HOOD_ERR_INDEX_OUT_OF_RANGE,
        HOOD_ERR_NON_FINITE,
        HOOD_ERR_DEGENERATE_FACE,
        HOOD_ERR_REPEATED_VERTEX,
        HOOD_ERR_UNUSED_VERTEX,
        HOOD_ERR_EMPTY,
        HOOD_ERR_SIZE_MISMATCH,
        HOOD_ERR_OUT_OF_RANGE,
        HOOD_ERR_CAPACITY_EXCEEDED,
        HOOD_ERR_INCOMPATIBLE_MODEL,
        HOOD_ERR_UNSUPPORTED_EFFECT,
        HOOD_ERR_CORRUPT_DATA,
        HOOD_ERR_PARSE,
        HOOD_ERR_IO,
        HOOD_ERR_INSIDE_OUT,
        HOOD_ERR_NULL_POINTER,
        HOOD_ERR_INVALID_HANDLE,
        HOOD_ERR_MODEL_IN_USE,
        HOOD_ERR_PANIC,
        HOOD_ERR_BAD_POINTER,
        HOOD_ERR_BUSY,
        HOOD_ERR_STRUCT_SIZE,
        HOOD_ERR_TOO_LATE,
        HOOD_MODEL_ALIGN,
        HOOD_MAX_VERTICES,
        HOOD_MAX_FACES,
        HOOD_MAX_MODEL_BYTES,
        HOOD_EFFECT_BODY_COLLISION,
        HOOD_EFFECT_PINNING,
        HOOD_EFFECT_NORMALS,
        HOOD_EFFECT_SLEEPING,
        HOOD_EFFECT_STARTUP,
        HOOD_EFFECT_AUTO_TELEPORT,
        HOOD_EFFECT_SPEED_LIMIT,
        HOOD_EFFECT_COLLISION_PROJECTION,
        HOOD_EFFECT_REFINE,
        HOOD_EFFECT_TETHER,
        HOOD_STEP_TELEPORTED,
        HOOD_STEP_SLEPT,
        HOOD_STEP_STARTUP,
        HOOD_STEP_SPEED_LIMITED,
        HOOD_STEP_REFINED,
        HOOD_STEP_PROJECTED,
        HOOD_STEP_OVER_BUDGET,
        HOOD_STEP_TETHERED,
        HOOD_LOG_ERROR,
        HOOD_LOG_WARNING,
        HOOD_PRECISION_F32,
        HOOD_PRECISION_BF16,
        HOOD_MODEL_TEXT_SCHEDULE,
        HOOD_MODEL_TEXT_PROVENANCE,
        HOOD_VERSION_MAJOR,
        HOOD_VERSION_MINOR,
        HOOD_VERSION_PATCH,
    ]
}

/// Compiles (C++17, -Werror) a file asserting every function's exact type, every constant's
/// value and every struct's size, alignment and field offsets, all taken from the Rust side.
#[test]
fn compiler_checks_types_constants_and_layouts() {
    let consts = checked_constants();
    // Every HOOD_ constant of the Rust side and every numeric #define of the header is listed.
    let listed: std::collections::BTreeSet<&str> = consts.iter().map(|c| c.0).collect();
    let source = source();
    let rust_names: std::collections::BTreeSet<&str> = source
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub const "))
        .filter_map(|l| l.split(':').next())
        .filter(|n| n.starts_with("HOOD_"))
        .collect();
    assert_eq!(rust_names, listed, "Rust constants vs the checked list");
    let header_names: std::collections::BTreeSet<&str> = HEADER
        .lines()
        .filter_map(|l| l.strip_prefix("#define "))
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            let (name, value) = (w.next()?, w.next()?);
            value.chars().next()?.is_ascii_digit().then_some(name)
        })
        .collect();
    assert_eq!(header_names, listed, "header #defines vs the checked list");

    let mut cpp = String::from("#include \"hood.h\"\n#include <cstddef>\n#include <type_traits>\n");
    for (name, value) in &consts {
        cpp.push_str(&format!("static_assert({name} == {value}u, \"{name}\");\n"));
    }
    cpp.push_str("static_assert(std::is_same<hood_status, uint32_t>::value, \"hood_status\");\n");
    cpp.push_str(
        "static_assert(std::is_same<hood_task_fn, void (*)(void *, uint32_t)>::value, \"hood_task_fn\");\n\
         static_assert(std::is_same<decltype(hood_executor::run), void (*)(void *, uint32_t, hood_task_fn, void *)>::value, \"run\");\n\
         static_assert(std::is_same<hood_log_fn, void (*)(uint32_t, const char *, void *)>::value, \"hood_log_fn\");\n",
    );
    for (name, (ret, params)) in rust_exports() {
        let ps: Vec<String> = params.iter().map(c_spelling).collect();
        let ps = if ps.is_empty() { "void".to_string() } else { ps.join(", ") };
        cpp.push_str(&format!(
            "static_assert(std::is_same<decltype(&{name}), {} (*)({ps})>::value, \"{name}\");\n",
            c_spelling(&ret)
        ));
    }
    layout!(cpp, hood_material { struct_size, density, mu, lambda, bending });
    layout!(
        cpp,
        hood_sim_config {
            struct_size,
            effects,
            precision,
            threads,
            sleep_frames,
            sleep_threshold,
            teleport_threshold,
            speed_limit,
            projection_margin,
            refine_iterations,
            solver_iterations,
            solver_budget_us,
            tether_slack
        }
    );
    layout!(cpp, hood_body_desc { struct_size, positions, n_vertices, indices, n_faces, omitted });
    layout!(cpp, hood_refinement { struct_size, iterations, energy_before, energy_after, budget_ns, used_ns });
    layout!(cpp, hood_body_survey { struct_size, volume, median_edge, longest_edge, too_coarse });
    layout!(
        cpp,
        hood_model_info {
            struct_size,
            format_version,
            latent,
            hidden_layers,
            blocks,
            levels,
            has_bf16,
            effects,
            local_materials,
            frame_time,
            length_unit,
            up_axis,
            parameters,
            schedule_len,
            provenance_len
        }
    );
    layout!(cpp, hood_executor { struct_size, user, parallelism, run });
    layout!(cpp, hood_allocator { struct_size, user, alloc, free });
    // The config-defaults macro, called as C++ code may spell it (after `::`, and as a
    // statement); it must fill the caller's whole struct.
    cpp.push_str(
        "static void defaults(hood_sim_config *c) { ::hood_sim_config_default(c); hood_sim_config_default(c); }\n\
         static_assert(std::is_same<decltype(hood_sim_config_default((hood_sim_config *)0)), hood_status>::value, \"macro\");\n",
    );
    cpp.push_str("int main() { hood_sim_config c; (void)&defaults; (void)c; return 0; }\n");

    let dir = scratch("header");
    let src = dir.join("abi_check.cpp");
    std::fs::write(&src, &cpp).unwrap();
    let o = Command::new("c++")
        .args(["-std=c++17", "-Wall", "-Wextra", "-Werror", "-fsyntax-only", "-I"])
        .arg(include_dir())
        .arg(&src)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stderr), cpp);
}

/// The header compiles as strict C99 on its own and with every pedantic warning.
#[test]
fn header_is_strict_c99_and_cpp() {
    let dir = scratch("header_strict");
    let src = dir.join("only_header.c");
    std::fs::write(&src, "#include \"hood.h\"\nint main(void) { return hood_version() == HOOD_VERSION ? 0 : 1; }\n")
        .unwrap();
    for (cc, std) in [("cc", "-std=c99"), ("c++", "-std=c++11")] {
        let lang = if cc == "c++" { "c++" } else { "c" };
        let o = Command::new(cc)
            .args([std, "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-fsyntax-only", "-x", lang, "-I"])
            .arg(include_dir())
            .arg(&src)
            .output()
            .unwrap();
        assert!(o.status.success(), "{cc}: {}", String::from_utf8_lossy(&o.stderr));
    }
}

/// The status codes' `#define` lines: (name, value, the comment stating the meaning).
fn header_status_codes() -> Vec<(String, u32, String)> {
    HEADER
        .lines()
        .filter_map(|l| l.strip_prefix("#define "))
        .filter(|l| l.starts_with("HOOD_OK ") || l.starts_with("HOOD_ERR_"))
        .map(|l| {
            let mut w = l.split_whitespace();
            let (name, value) = (w.next().unwrap(), w.next().unwrap());
            let comment = l.split_once("/*").and_then(|(_, c)| c.split_once("*/")).map(|(c, _)| c.trim());
            let comment = comment.unwrap_or_else(|| panic!("{name}: no comment stating its meaning"));
            (name.to_string(), value.trim_end_matches('u').parse().unwrap(), comment.to_string())
        })
        .collect()
}

fn status_string(code: u32) -> String {
    // SAFETY: a static NUL-terminated string for any code.
    unsafe { std::ffi::CStr::from_ptr(hood_ffi::hood_status_string(code)) }.to_str().unwrap().to_string()
}

/// Every status code's string is "NAME: meaning" as the header's comment on it states it (so all
/// are distinct); any other code gives "unknown status".
#[test]
fn status_strings_match_the_header() {
    let codes = header_status_codes();
    let listed: Vec<(&str, u64)> =
        checked_constants().into_iter().filter(|(n, _)| *n == "HOOD_OK" || n.starts_with("HOOD_ERR_")).collect();
    assert_eq!(codes.len(), listed.len(), "status codes of the header vs the checked list");
    let mut strings = std::collections::BTreeSet::new();
    for (name, value, meaning) in &codes {
        assert!(listed.contains(&(name.as_str(), *value as u64)), "{name} = {value} is not in the checked list");
        let s = status_string(*value);
        assert_eq!(s, format!("{name}: {meaning}"), "hood_status_string({value})");
        assert!(strings.insert(s), "{name}: its string is not distinct");
    }
    let known: Vec<u32> = codes.iter().map(|c| c.1).collect();
    for code in (0..=1000).chain([4096, u32::MAX - 1, u32::MAX]).filter(|c| !known.contains(c)) {
        assert_eq!(status_string(code), "unknown status", "code {code}");
    }
}

/// What `HOOD_API` and `HOOD_CALL` expand to for a target (the defines that mark it).
fn macro_expansion(defines: &[&str]) -> String {
    let dir = scratch("macros");
    let src = dir.join("macros.c");
    std::fs::write(&src, "#include \"hood.h\"\nAPI=HOOD_API CALL=HOOD_CALL\n").unwrap();
    let o = Command::new("cc")
        .args(["-E", "-P", "-ffreestanding", "-I"])
        .arg(include_dir())
        .args(defines)
        .arg(&src)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let line = out.lines().rev().find(|l| l.starts_with("API=")).unwrap_or_else(|| panic!("{out}"));
    line.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// The linkage and calling-convention macros for each kind of target (the Windows ones emulated by
/// their predefined macros).
#[test]
fn linkage_and_calling_convention_macros_expand_per_target() {
    let cases: [(&[&str], &str); 6] = [
        (&[], "API=__attribute__((visibility(\"default\"))) CALL="),
        (&["-D_WIN32"], "API= CALL=__cdecl"),
        (&["-D_WIN32", "-DHOOD_SHARED"], "API=__declspec(dllimport) CALL=__cdecl"),
        (&["-D_WIN32", "-D_WIN64"], "API= CALL="),
        (&["-D_WIN32", "-D_WIN64", "-DHOOD_SHARED"], "API=__declspec(dllimport) CALL="),
        (&["-DHOOD_API=", "-DHOOD_SHARED"], "API= CALL="),
    ];
    for (defines, want) in cases {
        assert_eq!(macro_expansion(defines), want, "{defines:?}");
    }
}

/// On 32-bit x86 with stdcall as the compiler's default (`-mrtd`, as MSVC's /Gz), and `_WIN32`
/// defined so that `HOOD_CALL` is `__cdecl`, every function and function pointer type of the
/// header is cdecl: the C compiler refuses to initialise a cdecl pointer from anything else.
/// Skipped without a compiler that builds 32-bit x86 code.
#[test]
fn hood_call_makes_every_function_and_callback_cdecl() {
    let dir = scratch("cdecl");
    let flags = [
        "-m32",
        "-mrtd",
        "-ffreestanding",
        "-std=c99",
        "-Wall",
        "-Wextra",
        "-Werror",
        "-fsyntax-only",
        "-D_WIN32",
        "-D__cdecl=__attribute__((cdecl))",
    ];
    let compiles = |name: &str, text: &str| {
        let src = dir.join(name);
        std::fs::write(&src, text).unwrap();
        let o = Command::new("cc").args(flags).arg("-I").arg(include_dir()).arg(&src).output().unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let probe = "#include <stdint.h>\nuint32_t (__cdecl *p)(void);\n";
    if !compiles("probe.c", probe).0 {
        println!("hood_call_makes_every_function_and_callback_cdecl: skipped, cc cannot build 32-bit x86");
        return;
    }
    // The check can fail: a function without the convention is refused under these flags.
    let control = "#include <stdint.h>\nuint32_t f(void);\nuint32_t (__cdecl *p)(void) = f;\n";
    assert!(!compiles("control.c", control).0, "-mrtd did not make stdcall the default");
    let mut c = String::from("#include \"hood.h\"\n");
    for (name, (ret, params)) in rust_exports() {
        let ps: Vec<String> = params.iter().map(c_spelling).collect();
        let ps = if ps.is_empty() { "void".to_string() } else { ps.join(", ") };
        c.push_str(&format!("{} (__cdecl *p_{name})({ps}) = {name};\n", c_spelling(&ret)));
    }
    c.push_str(
        "void check_callbacks(hood_task_fn task, const hood_executor *e, hood_log_fn log);\n\
         void check_callbacks(hood_task_fn task, const hood_executor *e, hood_log_fn log) {\n\
         \x20   void (__cdecl *t)(void *, uint32_t) = task;\n\
         \x20   void (__cdecl *r)(void *, uint32_t, hood_task_fn, void *) = e->run;\n\
         \x20   void (__cdecl *l)(uint32_t, const char *, void *) = log;\n\
         \x20   (void)t;\n\
         \x20   (void)r;\n\
         \x20   (void)l;\n\
         }\n",
    );
    let (ok, stderr) = compiles("cdecl.c", &c);
    assert!(ok, "{stderr}\n{c}");
}
