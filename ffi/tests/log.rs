//! The log callback (its own test binary: the callback is process-wide). Warnings and caught
//! panics reach it with the caller's `user`; with it set, a panic no longer prints to stderr, and
//! without it stderr gets Rust's panic message as before.

mod common;

use common::{network_config, random_model_bytes};
use hood::model::ModelBytes;
use hood_ffi::*;
use std::ffi::{c_char, c_void, CStr};
use std::process::Command;
use std::ptr::{null, null_mut};
use std::sync::Mutex;

static MESSAGES: Mutex<Vec<(u32, String)>> = Mutex::new(Vec::new());
static TOKEN: u8 = 7;

unsafe extern "C-unwind" fn collect(level: u32, message: *const c_char, user: *mut c_void) {
    assert_eq!(user as *const u8, &TOKEN as *const u8, "the callback got another user pointer");
    // SAFETY: a NUL-terminated string valid during the call (the header's contract).
    let text = unsafe { CStr::from_ptr(message) }.to_string_lossy().into_owned();
    MESSAGES.lock().unwrap().push((level, text));
}

fn messages() -> Vec<(u32, String)> {
    std::mem::take(&mut *MESSAGES.lock().unwrap())
}

fn last_error() -> String {
    // SAFETY: `hood_last_error` returns a NUL-terminated string valid until the next call.
    unsafe { CStr::from_ptr(hood_last_error()) }.to_string_lossy().into_owned()
}

/// A sim of a 6 x 6 cloth over an ellipsoid of `rings x segments` (12 x 16: too coarse for the
/// body edges; 40 x 64: fine).
fn sim(model: *const hood_model, rings: usize, segments: usize) -> *mut hood_sim {
    sim_on(model, rings, segments, 1)
}

/// [`sim`] asking for `threads` threads.
fn sim_on(model: *const hood_model, rings: usize, segments: usize, threads: u32) -> *mut hood_sim {
    let (rest, faces) = hood::mesh::shapes::grid(6, 6, 0.6, 0.6, 0.32);
    let (body, body_faces) = hood::body::shapes::ellipsoid(rings, segments, [0.25, 0.3, 0.25], [0.0; 3]);
    let desc = common::body_desc(&body, &body_faces);
    let (mut g, mut s) = (null_mut(), null_mut());
    // SAFETY: arrays of the stated lengths; live handles.
    unsafe {
        let (r, f) = (rest.as_ptr().cast(), faces.as_ptr().cast());
        assert_eq!(hood_garment_new(r, rest.len(), f, faces.len(), null(), 0, null(), &mut g), HOOD_OK);
        // The network's step, whose tasks run on the executor.
        let cfg = hood_sim_config { threads, ..network_config() };
        assert_eq!(hood_sim_new(model, g, &desc, &cfg, &mut s), HOOD_OK, "{}", last_error());
        assert_eq!(hood_garment_free(g), HOOD_OK);
    }
    s
}

/// An executor that runs no task: the step panics inside the library (`HOOD_ERR_PANIC`).
unsafe extern "C-unwind" fn run_nothing(_: *mut c_void, _: u32, _: hood_task_fn, _: *mut c_void) {}

/// Steps `sim` on [`run_nothing`]: the caught panic's status and message.
fn failing_step(sim: *mut hood_sim) -> (hood_status, String) {
    let exec = hood_executor {
        struct_size: size_of::<hood_executor>() as u32,
        user: null_mut(),
        parallelism: 2,
        run: Some(run_nothing),
    };
    let mut n = 0;
    let mut nb = 0;
    // SAFETY: a live sim; arrays of the stated lengths.
    unsafe {
        assert_eq!(hood_sim_vertex_count(sim, &mut n), HOOD_OK);
        assert_eq!(hood_sim_body_vertex_count(sim, &mut nb), HOOD_OK);
        assert_eq!(hood_sim_set_executor(sim, &exec), HOOD_OK);
        // Any finite body: the executor fails the step before the body matters.
        let body = vec![0.0f32; 3 * nb];
        let mut out = vec![0.0f32; 3 * n];
        let s = hood_sim_step(sim, body.as_ptr(), nb, out.as_mut_ptr(), n);
        (s, last_error())
    }
}

fn with_model<R>(f: impl FnOnce(*mut hood_model) -> R) -> R {
    let bytes = ModelBytes::new(&random_model_bytes(8, 21));
    let mut model = null_mut();
    // SAFETY: aligned bytes that outlive the model (freed below).
    unsafe { assert_eq!(hood_model_load(bytes.as_bytes().as_ptr(), bytes.as_bytes().len(), &mut model), HOOD_OK) };
    let r = f(model);
    // SAFETY: a live model whose sims are freed.
    assert_eq!(unsafe { hood_model_free(model) }, HOOD_OK);
    r
}

#[test]
fn warnings_and_caught_panics_reach_the_callback() {
    with_model(|model| {
        // SAFETY: `collect` keeps the callback contract; `TOKEN` is static.
        assert_eq!(unsafe { hood_set_log_callback(Some(collect), &TOKEN as *const u8 as *mut c_void) }, HOOD_OK);
        let coarse = sim(model, 12, 16);
        let got = messages();
        assert_eq!(got.len(), 1, "{got:?}");
        assert_eq!(got[0].0, HOOD_LOG_WARNING);
        assert!(got[0].1.contains("too coarse") && got[0].1.contains("median edge"), "{got:?}");
        let fine = sim(model, 40, 64);
        assert_eq!(messages(), vec![], "a fine body is no warning");
        // More threads than the machine has cores: capped at the cores, with a warning.
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let many = sim_on(model, 40, 64, cores as u32 + 1);
        let got = messages();
        assert_eq!(got.len(), 1, "{got:?}");
        assert_eq!(got[0].0, HOOD_LOG_WARNING);
        assert!(got[0].1.contains(&format!("capped at the machine's {cores}")), "{got:?}");
        let all = sim_on(model, 40, 64, cores as u32);
        assert_eq!(messages(), vec![], "as many threads as cores is no warning");
        let (status, error) = failing_step(coarse);
        assert_eq!(status, HOOD_ERR_PANIC);
        let got = messages();
        assert_eq!(got, vec![(HOOD_LOG_ERROR, error.clone())], "the callback gets hood_last_error's text");
        assert!(error.contains("panic at ") && error.contains("exactly once"), "{error}");
        // Removed: nothing more arrives.
        // SAFETY: NULL removes the callback.
        assert_eq!(unsafe { hood_set_log_callback(None, null_mut()) }, HOOD_OK);
        let again = sim(model, 12, 16);
        assert_eq!(failing_step(again).0, HOOD_ERR_PANIC);
        assert_eq!(messages(), vec![]);
        // SAFETY: live sims.
        unsafe {
            for s in [coarse, fine, many, all, again] {
                assert_eq!(hood_sim_free(s), HOOD_OK);
            }
        }
    });
}

/// In a child process: a caught panic with (`HOOD_LOG_CHILD=callback`) or without a callback.
#[test]
fn a_caught_panic_prints_to_stderr_only_without_a_callback() {
    if let Ok(mode) = std::env::var("HOOD_LOG_CHILD") {
        with_model(|model| {
            if mode == "callback" {
                // SAFETY: as above.
                unsafe { hood_set_log_callback(Some(collect), &TOKEN as *const u8 as *mut c_void) };
            }
            let s = sim(model, 40, 64);
            assert_eq!(failing_step(s).0, HOOD_ERR_PANIC);
            // SAFETY: a live sim.
            assert_eq!(unsafe { hood_sim_free(s) }, HOOD_OK);
        });
        return;
    }
    let exe = std::env::current_exe().unwrap();
    for (mode, printed) in [("callback", false), ("none", true)] {
        let o = Command::new(&exe)
            .args(["--exact", "a_caught_panic_prints_to_stderr_only_without_a_callback", "--nocapture"])
            .env("HOOD_LOG_CHILD", mode)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{mode}: {stderr}");
        assert_eq!(stderr.contains("exactly once"), printed, "{mode}: stderr is\n{stderr}");
    }
}

/// The garment `free_the_garment` frees, and what the free returned.
static REENTRANT_GARMENT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
static REENTRANT_STATUS: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(u32::MAX);

/// A log callback that calls back into the library: it frees the garment of the call that logs.
unsafe extern "C-unwind" fn free_the_garment(_: u32, _: *const c_char, _: *mut c_void) {
    let g = REENTRANT_GARMENT.load(std::sync::atomic::Ordering::SeqCst) as *mut hood_garment;
    // SAFETY: a garment handle (checked by the library).
    let s = unsafe { hood_garment_free(g) };
    REENTRANT_STATUS.store(s, std::sync::atomic::Ordering::SeqCst);
}

/// `hood_sim_new` logs (more threads than cores) while it reads the garment; a log callback that
/// frees that garment is refused with `HOOD_ERR_BUSY` instead of freeing what the call then reads.
/// In a child process: the callback is process-wide.
#[test]
fn a_callback_cannot_free_the_garment_a_call_reads() {
    if std::env::var("HOOD_LOG_CHILD").as_deref() != Ok("reentrant") {
        let o = Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "a_callback_cannot_free_the_garment_a_call_reads", "--nocapture"])
            .env("HOOD_LOG_CHILD", "reentrant")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        return;
    }
    with_model(|model| {
        let (rest, faces) = hood::mesh::shapes::grid(6, 6, 0.6, 0.6, 0.32);
        let (mut g, mut s) = (null_mut(), null_mut());
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let cfg = hood_sim_config { threads: cores as u32 + 1, ..network_config() };
        // SAFETY: arrays of the stated lengths; live handles; the callback keeps the contract.
        unsafe {
            let (r, f) = (rest.as_ptr().cast(), faces.as_ptr().cast());
            assert_eq!(hood_garment_new(r, rest.len(), f, faces.len(), null(), 0, null(), &mut g), HOOD_OK);
            REENTRANT_GARMENT.store(g as usize, std::sync::atomic::Ordering::SeqCst);
            assert_eq!(hood_set_log_callback(Some(free_the_garment), null_mut()), HOOD_OK);
            assert_eq!(hood_sim_new(model, g, null(), &cfg, &mut s), HOOD_OK, "{}", last_error());
            assert_eq!(hood_set_log_callback(None, null_mut()), HOOD_OK);
            assert_eq!(REENTRANT_STATUS.load(std::sync::atomic::Ordering::SeqCst), HOOD_ERR_BUSY);
            // Still live, and freed once the call is over.
            let mut n = 0;
            assert_eq!(hood_garment_vertex_count(g, &mut n), HOOD_OK);
            assert_eq!(n, rest.len());
            assert_eq!(hood_garment_free(g), HOOD_OK);
            assert_eq!(hood_sim_free(s), HOOD_OK);
        }
    });
}
