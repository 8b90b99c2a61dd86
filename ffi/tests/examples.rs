//! Builds the C and C++ examples against `include/hood.h` and `libhood_ffi.a`, runs them on a
//! random model and checks what they print; runs the C example under valgrind memcheck.

mod common;

use common::*;
use std::path::Path;
use std::process::Command;

/// The report of an example run: steps, the final bounding box, and the vertices pushed out of
/// the body at the start (C example only).
struct Report {
    steps: usize,
    min: [f64; 3],
    max: [f64; 3],
    pushed: Option<usize>,
}

fn parse(stdout: &str) -> Report {
    let line = |key: &str| -> &str {
        stdout.lines().find_map(|l| l.strip_prefix(key)).unwrap_or_else(|| panic!("no `{key}` line in:\n{stdout}"))
    };
    let steps = line("steps: ").trim().parse().unwrap();
    assert!(line("time: ").contains("ms/step"), "{stdout}");
    let nums: Vec<f64> = line("bbox: ")
        .split_whitespace()
        .filter(|w| *w != "min" && *w != "max")
        .map(|w| w.parse().unwrap_or(f64::NAN))
        .collect();
    assert_eq!(nums.len(), 6, "{stdout}");
    let pushed = stdout.lines().find_map(|l| l.strip_prefix("pushed out: ")?.strip_suffix(" vertices")?.parse().ok());
    Report { steps, min: [nums[0], nums[1], nums[2]], max: [nums[3], nums[4], nums[5]], pushed }
}

fn run(exe: &Path, model: &Path, grid: usize) -> Report {
    let o = Command::new(exe).arg(model).arg(grid.to_string()).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(o.status.success(), "{} failed:\n{stdout}{}", exe.display(), String::from_utf8_lossy(&o.stderr));
    print!("{}: {stdout}", exe.display());
    parse(&stdout)
}

/// The draped square: 60 steps, a finite box that is still about the cloth's size (0.6 m wide,
/// pinned corners at y = 0.32), not exploded.
fn check_report(r: &Report) {
    assert_eq!(r.steps, 60);
    for k in 0..3 {
        assert!(r.min[k].is_finite() && r.max[k].is_finite(), "non-finite box");
        assert!(r.min[k] <= r.max[k]);
        assert!(r.max[k] - r.min[k] < 5.0, "box exploded: {:?} {:?}", r.min, r.max);
    }
    assert!(r.max[0] - r.min[0] > 0.3, "the cloth lost its width: {:?} {:?}", r.min, r.max);
    assert!(r.min[1] <= 0.32 + 1e-3 && r.max[1] >= 0.32 - 1e-3, "pins at y = 0.32 not inside the box");
}

#[test]
fn c_example_builds_and_drapes() {
    let dir = scratch("c_example");
    let model = model_file(&dir, 16, 7);
    let exe = dir.join("drape");
    compile("cc", C_FLAGS, &example("drape.c"), &exe);
    let r = run(&exe, &model, 16);
    check_report(&r);
    // The cloth starts 2 cm above the body: the push-out leaves it.
    assert_eq!(r.pushed, Some(0));
}

#[test]
fn cpp_example_builds_and_drapes() {
    let dir = scratch("cpp_example");
    let model = model_file(&dir, 16, 7);
    let exe = dir.join("drape_cpp");
    compile("c++", CXX_FLAGS, &example("drape.cpp"), &exe);
    let r = run(&exe, &model, 16);
    check_report(&r);
    assert_eq!(r.pushed, Some(0));
}

/// The C and C++ examples run the same scene; the C++ one through a 2-thread executor. The
/// step's sums do not depend on the task split, so the boxes agree.
#[test]
fn c_and_cpp_examples_agree() {
    let dir = scratch("agree");
    let model = model_file(&dir, 16, 11);
    let (c, cpp) = (dir.join("drape"), dir.join("drape_cpp"));
    compile("cc", C_FLAGS, &example("drape.c"), &c);
    compile("c++", CXX_FLAGS, &example("drape.cpp"), &cpp);
    let (a, b) = (run(&c, &model, 12), run(&cpp, &model, 12));
    for k in 0..3 {
        assert!((a.min[k] - b.min[k]).abs() < 1e-4 && (a.max[k] - b.max[k]).abs() < 1e-4);
    }
}

/// The documented memcheck command:
/// `valgrind --leak-check=full --error-exitcode=1 ./drape model.hood 8`.
#[test]
fn c_example_valgrind_memcheck() {
    if !on_path("valgrind") {
        println!("c_example_valgrind_memcheck: skipped, valgrind is not on PATH");
        return;
    }
    let dir = scratch("valgrind");
    let model = model_file(&dir, 8, 3);
    let exe = dir.join("drape");
    compile("cc", C_FLAGS, &example("drape.c"), &exe);
    let o = Command::new("valgrind")
        .args(["--leak-check=full", "--error-exitcode=1", "--errors-for-leak-kinds=definite,indirect,possible"])
        .arg(&exe)
        .arg(&model)
        .arg("8")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "valgrind reported errors:\n{stderr}");
    assert!(stderr.contains("ERROR SUMMARY: 0 errors"), "{stderr}");
    assert!(!stderr.contains("definitely lost: ") || stderr.contains("definitely lost: 0 bytes"), "{stderr}");
    check_report(&parse(&String::from_utf8_lossy(&o.stdout)));
}

/// `tests/c/alloc_hooks.c`: an allocator installed first gets every allocation of a model load,
/// a sim's creation, steps and frees (each free with its block's size and alignment), and a
/// second installation is refused with `HOOD_ERR_TOO_LATE`.
#[test]
fn allocator_callbacks_get_every_allocation() {
    let dir = scratch("alloc_hooks");
    let model = model_file(&dir, 8, 5);
    let exe = dir.join("alloc_hooks");
    let src = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/c/alloc_hooks.c"));
    compile("cc", C_FLAGS, &src, &exe);
    let o = Command::new(&exe).arg(&model).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "exit {:?}: {stdout}{}", o.status.code(), String::from_utf8_lossy(&o.stderr));
    assert!(stdout.starts_with("allocations: "), "{stdout}");
}
