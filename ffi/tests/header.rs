//! `include/hood.h` is hand-written; this test fails when it and the Rust exports disagree:
//! the prototypes (names and C types) parsed from the header equal those derived from the
//! `#[no_mangle] extern "C"` functions in `src/lib.rs`, which equal the symbols the shared library
//! exports; a generated C++ file then checks every function's type, every constant's value and
//! every struct's layout with the compiler.

mod common;

use common::*;
use std::collections::BTreeMap;
use std::process::Command;

const HEADER: &str = include_str!("../include/hood.h");
const SOURCE: &str = include_str!("../src/lib.rs");

/// A C type as tokens (`const float *` -> ["const", "float", "*"]).
type CType = Vec<String>;

fn c_tokens(s: &str) -> CType {
    s.replace('*', " * ").split_whitespace().map(str::to_string).collect()
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

/// Function prototypes of the header: name -> (return type, parameter types).
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
    let mut out = BTreeMap::new();
    for decl in flat.split(';') {
        let decl = decl.split_whitespace().collect::<Vec<_>>().join(" ");
        if decl.is_empty() || decl.starts_with("typedef") || !decl.contains('(') {
            continue;
        }
        let open = decl.find('(').unwrap();
        let close = decl.rfind(')').unwrap();
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

/// Exported functions of `src/lib.rs`: name -> (return type, parameter types), in C spelling.
fn rust_exports() -> BTreeMap<String, (CType, Vec<CType>)> {
    let mut out = BTreeMap::new();
    let mut rest = SOURCE;
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

/// Compiles (C++17, -Werror) a file asserting every function's exact type, every constant's
/// value and every struct's size, alignment and field offsets, all taken from the Rust side.
#[test]
fn compiler_checks_types_constants_and_layouts() {
    let consts = constants![
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
        HOOD_MODEL_ALIGN,
        HOOD_EFFECT_BODY_COLLISION,
        HOOD_EFFECT_PINNING,
        HOOD_EFFECT_NORMALS,
        HOOD_EFFECT_SLEEPING,
        HOOD_EFFECT_STARTUP,
        HOOD_EFFECT_AUTO_TELEPORT,
        HOOD_EFFECT_SPEED_LIMIT,
        HOOD_EFFECT_COLLISION_PROJECTION,
        HOOD_EFFECT_REFINE,
        HOOD_PRECISION_F32,
        HOOD_PRECISION_BF16,
        HOOD_VERSION_MAJOR,
        HOOD_VERSION_MINOR,
        HOOD_VERSION_PATCH,
    ];
    // Every HOOD_ constant of the Rust side and every numeric #define of the header is listed.
    let listed: std::collections::BTreeSet<&str> = consts.iter().map(|c| c.0).collect();
    let rust_names: std::collections::BTreeSet<&str> = SOURCE
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
         static_assert(std::is_same<decltype(hood_executor::run), void (*)(void *, uint32_t, hood_task_fn, void *)>::value, \"run\");\n",
    );
    for (name, (ret, params)) in rust_exports() {
        let ps: Vec<String> = params.iter().map(c_spelling).collect();
        let ps = if ps.is_empty() { "void".to_string() } else { ps.join(", ") };
        cpp.push_str(&format!(
            "static_assert(std::is_same<decltype(&{name}), {} (*)({ps})>::value, \"{name}\");\n",
            c_spelling(&ret)
        ));
    }
    layout!(cpp, hood_material { density, mu, lambda, bending });
    layout!(
        cpp,
        hood_sim_config {
            effects,
            precision,
            threads,
            sleep_frames,
            sleep_threshold,
            teleport_threshold,
            speed_limit,
            projection_margin,
            refine_iterations,
            solver_iterations
        }
    );
    layout!(cpp, hood_body_desc { positions, n_vertices, indices, n_faces, omitted });
    layout!(cpp, hood_refinement { iterations, energy_before, energy_after });
    layout!(cpp, hood_body_survey { volume, median_edge, longest_edge, too_coarse });
    layout!(cpp, hood_executor { user, parallelism, run });
    cpp.push_str("int main() { return 0; }\n");

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
