//! The C ABI called as C would call it (through the exported functions): every error path gives
//! its status code and leaves state and out-parameters alone; reset, teleport, executors.

mod common;

use common::{default_config, network_config, random_model_bytes};
use hood::model::ModelBytes;
use hood_ffi::*;
use std::ffi::CStr;
use std::ptr::{null, null_mut};

fn last_error() -> String {
    // SAFETY: `hood_last_error` returns a NUL-terminated string valid until the next call.
    unsafe { CStr::from_ptr(hood_last_error()) }.to_string_lossy().into_owned()
}

/// Loaded model with its aligned bytes (which must outlive it).
struct Loaded {
    _bytes: ModelBytes,
    model: *mut hood_model,
}

fn load(h: usize, seed: u64) -> Loaded {
    let bytes = ModelBytes::new(&random_model_bytes(h, seed));
    let mut model = null_mut();
    // SAFETY: aligned bytes that outlive the model (freed in `Drop` order by the tests).
    let s = unsafe { hood_model_load(bytes.as_bytes().as_ptr(), bytes.as_bytes().len(), &mut model) };
    assert_eq!(s, HOOD_OK, "{}", last_error());
    Loaded { _bytes: bytes, model }
}

impl Drop for Loaded {
    fn drop(&mut self) {
        // SAFETY: a model handle (or already freed: then a status, no crash).
        unsafe { hood_model_free(self.model) };
    }
}

/// The examples' scene: an `n x n` cloth pinned at two corners above an ellipsoid.
struct Scene {
    rest: Vec<[f32; 3]>,
    faces: Vec<[u32; 3]>,
    pinned: Vec<u8>,
    body: Vec<[f32; 3]>,
    body_faces: Vec<[u32; 3]>,
}

fn scene(n: usize) -> Scene {
    let (rest, faces) = hood::mesh::shapes::grid(n, n, 0.6, 0.6, 0.32);
    let mut pinned = vec![0u8; rest.len()];
    pinned[0] = 1;
    pinned[n - 1] = 1;
    let (body, body_faces) = hood::body::shapes::ellipsoid(12, 16, [0.25, 0.3, 0.25], [0.0; 3]);
    Scene { rest, faces, pinned, body, body_faces }
}

impl Scene {
    fn garment(&self) -> *mut hood_garment {
        let mut g = null_mut();
        // SAFETY: arrays of the stated lengths.
        let s = unsafe {
            hood_garment_new(
                self.rest.as_ptr().cast(),
                self.rest.len(),
                self.faces.as_ptr().cast(),
                self.faces.len(),
                null(),
                0,
                self.pinned.as_ptr(),
                &mut g,
            )
        };
        assert_eq!(s, HOOD_OK, "{}", last_error());
        g
    }

    fn body_desc(&self) -> hood_body_desc {
        common::body_desc(&self.body, &self.body_faces)
    }

    fn sim(&self, model: *const hood_model) -> *mut hood_sim {
        let g = self.garment();
        let bd = self.body_desc();
        let mut sim = null_mut();
        let cfg = network_config();
        // SAFETY: live handles, valid descriptors.
        let s = unsafe { hood_sim_new(model, g, &bd, &cfg, &mut sim) };
        assert_eq!(s, HOOD_OK, "{}", last_error());
        // SAFETY: the sim keeps its own garment copy.
        assert_eq!(unsafe { hood_garment_free(g) }, HOOD_OK);
        sim
    }

    fn body_at(&self, t: usize, offset: [f32; 3]) -> Vec<[f32; 3]> {
        let dx = 0.01 * (t as f32 * 0.3).sin();
        self.body.iter().map(|p| [p[0] + dx + offset[0], p[1] + offset[1], p[2] + offset[2]]).collect()
    }
}

fn step(sim: *mut hood_sim, body: &[[f32; 3]], out: &mut [[f32; 3]]) -> hood_status {
    // SAFETY: arrays of the stated lengths.
    unsafe { hood_sim_step(sim, body.as_ptr().cast(), body.len(), out.as_mut_ptr().cast(), out.len()) }
}

fn positions(sim: *const hood_sim, n: usize) -> Vec<[f32; 3]> {
    let mut p = vec![[0.0f32; 3]; n];
    // SAFETY: `p` holds n points.
    assert_eq!(unsafe { hood_sim_positions(sim, p.as_mut_ptr().cast(), n) }, HOOD_OK, "{}", last_error());
    p
}

fn velocities(sim: *const hood_sim, n: usize) -> Vec<[f32; 3]> {
    let mut p = vec![[0.0f32; 3]; n];
    // SAFETY: `p` holds n points.
    assert_eq!(unsafe { hood_sim_velocities(sim, p.as_mut_ptr().cast(), n) }, HOOD_OK, "{}", last_error());
    p
}

/// `sizeof(T)` as a `struct_size`.
fn size_of_u32<T>() -> u32 {
    size_of::<T>() as u32
}

/// An executor struct of the current size.
fn executor(user: *mut std::ffi::c_void, parallelism: u32, run: Option<RunFn>) -> hood_executor {
    hood_executor { struct_size: size_of_u32::<hood_executor>(), user, parallelism, run }
}

type RunFn = unsafe extern "C-unwind" fn(*mut std::ffi::c_void, u32, hood_task_fn, *mut std::ffi::c_void);

fn material(density: f32, mu: f32, lambda: f32, bending: f32) -> hood_material {
    hood_material { struct_size: size_of_u32::<hood_material>(), density, mu, lambda, bending }
}

fn max_diff(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter().zip(b).flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs())).fold(0.0, f32::max)
}

#[test]
fn version_matches_cargo_toml() {
    let v = hood_version();
    let want: Vec<u32> = env!("CARGO_PKG_VERSION").split('.').map(|s| s.parse().unwrap()).collect();
    assert_eq!(v, (want[0] << 16) | (want[1] << 8) | want[2]);
    // SAFETY: a static NUL-terminated string.
    let s = unsafe { CStr::from_ptr(hood_version_string()) };
    assert_eq!(s.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
}

#[test]
fn status_codes_mirror_error_codes() {
    use hood::Error;
    let cases = [
        (Error::IndexOutOfRange { what: "", at: 0, index: 0, len: 0 }, HOOD_ERR_INDEX_OUT_OF_RANGE),
        (Error::NonFinite { what: "", index: 0 }, HOOD_ERR_NON_FINITE),
        (Error::DegenerateFace { face: 0 }, HOOD_ERR_DEGENERATE_FACE),
        (Error::RepeatedVertex { face: 0, vertex: 0 }, HOOD_ERR_REPEATED_VERTEX),
        (Error::UnusedVertex { vertex: 0 }, HOOD_ERR_UNUSED_VERTEX),
        (Error::Empty { what: "" }, HOOD_ERR_EMPTY),
        (Error::SizeMismatch { what: "", expected: 0, got: 0 }, HOOD_ERR_SIZE_MISMATCH),
        (Error::OutOfRange { what: "", index: 0 }, HOOD_ERR_OUT_OF_RANGE),
        (Error::CapacityExceeded { what: "", capacity: 0, needed: 0 }, HOOD_ERR_CAPACITY_EXCEEDED),
        (Error::IncompatibleModel { reason: "" }, HOOD_ERR_INCOMPATIBLE_MODEL),
        (Error::UnsupportedEffect { effect: "" }, HOOD_ERR_UNSUPPORTED_EFFECT),
        (Error::CorruptData { reason: "" }, HOOD_ERR_CORRUPT_DATA),
        (Error::parse("", 0, ""), HOOD_ERR_PARSE),
        (Error::Io { path: String::new(), message: String::new() }, HOOD_ERR_IO),
        (Error::InsideOut { what: "" }, HOOD_ERR_INSIDE_OUT),
    ];
    let mut seen = std::collections::BTreeSet::new();
    for (e, code) in cases {
        assert_eq!(e.code(), code, "{e:?}");
        assert!(seen.insert(code));
    }
    for c in [
        HOOD_OK,
        HOOD_ERR_NULL_POINTER,
        HOOD_ERR_INVALID_HANDLE,
        HOOD_ERR_MODEL_IN_USE,
        HOOD_ERR_PANIC,
        HOOD_ERR_BAD_POINTER,
        HOOD_ERR_BUSY,
        HOOD_ERR_STRUCT_SIZE,
        HOOD_ERR_TOO_LATE,
    ] {
        assert!(seen.insert(c), "code {c} reused");
    }
}

#[test]
fn null_arguments_give_status() {
    let l = load(8, 1);
    let sc = scene(6);
    let mut m = null_mut();
    let mut out = 0usize;
    // SAFETY: every call below is given NULL where a pointer is required; none may dereference it.
    unsafe {
        assert_eq!(hood_model_load(null(), 10, &mut m), HOOD_ERR_NULL_POINTER);
        assert!(last_error().contains("bytes"), "{}", last_error());
        assert!(m.is_null());
        assert_eq!(
            hood_model_load(l._bytes.as_bytes().as_ptr(), l._bytes.as_bytes().len(), null_mut()),
            HOOD_ERR_NULL_POINTER
        );
        let mut g = null_mut();
        assert_eq!(
            hood_garment_new(null(), 3, sc.faces.as_ptr().cast(), 1, null(), 0, null(), &mut g),
            HOOD_ERR_NULL_POINTER
        );
        assert_eq!(
            hood_garment_new(sc.rest.as_ptr().cast(), sc.rest.len(), null(), 1, null(), 0, null(), &mut g),
            HOOD_ERR_NULL_POINTER
        );
        // materials NULL with a nonzero count
        assert_eq!(
            hood_garment_new(
                sc.rest.as_ptr().cast(),
                sc.rest.len(),
                sc.faces.as_ptr().cast(),
                sc.faces.len(),
                null(),
                1,
                null(),
                &mut g
            ),
            HOOD_ERR_NULL_POINTER
        );
        assert!(g.is_null());
        let g = sc.garment();
        let mut sim = null_mut();
        assert_eq!(hood_sim_new(null(), g, null(), null(), &mut sim), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_new(l.model, null(), null(), null(), &mut sim), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_new(l.model, g, null(), null(), null_mut()), HOOD_ERR_NULL_POINTER);
        let mut bd = sc.body_desc();
        bd.positions = null();
        assert_eq!(hood_sim_new(l.model, g, &bd, null(), &mut sim), HOOD_ERR_NULL_POINTER);
        assert!(sim.is_null());
        assert_eq!(hood_garment_vertex_count(g, null_mut()), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_garment_vertex_count(null(), &mut out), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_model_has_bf16(null(), null_mut()), HOOD_ERR_NULL_POINTER);
        let sim = sc.sim(l.model);
        let n = sc.rest.len();
        let mut buf = vec![[0.0f32; 3]; n];
        let body = sc.body_at(1, [0.0; 3]);
        assert_eq!(
            hood_sim_step(null_mut(), body.as_ptr().cast(), body.len(), buf.as_mut_ptr().cast(), n),
            HOOD_ERR_NULL_POINTER
        );
        assert_eq!(hood_sim_step(sim, null(), body.len(), buf.as_mut_ptr().cast(), n), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_step(sim, body.as_ptr().cast(), body.len(), null_mut(), n), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_positions(sim, null_mut(), n), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_set_pin_targets(sim, null(), n), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_reset(sim, null(), n, null(), 0), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_vertex_count(sim, null_mut()), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_sim_teleport(null_mut(), null(), null(), null(), 0), HOOD_ERR_NULL_POINTER);
        let e = executor(null_mut(), 2, None);
        assert_eq!(hood_sim_set_executor(sim, &e), HOOD_ERR_NULL_POINTER);
        hood_sim_config_default(null_mut());
        // Free functions accept NULL.
        assert_eq!(hood_sim_free(null_mut()), HOOD_OK);
        assert_eq!(hood_garment_free(null_mut()), HOOD_OK);
        assert_eq!(hood_model_free(null_mut()), HOOD_OK);
        // The sim still works after all that.
        assert_eq!(step(sim, &body, &mut buf), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        assert_eq!(hood_garment_free(g), HOOD_OK);
    }
}

#[test]
fn bad_pointers_and_thread_counts_give_status_and_change_nothing() {
    let l = load(8, 3);
    let sc = scene(6);
    let sim = sc.sim(l.model);
    let n = sc.rest.len();
    let nb = sc.body.len();
    let body = sc.body_at(1, [0.0; 3]);
    let before = positions(sim, n);
    // One buffer of floats holding the body, then room for the garment: overlapping views.
    let mut floats: Vec<f32> = body.iter().flatten().copied().collect();
    floats.extend(std::iter::repeat_n(7.0f32, 3 * n));
    let kept = floats.clone();
    // A misaligned copy of the body: one byte into a u32 buffer.
    let mut bytes = vec![0u32; 3 * nb + 1];
    let raw = bytes.as_mut_ptr().cast::<u8>();
    // SAFETY: `bytes` holds 4 (3 nb + 1) bytes; the copy fills 12 nb of them from offset 1.
    let misaligned = unsafe {
        std::ptr::copy_nonoverlapping(body.as_ptr().cast::<u8>(), raw.add(1), 12 * nb);
        raw.add(1).cast::<f32>()
    };
    // One spare vertex, so that the misaligned view of n vertices stays inside the buffer.
    let mut out = vec![[9.0f32; 3]; n + 1];
    let out_misaligned = out.as_mut_ptr().cast::<u8>().wrapping_add(2).cast::<f32>();
    // SAFETY: every pointer below spans the stated counts (read or written only on success).
    unsafe {
        let base = floats.as_mut_ptr();
        // garment_out starts inside the body's array.
        assert_eq!(hood_sim_step(sim, base, nb, base.add(3), n), HOOD_ERR_BAD_POINTER);
        assert!(last_error().contains("overlaps"), "{}", last_error());
        // body_next starts inside garment_out's array.
        assert_eq!(hood_sim_step(sim, base.add(3), nb, base, n), HOOD_ERR_BAD_POINTER);
        assert_eq!(hood_sim_step(sim, misaligned, nb, out.as_mut_ptr().cast(), n), HOOD_ERR_BAD_POINTER);
        assert!(last_error().contains("aligned"), "{}", last_error());
        assert_eq!(hood_sim_step(sim, body.as_ptr().cast(), nb, out_misaligned, n), HOOD_ERR_BAD_POINTER);
        assert_eq!(floats, kept);
        assert!(out.iter().all(|p| *p == [9.0; 3]));
        assert_eq!(positions(sim, n), before);
        // Adjacent, not overlapping: fine.
        assert_eq!(hood_sim_step(sim, base, nb, base.add(3 * nb), n), HOOD_OK, "{}", last_error());
        assert_ne!(positions(sim, n), before);
        assert_eq!(hood_sim_free(sim), HOOD_OK);

        // An absurd thread count is refused, and the model is not left "in use".
        let g = sc.garment();
        let bd = sc.body_desc();
        let mut cfg = default_config();
        cfg.threads = u32::MAX;
        let mut s = null_mut();
        assert_eq!(hood_sim_new(l.model, g, &bd, &cfg, &mut s), HOOD_ERR_OUT_OF_RANGE);
        assert!(last_error().contains("threads"), "{}", last_error());
        assert!(s.is_null());
        assert_eq!(hood_garment_free(g), HOOD_OK);
        assert_eq!(hood_model_free(l.model), HOOD_OK, "{}", last_error());
    }
}

#[test]
fn wrong_sizes_give_size_mismatch_and_change_nothing() {
    let l = load(8, 2);
    let sc = scene(6);
    let sim = sc.sim(l.model);
    let n = sc.rest.len();
    let (mut nv, mut nb) = (0, 0);
    // SAFETY: live sim, valid out-parameters.
    unsafe {
        assert_eq!(hood_sim_vertex_count(sim, &mut nv), HOOD_OK);
        assert_eq!(hood_sim_body_vertex_count(sim, &mut nb), HOOD_OK);
    }
    assert_eq!((nv, nb), (n, sc.body.len()));
    let before = positions(sim, n);
    let body = sc.body_at(1, [0.0; 3]);
    let mut out = vec![[7.0f32; 3]; n];
    // SAFETY: the counts passed are smaller than the arrays (the library must refuse them).
    unsafe {
        let s = hood_sim_step(sim, body.as_ptr().cast(), body.len() - 1, out.as_mut_ptr().cast(), n);
        assert_eq!(s, HOOD_ERR_SIZE_MISMATCH);
        assert!(last_error().contains("body vertices"), "{}", last_error());
        let s = hood_sim_step(sim, body.as_ptr().cast(), body.len(), out.as_mut_ptr().cast(), n - 1);
        assert_eq!(s, HOOD_ERR_SIZE_MISMATCH);
        assert_eq!(hood_sim_positions(sim, out.as_mut_ptr().cast(), n - 1), HOOD_ERR_SIZE_MISMATCH);
        assert_eq!(hood_sim_set_pin_targets(sim, sc.rest.as_ptr().cast(), n - 1), HOOD_ERR_SIZE_MISMATCH);
        assert_eq!(hood_sim_reset(sim, sc.rest.as_ptr().cast(), n - 1, null(), 0), HOOD_ERR_SIZE_MISMATCH);
        assert_eq!(hood_sim_reset(sim, sc.rest.as_ptr().cast(), n, sc.body.as_ptr().cast(), 3), HOOD_ERR_SIZE_MISMATCH);
        // Garment: pinned flags read n_vertices entries; indices past the end; bad materials.
        let mut g = null_mut();
        let bad_faces = [[0u32, 1, 99]];
        let s = hood_garment_new(sc.rest.as_ptr().cast(), 3, bad_faces.as_ptr().cast(), 1, null(), 0, null(), &mut g);
        assert_eq!(s, HOOD_ERR_INDEX_OUT_OF_RANGE);
        let mats = [material(0.2, 2e4, 4e4, 1e-5); 2];
        let s = hood_garment_new(
            sc.rest.as_ptr().cast(),
            n,
            sc.faces.as_ptr().cast(),
            sc.faces.len(),
            mats.as_ptr(),
            2,
            null(),
            &mut g,
        );
        assert_eq!(s, HOOD_ERR_SIZE_MISMATCH, "{}", last_error());
        assert!(g.is_null());
    }
    assert!(out.iter().all(|p| *p == [7.0; 3]), "out written on error");
    assert_eq!(positions(sim, n), before);
    // SAFETY: live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
}

#[test]
fn absurd_counts_are_refused_before_any_array_is_read() {
    let l = load(8, 2);
    let sc = scene(6);
    // Tiny arrays with counts of 10^8: the library must refuse the counts, not read (or allocate
    // for) 10^8 elements of each.
    let (rest, faces, flags) = ([[0.0f32; 3]; 3], [[0u32, 1, 2]], [0u8; 3]);
    let huge = 100_000_000;
    // SAFETY: the counts are larger than the arrays: the library must refuse them unread.
    unsafe {
        let mut g = null_mut();
        let (r, f) = (rest.as_ptr().cast(), faces.as_ptr().cast());
        assert_eq!(hood_garment_new(r, huge, f, 1, null(), 0, flags.as_ptr(), &mut g), HOOD_ERR_CAPACITY_EXCEEDED);
        assert!(last_error().contains("garment vertices") && last_error().contains("16777216"), "{}", last_error());
        assert_eq!(hood_garment_new(r, 3, f, 10 * huge, null(), 0, null(), &mut g), HOOD_ERR_CAPACITY_EXCEEDED);
        assert!(last_error().contains("garment faces"), "{}", last_error());
        assert!(g.is_null());
        // The same limits for a body, through both functions that read one.
        let garment = sc.garment();
        let mut bd = common::body_desc(&rest, &faces);
        bd.n_vertices = huge;
        bd.omitted = flags.as_ptr();
        let mut s = null_mut();
        assert_eq!(hood_sim_new(l.model, garment, &bd, &network_config(), &mut s), HOOD_ERR_CAPACITY_EXCEEDED);
        assert!(last_error().contains("body vertices"), "{}", last_error());
        assert!(s.is_null());
        let mut pos = sc.rest.clone();
        let s = hood_garment_push_out(&bd, pos.as_mut_ptr().cast(), pos.len(), null(), null_mut());
        assert_eq!(s, HOOD_ERR_CAPACITY_EXCEEDED, "{}", last_error());
        bd.n_vertices = 3;
        bd.n_faces = 10 * huge;
        let mut s = null_mut();
        assert_eq!(hood_sim_new(l.model, garment, &bd, &network_config(), &mut s), HOOD_ERR_CAPACITY_EXCEEDED);
        assert!(last_error().contains("body faces"), "{}", last_error());
        assert_eq!(hood_garment_free(garment), HOOD_OK);
    }
}

#[test]
fn nan_body_input_is_refused_and_state_unchanged() {
    let l = load(8, 3);
    let sc = scene(6);
    let sim = sc.sim(l.model);
    let n = sc.rest.len();
    let mut out = vec![[0.0f32; 3]; n];
    for t in 1..=3 {
        assert_eq!(step(sim, &sc.body_at(t, [0.0; 3]), &mut out), HOOD_OK, "{}", last_error());
    }
    let (p0, v0) = (positions(sim, n), velocities(sim, n));
    assert!(v0.iter().any(|v| *v != [0.0; 3]), "the garment should move");
    let mut bad = sc.body_at(4, [0.0; 3]);
    bad[5][1] = f32::NAN;
    let mut sentinel = vec![[9.0f32; 3]; n];
    assert_eq!(step(sim, &bad, &mut sentinel), HOOD_ERR_NON_FINITE);
    assert!(last_error().contains("body vertex 5"), "{}", last_error());
    assert!(sentinel.iter().all(|p| *p == [9.0; 3]));
    assert_eq!(positions(sim, n), p0);
    assert_eq!(velocities(sim, n), v0);
    // Stepping on with good input matches a sim that never saw the NaN frame.
    let twin = sc.sim(l.model);
    let mut o2 = vec![[0.0f32; 3]; n];
    for t in 1..=4 {
        assert_eq!(step(twin, &sc.body_at(t, [0.0; 3]), &mut o2), HOOD_OK);
    }
    assert_eq!(step(sim, &sc.body_at(4, [0.0; 3]), &mut out), HOOD_OK);
    assert_eq!(out, o2);
    // A NaN pin target is refused too.
    let mut targets = sc.rest.clone();
    targets[0][0] = f32::INFINITY;
    // SAFETY: n targets.
    assert_eq!(unsafe { hood_sim_set_pin_targets(sim, targets.as_ptr().cast(), n) }, HOOD_ERR_NON_FINITE);
    // SAFETY: live sims.
    unsafe {
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        assert_eq!(hood_sim_free(twin), HOOD_OK);
    }
}

#[test]
fn misaligned_and_corrupt_models_are_refused() {
    let bytes = ModelBytes::new(&random_model_bytes(8, 4));
    let b = bytes.as_bytes();
    // An aligned buffer with the model copied one byte in.
    let mut shifted = ModelBytes::new(&[&[0u8][..], b].concat());
    // A sentinel that must stay.
    let mut out: *mut hood_model = std::ptr::dangling_mut::<hood_model>();
    // SAFETY: readable ranges; `out` is writable.
    unsafe {
        let s = hood_model_load(shifted.as_bytes().as_ptr().add(1), b.len(), &mut out);
        assert_eq!(s, HOOD_ERR_CORRUPT_DATA);
        assert!(last_error().contains("align"), "{}", last_error());
        assert_eq!(out, std::ptr::dangling_mut::<hood_model>());
        // Truncated.
        assert_eq!(hood_model_load(b.as_ptr(), b.len() / 2, &mut out), HOOD_ERR_CORRUPT_DATA);
        // Bad magic.
        let mut v = b.to_vec();
        v[0] ^= 0xff;
        shifted = ModelBytes::new(&v);
        assert_eq!(hood_model_load(shifted.as_bytes().as_ptr(), v.len(), &mut out), HOOD_ERR_CORRUPT_DATA);
        // Flipped bytes in the middle of the archive.
        let mut v = b.to_vec();
        let mid = v.len() / 2;
        for x in &mut v[mid..mid + 64] {
            *x ^= 0x5a;
        }
        shifted = ModelBytes::new(&v);
        let s = hood_model_load(shifted.as_bytes().as_ptr(), v.len(), &mut out);
        // Flipped weight bytes may still validate (floats are floats); structure bytes must not.
        assert!(s == HOOD_ERR_CORRUPT_DATA || s == HOOD_OK, "status {s}");
        if s == HOOD_OK {
            assert_eq!(hood_model_free(out), HOOD_OK);
            out = std::ptr::dangling_mut::<hood_model>();
        }
        assert_eq!(hood_model_load(b.as_ptr(), 0, &mut out), HOOD_ERR_CORRUPT_DATA);
        assert_eq!(out, std::ptr::dangling_mut::<hood_model>());
        // The intact bytes load, and the f32-only model refuses bf16.
        assert_eq!(hood_model_load(b.as_ptr(), b.len(), &mut out), HOOD_OK);
        let mut bf = 9;
        assert_eq!(hood_model_has_bf16(out, &mut bf), HOOD_OK);
        assert_eq!(bf, 0);
        let sc = scene(5);
        let g = sc.garment();
        let mut cfg = default_config();
        cfg.solver_iterations = 0; // bf16 is the network's arithmetic
        cfg.precision = HOOD_PRECISION_BF16;
        let mut sim = null_mut();
        assert_eq!(hood_sim_new(out, g, null(), &cfg, &mut sim), HOOD_ERR_UNSUPPORTED_EFFECT);
        cfg.precision = 7;
        assert_eq!(hood_sim_new(out, g, null(), &cfg, &mut sim), HOOD_ERR_OUT_OF_RANGE);
        cfg.precision = HOOD_PRECISION_F32;
        assert_ne!(cfg.effects & HOOD_EFFECT_SPEED_LIMIT, 0, "the speed limit is on by default");
        assert_eq!(cfg.speed_limit, hood::sim::DEFAULT_SPEED_LIMIT);
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            cfg.speed_limit = bad;
            assert_eq!(hood_sim_new(out, g, null(), &cfg, &mut sim), HOOD_ERR_OUT_OF_RANGE, "{bad}");
        }
        cfg.speed_limit = hood::sim::DEFAULT_SPEED_LIMIT;
        assert_eq!(cfg.effects & HOOD_EFFECT_COLLISION_PROJECTION, 0, "projection is off by default");
        assert_eq!(cfg.projection_margin, hood::sim::DEFAULT_PROJECTION_MARGIN);
        cfg.effects |= HOOD_EFFECT_COLLISION_PROJECTION;
        assert_eq!(
            hood_sim_new(out, g, null(), &cfg, &mut sim),
            HOOD_ERR_UNSUPPORTED_EFFECT,
            "projection without a body"
        );
        cfg.effects &= !HOOD_EFFECT_COLLISION_PROJECTION;
        cfg.effects |= 1 << 20;
        assert_eq!(hood_sim_new(out, g, null(), &cfg, &mut sim), HOOD_ERR_OUT_OF_RANGE);
        assert!(sim.is_null());
        assert_eq!(hood_garment_free(g), HOOD_OK);
        assert_eq!(hood_model_free(out), HOOD_OK);
    }
}

#[test]
fn double_free_use_after_free_and_mismatched_handles() {
    let l = load(8, 5);
    let sc = scene(5);
    let g = sc.garment();
    let sim = sc.sim(l.model);
    let n = sc.rest.len();
    let mut count = 0;
    // SAFETY: freed and mismatched handles are exactly what the registry must catch without
    // dereferencing them.
    unsafe {
        // A garment handle where a sim is expected, and the other way round.
        assert_eq!(hood_sim_vertex_count(g as *const hood_sim, &mut count), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(hood_garment_vertex_count(sim as *const hood_garment, &mut count), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(hood_model_free(sim as *mut hood_model), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(hood_sim_free(l.model as *mut hood_sim), HOOD_ERR_INVALID_HANDLE);
        let mut bogus = [0u64; 8];
        assert_eq!(hood_sim_free(bogus.as_mut_ptr() as *mut hood_sim), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(count, 0);
        assert_eq!(hood_garment_free(g), HOOD_OK);
        assert_eq!(hood_garment_free(g), HOOD_ERR_INVALID_HANDLE);
        assert!(last_error().contains("garment"), "{}", last_error());
        assert_eq!(hood_garment_vertex_count(g, &mut count), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        assert_eq!(hood_sim_free(sim), HOOD_ERR_INVALID_HANDLE);
        let mut out = vec![[0.0f32; 3]; n];
        let body = sc.body_at(1, [0.0; 3]);
        assert_eq!(step(sim, &body, &mut out), HOOD_ERR_INVALID_HANDLE);
    }
}

#[test]
fn model_freed_while_a_sim_lives_is_refused() {
    let bytes = ModelBytes::new(&random_model_bytes(8, 6));
    let mut model = null_mut();
    let sc = scene(5);
    // SAFETY: aligned bytes outliving the model; live handles.
    unsafe {
        assert_eq!(hood_model_load(bytes.as_bytes().as_ptr(), bytes.as_bytes().len(), &mut model), HOOD_OK);
        let a = sc.sim(model);
        let b = sc.sim(model);
        assert_eq!(hood_model_free(model), HOOD_ERR_MODEL_IN_USE);
        assert!(last_error().contains("2 sim"), "{}", last_error());
        assert_eq!(hood_sim_free(a), HOOD_OK);
        assert_eq!(hood_model_free(model), HOOD_ERR_MODEL_IN_USE);
        // The refused free left the model usable.
        let mut out = vec![[0.0f32; 3]; sc.rest.len()];
        assert_eq!(step(b, &sc.body_at(1, [0.0; 3]), &mut out), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_free(b), HOOD_OK);
        // A failed sim creation does not leave a count behind.
        let g = sc.garment();
        let mut cfg = default_config();
        cfg.solver_iterations = 0; // bf16 is the network's arithmetic
        cfg.precision = HOOD_PRECISION_BF16;
        let mut sim = null_mut();
        assert_eq!(hood_sim_new(model, g, null(), &cfg, &mut sim), HOOD_ERR_UNSUPPORTED_EFFECT);
        assert_eq!(hood_garment_free(g), HOOD_OK);
        assert_eq!(hood_model_free(model), HOOD_OK);
        assert_eq!(hood_model_free(model), HOOD_ERR_INVALID_HANDLE);
    }
}

#[test]
fn last_error_is_per_thread() {
    // SAFETY: NULL arguments only.
    assert_eq!(unsafe { hood_sim_free(std::ptr::dangling_mut::<hood_sim>()) }, HOOD_ERR_INVALID_HANDLE);
    assert!(!last_error().is_empty());
    let other = std::thread::spawn(last_error).join().unwrap();
    assert_eq!(other, "");
}

#[test]
fn reset_replays_a_fresh_sim() {
    let l = load(8, 7);
    let sc = scene(6);
    let n = sc.rest.len();
    let (a, b) = (sc.sim(l.model), sc.sim(l.model));
    let mut out_a = vec![[0.0f32; 3]; n];
    let mut out_b = vec![[0.0f32; 3]; n];
    for t in 1..=5 {
        assert_eq!(step(a, &sc.body_at(t + 10, [0.0; 3]), &mut out_a), HOOD_OK);
    }
    // SAFETY: arrays of the stated lengths.
    let s = unsafe { hood_sim_reset(a, sc.rest.as_ptr().cast(), n, sc.body.as_ptr().cast(), sc.body.len()) };
    assert_eq!(s, HOOD_OK, "{}", last_error());
    assert!(velocities(a, n).iter().all(|v| *v == [0.0; 3]));
    assert_eq!(positions(a, n), sc.rest);
    for t in 1..=3 {
        assert_eq!(step(a, &sc.body_at(t, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(step(b, &sc.body_at(t, [0.0; 3]), &mut out_b), HOOD_OK);
    }
    assert_eq!(out_a, out_b);
    // SAFETY: live sims.
    unsafe {
        assert_eq!(hood_sim_free(a), HOOD_OK);
        assert_eq!(hood_sim_free(b), HOOD_OK);
    }
}

#[test]
fn teleport_moves_state_rigidly_and_translation_commutes_with_steps() {
    let l = load(8, 8);
    let sc = scene(6);
    let n = sc.rest.len();
    let (a, b) = (sc.sim(l.model), sc.sim(l.model));
    let mut out_a = vec![[0.0f32; 3]; n];
    let mut out_b = vec![[0.0f32; 3]; n];
    for t in 1..=4 {
        assert_eq!(step(a, &sc.body_at(t, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(step(b, &sc.body_at(t, [0.0; 3]), &mut out_b), HOOD_OK);
    }
    let (p0, v0) = (positions(b, n), velocities(b, n));
    // A quarter turn about y, then a shift.
    let r = [0.0f32, 0.0, 1.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0];
    let t = [1.5f32, -0.25, 2.0];
    // SAFETY: 9 and 3 floats.
    assert_eq!(unsafe { hood_sim_teleport(b, r.as_ptr(), t.as_ptr(), null(), 0) }, HOOD_OK, "{}", last_error());
    let (p1, v1) = (positions(b, n), velocities(b, n));
    for i in 0..n {
        let (p, v) = (p0[i], v0[i]);
        let want_p = [p[2] + t[0], p[1] + t[1], -p[0] + t[2]];
        let want_v = [v[2], v[1], -v[0]];
        assert!(max_diff(&[p1[i]], &[want_p]) < 1e-6 && max_diff(&[v1[i]], &[want_v]) < 1e-7, "vertex {i}");
    }
    // Undo it: shift by -t, then rotate by R^T.
    let rt = [0.0f32, 0.0, -1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0];
    // SAFETY: 9 floats.
    unsafe {
        let back = [-t[0], -t[1], -t[2]];
        assert_eq!(hood_sim_teleport(b, null(), back.as_ptr(), null(), 0), HOOD_OK);
        assert_eq!(hood_sim_teleport(b, rt.as_ptr(), null(), null(), 0), HOOD_OK);
    }
    assert!(max_diff(&positions(b, n), &p0) < 1e-5);
    // Now a pure translation: the network sees only relative quantities, so stepping the moved
    // scene equals stepping the original and moving the result. (A teleport leaves the body at
    // rest: the identity teleport of `a` does the same to it.)
    let d = [3.0f32, 0.5, -2.0];
    // SAFETY: 3 floats.
    unsafe {
        assert_eq!(hood_sim_teleport(b, null(), d.as_ptr(), null(), 0), HOOD_OK);
        assert_eq!(hood_sim_teleport(a, null(), null(), null(), 0), HOOD_OK);
    }
    for t in 5..=8 {
        assert_eq!(step(a, &sc.body_at(t, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(step(b, &sc.body_at(t, d), &mut out_b), HOOD_OK);
    }
    let moved_back: Vec<[f32; 3]> = out_b.iter().map(|p| [p[0] - d[0], p[1] - d[1], p[2] - d[2]]).collect();
    let err = max_diff(&moved_back, &out_a);
    assert!(err < 1e-4, "translation changed the result by {err} m");
    // Not rotations: a scale and a reflection are refused, state unchanged.
    let before = positions(b, n);
    let scale = [2.0f32, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0];
    let mirror = [-1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let nan_t = [f32::NAN, 0.0, 0.0];
    // SAFETY: 9 and 3 floats.
    unsafe {
        assert_eq!(hood_sim_teleport(b, scale.as_ptr(), null(), null(), 0), HOOD_ERR_OUT_OF_RANGE);
        assert_eq!(hood_sim_teleport(b, mirror.as_ptr(), null(), null(), 0), HOOD_ERR_OUT_OF_RANGE);
        assert_eq!(hood_sim_teleport(b, null(), nan_t.as_ptr(), null(), 0), HOOD_ERR_NON_FINITE);
    }
    // An explicit body: wrong count or NaN refused, state unchanged.
    let mut body = sc.body_at(9, d);
    // SAFETY: the counts passed are at most the array lengths.
    unsafe {
        assert_eq!(hood_sim_teleport(b, null(), null(), body.as_ptr().cast(), 3), HOOD_ERR_SIZE_MISMATCH);
        body[2][2] = f32::NAN;
        let s = hood_sim_teleport(b, null(), null(), body.as_ptr().cast(), body.len());
        assert_eq!(s, HOOD_ERR_NON_FINITE);
    }
    assert_eq!(positions(b, n), before);
    // Auto-teleport (on by default): a 2 m jump of the body carries the garment along.
    let jump = [d[0] + 2.0, d[1], d[2]];
    assert_eq!(step(b, &sc.body_at(9, jump), &mut out_b), HOOD_OK);
    let shifted: Vec<[f32; 3]> = before.iter().map(|p| [p[0] + 2.0, p[1], p[2]]).collect();
    let err = max_diff(&out_b, &shifted);
    assert!(err < 0.03, "auto-teleport moved the garment {err} m away from the body's jump");
    // SAFETY: live sims.
    unsafe {
        assert_eq!(hood_sim_free(a), HOOD_OK);
        assert_eq!(hood_sim_free(b), HOOD_OK);
    }
}

/// A C-style executor implemented in Rust: runs the tasks in reverse order (any order is allowed),
/// or misbehaves on request.
#[repr(C)]
struct TestExec {
    mode: u32, // 0: all tasks in reverse; 1: skip the last task; 2: call an index past the end;
    // 3: call index 0 twice; 4: as 0, but first wait until `release` is set (after setting `entered`);
    // 5: as 0 for the first `fail_after` runs, then as 1
    calls: std::sync::atomic::AtomicUsize,
    entered: std::sync::atomic::AtomicBool,
    release: std::sync::atomic::AtomicBool,
    fail_after: usize,
}

impl TestExec {
    fn new(mode: u32) -> TestExec {
        TestExec {
            mode,
            calls: Default::default(),
            entered: Default::default(),
            release: Default::default(),
            fail_after: 0,
        }
    }
}

unsafe extern "C-unwind" fn test_run(
    user: *mut std::ffi::c_void,
    n: u32,
    task: hood_task_fn,
    ctx: *mut std::ffi::c_void,
) {
    // SAFETY: `user` is the `TestExec` the test registered; `task` is the library's trampoline.
    let e = unsafe { &*(user as *const TestExec) };
    let task = task.unwrap();
    let before = e.calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    if e.mode == 4 {
        e.entered.store(true, std::sync::atomic::Ordering::SeqCst);
        while !e.release.load(std::sync::atomic::Ordering::SeqCst) {
            std::thread::yield_now();
        }
    }
    let skip_last = e.mode == 1 || (e.mode == 5 && before >= e.fail_after);
    let upto = if skip_last { n.saturating_sub(1) } else { n };
    for i in (0..upto).rev() {
        // SAFETY: the executor contract.
        unsafe { task(ctx, i) };
    }
    if e.mode == 2 {
        // SAFETY: the library must ignore (and report) out-of-range indices.
        unsafe { task(ctx, n + 5) };
    }
    if e.mode == 3 {
        // SAFETY: the library must refuse (and report) an index run twice.
        unsafe { task(ctx, 0) };
    }
}

#[test]
fn executor_callback_runs_the_step_and_misuse_is_caught() {
    let l = load(8, 9);
    let sc = scene(8);
    let n = sc.rest.len();
    let (a, b) = (sc.sim(l.model), sc.sim(l.model));
    let good = TestExec::new(0);
    let exec = executor(&good as *const TestExec as *mut _, 3, Some(test_run));
    // SAFETY: `good` outlives its use by `b` (restored to NULL below).
    assert_eq!(unsafe { hood_sim_set_executor(b, &exec) }, HOOD_OK);
    let mut out_a = vec![[0.0f32; 3]; n];
    let mut out_b = vec![[0.0f32; 3]; n];
    for t in 1..=3 {
        assert_eq!(step(a, &sc.body_at(t, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(step(b, &sc.body_at(t, [0.0; 3]), &mut out_b), HOOD_OK, "{}", last_error());
    }
    assert!(good.calls.load(std::sync::atomic::Ordering::SeqCst) > 0, "the executor was not used");
    assert_eq!(out_a, out_b, "task order changed the result");
    for mode in [1, 2, 3] {
        let bad = TestExec::new(mode);
        let exec = executor(&bad as *const TestExec as *mut _, 3, Some(test_run));
        let before = positions(b, n);
        let mut sentinel = vec![[5.0f32; 3]; n];
        // SAFETY: `bad` outlives its use (replaced below).
        unsafe {
            assert_eq!(hood_sim_set_executor(b, &exec), HOOD_OK);
            assert_eq!(step(b, &sc.body_at(4, [0.0; 3]), &mut sentinel), HOOD_ERR_PANIC);
            assert!(last_error().contains("exactly once"), "{}", last_error());
            assert_eq!(hood_sim_set_executor(b, null()), HOOD_OK);
        }
        assert!(sentinel.iter().all(|p| *p == [5.0; 3]));
        assert_eq!(positions(b, n), before, "a failed step changed the state");
    }
    // Back on its own executor, b still follows a.
    assert_eq!(step(a, &sc.body_at(4, [0.0; 3]), &mut out_a), HOOD_OK);
    assert_eq!(step(b, &sc.body_at(4, [0.0; 3]), &mut out_b), HOOD_OK);
    assert_eq!(out_a, out_b);
    // The first step runs a start-up pass, then the regular one: an executor that breaks the
    // contract in either leaves the state as it was, and the sim then steps as a fresh one does.
    let first = TestExec::new(0);
    let exec = executor(&first as *const TestExec as *mut _, 3, Some(test_run));
    let counted = sc.sim(l.model);
    // SAFETY: `first` outlives its use (the sim is freed below).
    unsafe {
        assert_eq!(hood_sim_set_executor(counted, &exec), HOOD_OK);
        assert_eq!(step(counted, &sc.body_at(1, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(hood_sim_free(counted), HOOD_OK);
    }
    let runs = first.calls.load(std::sync::atomic::Ordering::SeqCst);
    assert!(runs > 4, "{runs} executor runs in a first step");
    // Failing at the first run (the start-up pass) and at the last (the regular pass).
    for fail_after in [0, runs - 1] {
        let bad = TestExec { fail_after, ..TestExec::new(5) };
        let exec = executor(&bad as *const TestExec as *mut _, 3, Some(test_run));
        let (c, fresh) = (sc.sim(l.model), sc.sim(l.model));
        let (p0, v0) = (positions(c, n), velocities(c, n));
        // SAFETY: `bad` outlives its use (removed below).
        unsafe {
            assert_eq!(hood_sim_set_executor(c, &exec), HOOD_OK);
            assert_eq!(step(c, &sc.body_at(1, [0.0; 3]), &mut out_a), HOOD_ERR_PANIC, "fail after {fail_after}");
            assert_eq!(hood_sim_set_executor(c, null()), HOOD_OK);
        }
        assert_eq!((positions(c, n), velocities(c, n)), (p0, v0), "fail after {fail_after}: state changed");
        assert_eq!(step(c, &sc.body_at(1, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(step(fresh, &sc.body_at(1, [0.0; 3]), &mut out_b), HOOD_OK);
        assert_eq!(out_a, out_b, "fail after {fail_after}: the next step is not a first step");
        // SAFETY: live sims.
        unsafe {
            assert_eq!(hood_sim_free(c), HOOD_OK);
            assert_eq!(hood_sim_free(fresh), HOOD_OK);
        }
    }
    // SAFETY: live sims.
    unsafe {
        assert_eq!(hood_sim_free(a), HOOD_OK);
        assert_eq!(hood_sim_free(b), HOOD_OK);
    }
}

#[test]
fn config_effects_are_honoured() {
    let l = load(8, 10);
    let sc = scene(6);
    let n = sc.rest.len();
    let g = sc.garment();
    let bd = sc.body_desc();
    // SAFETY: live handles, arrays of the stated lengths.
    unsafe {
        let mut cfg = default_config();
        assert_eq!(cfg.effects & HOOD_EFFECT_NORMALS, 0);
        assert_eq!(cfg.solver_iterations, 30, "the default step is the solver's");
        // The network's step, with which refinement combines.
        cfg.solver_iterations = 0;
        let mut sim = null_mut();
        assert_eq!(hood_sim_new(l.model, g, &bd, &cfg, &mut sim), HOOD_OK);
        let mut nrm = vec![[0.0f32; 3]; n];
        assert_eq!(hood_sim_normals(sim, nrm.as_mut_ptr().cast(), n), HOOD_ERR_UNSUPPORTED_EFFECT);
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        // Collision projection: its margin is range-checked, and it needs body collision.
        let mut proj = cfg;
        proj.effects |= HOOD_EFFECT_COLLISION_PROJECTION;
        for bad in [-1e-3, f32::NAN, f32::INFINITY, hood::sim::PROJECTION_REACH] {
            proj.projection_margin = bad;
            assert_eq!(hood_sim_new(l.model, g, &bd, &proj, &mut sim), HOOD_ERR_OUT_OF_RANGE, "{bad}");
        }
        proj.projection_margin = 0.0;
        assert_eq!(hood_sim_new(l.model, g, &bd, &proj, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        proj.effects &= !HOOD_EFFECT_BODY_COLLISION;
        assert_eq!(hood_sim_new(l.model, g, &bd, &proj, &mut sim), HOOD_ERR_UNSUPPORTED_EFFECT);
        // Body tethers: off by default; the slack is range-checked; they need body collision.
        assert_eq!(cfg.effects & HOOD_EFFECT_TETHER, 0, "tethers are off by default");
        assert_eq!(cfg.tether_slack, hood::sim::DEFAULT_TETHER_SLACK);
        let mut tether = cfg;
        tether.effects |= HOOD_EFFECT_TETHER;
        for bad in [-1e-3, f32::NAN, f32::INFINITY, 2.0 * hood::sim::MAX_TETHER_SLACK] {
            tether.tether_slack = bad;
            assert_eq!(hood_sim_new(l.model, g, &bd, &tether, &mut sim), HOOD_ERR_OUT_OF_RANGE, "{bad}");
        }
        tether.tether_slack = 0.0;
        assert_eq!(hood_sim_new(l.model, g, &bd, &tether, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        tether.effects &= !HOOD_EFFECT_BODY_COLLISION;
        assert_eq!(hood_sim_new(l.model, g, &bd, &tether, &mut sim), HOOD_ERR_UNSUPPORTED_EFFECT);
        // Solver refinement: off by default; its iteration count is range-checked; it runs with
        // or without a body.
        assert_eq!(cfg.effects & HOOD_EFFECT_REFINE, 0, "refinement is off by default");
        assert_eq!(cfg.refine_iterations, hood::sim::DEFAULT_REFINE_ITERATIONS);
        let mut refine = cfg;
        refine.effects |= HOOD_EFFECT_REFINE;
        for bad in [0, hood::sim::MAX_REFINE_ITERATIONS + 1] {
            refine.refine_iterations = bad;
            assert_eq!(hood_sim_new(l.model, g, &bd, &refine, &mut sim), HOOD_ERR_OUT_OF_RANGE, "{bad}");
        }
        refine.refine_iterations = 2;
        assert_eq!(hood_sim_new(l.model, g, &bd, &refine, &mut sim), HOOD_OK, "{}", last_error());
        let sized = hood_refinement { struct_size: size_of_u32::<hood_refinement>(), ..Default::default() };
        let mut rep = hood_refinement { iterations: 9, energy_before: 9.0, energy_after: 9.0, ..sized };
        assert_eq!(hood_sim_last_refinement(sim, &mut rep), HOOD_OK);
        assert_eq!(rep, sized, "nothing refined yet");
        assert_eq!(hood_sim_last_refinement(sim, null_mut()), HOOD_ERR_NULL_POINTER);
        let body = sc.body_at(1, [0.0; 3]);
        let mut buf = vec![[0.0f32; 3]; n];
        assert_eq!(hood_sim_step(sim, body.as_ptr().cast(), body.len(), buf.as_mut_ptr().cast(), n), HOOD_OK);
        assert_eq!(hood_sim_last_refinement(sim, &mut rep), HOOD_OK);
        assert!(rep.iterations >= 1 && rep.energy_after < rep.energy_before, "{rep:?}");
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        assert_eq!(hood_sim_new(l.model, g, &bd, &cfg, &mut sim), HOOD_OK);
        assert_eq!(hood_sim_last_refinement(sim, &mut rep), HOOD_ERR_UNSUPPORTED_EFFECT);
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        // The solver step mode: off by default (0), range-checked, refused beside refinement,
        // reported by hood_sim_last_refinement.
        assert_eq!(cfg.solver_iterations, 0, "the network steps by default");
        let mut solver = cfg;
        solver.solver_iterations = hood::sim::MAX_REFINE_ITERATIONS + 1;
        assert_eq!(hood_sim_new(l.model, g, &bd, &solver, &mut sim), HOOD_ERR_OUT_OF_RANGE);
        solver.solver_iterations = 4;
        assert_eq!(hood_sim_new(l.model, g, &bd, &solver, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_step(sim, body.as_ptr().cast(), body.len(), buf.as_mut_ptr().cast(), n), HOOD_OK);
        assert_eq!(hood_sim_last_refinement(sim, &mut rep), HOOD_OK);
        assert!(rep.iterations >= 1 && rep.energy_after <= rep.energy_before, "{rep:?}");
        assert_eq!((rep.budget_ns, rep.used_ns), (0, 0), "a fixed count has no budget");
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        // Within a time budget (an hour: the iteration cap ends every solve here), and a budget
        // without the solver refused.
        assert_eq!(cfg.solver_budget_us, 0, "no time budget by default");
        solver.solver_budget_us = 3_600_000_000;
        assert_eq!(hood_sim_new(l.model, g, &bd, &solver, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_step(sim, body.as_ptr().cast(), body.len(), buf.as_mut_ptr().cast(), n), HOOD_OK);
        assert_eq!(hood_sim_last_refinement(sim, &mut rep), HOOD_OK);
        assert!(rep.iterations >= 1 && rep.iterations <= 4, "{rep:?}");
        assert_eq!(rep.budget_ns, 3_600_000_000_000);
        assert!(rep.used_ns > 0 && rep.used_ns < rep.budget_ns, "{rep:?}");
        assert_eq!(last_effects(sim) & HOOD_STEP_OVER_BUDGET, 0);
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        // A budget no step can keep (1 us): one iteration runs, and the step says it overran.
        solver.solver_budget_us = 1;
        assert_eq!(hood_sim_new(l.model, g, &bd, &solver, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_step(sim, body.as_ptr().cast(), body.len(), buf.as_mut_ptr().cast(), n), HOOD_OK);
        assert_eq!(hood_sim_last_refinement(sim, &mut rep), HOOD_OK);
        assert!(rep.iterations <= 1 && rep.budget_ns == 1000 && rep.used_ns > 1000, "{rep:?}");
        assert_ne!(last_effects(sim) & HOOD_STEP_OVER_BUDGET, 0);
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        let mut budget_alone = cfg;
        budget_alone.solver_budget_us = 5000;
        assert_eq!(hood_sim_new(l.model, g, &bd, &budget_alone, &mut sim), HOOD_ERR_UNSUPPORTED_EFFECT);
        solver.solver_budget_us = 0;
        solver.effects |= HOOD_EFFECT_REFINE;
        assert_eq!(hood_sim_new(l.model, g, &bd, &solver, &mut sim), HOOD_ERR_UNSUPPORTED_EFFECT);
        refine.effects &= !HOOD_EFFECT_BODY_COLLISION;
        assert_eq!(hood_sim_new(l.model, g, null(), &refine, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        // Normals on, no body collision: the sim wants no body vertices.
        cfg.effects = (cfg.effects | HOOD_EFFECT_NORMALS) & !HOOD_EFFECT_BODY_COLLISION;
        cfg.threads = 2;
        assert_eq!(hood_sim_new(l.model, g, &bd, &cfg, &mut sim), HOOD_OK);
        let mut nb = 9;
        assert_eq!(hood_sim_body_vertex_count(sim, &mut nb), HOOD_OK);
        assert_eq!(nb, 0);
        let mut out = vec![[0.0f32; 3]; n];
        assert_eq!(hood_sim_step(sim, null(), 0, out.as_mut_ptr().cast(), n), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_normals(sim, nrm.as_mut_ptr().cast(), n), HOOD_OK);
        let len = |v: [f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        assert!(nrm.iter().all(|v| (len(*v) - 1.0).abs() < 1e-3), "normals are not unit length");
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        assert_eq!(hood_garment_free(g), HOOD_OK);
    }
}

/// A raw pointer that may cross threads (the tests use it as the header allows).
struct SendPtr<T>(*mut T);
impl<T> Clone for SendPtr<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SendPtr<T> {}
// SAFETY: only handed to the library, which checks every use.
unsafe impl<T> Send for SendPtr<T> {}

#[test]
fn a_sim_in_use_on_another_thread_is_busy_for_step_and_free() {
    let l = load(8, 13);
    let sc = scene(6);
    let n = sc.rest.len();
    let sim = sc.sim(l.model);
    let exec = Box::leak(Box::new(TestExec::new(4)));
    let raw = executor(exec as *const TestExec as *mut _, 2, Some(test_run));
    // SAFETY: `exec` is leaked, so it outlives the sim.
    assert_eq!(unsafe { hood_sim_set_executor(sim, &raw) }, HOOD_OK);
    let p = SendPtr(sim);
    let body = sc.body_at(1, [0.0; 3]);
    let stepper = std::thread::spawn(move || {
        let p = p;
        let mut out = vec![[0.0f32; 3]; n];
        step(p.0, &body, &mut out)
    });
    while !exec.entered.load(std::sync::atomic::Ordering::SeqCst) {
        std::thread::yield_now();
    }
    // The other thread is inside the step: every call that changes or frees the sim is refused.
    let mut out = vec![[0.0f32; 3]; n];
    assert_eq!(step(sim, &sc.body_at(1, [0.0; 3]), &mut out), HOOD_ERR_BUSY);
    assert!(last_error().contains("another thread"), "{}", last_error());
    // SAFETY: a live sim (the library refuses the free while it is in use).
    unsafe {
        assert_eq!(hood_sim_free(sim), HOOD_ERR_BUSY);
        assert_eq!(hood_sim_set_executor(sim, null()), HOOD_ERR_BUSY);
    }
    exec.release.store(true, std::sync::atomic::Ordering::SeqCst);
    assert_eq!(stepper.join().unwrap(), HOOD_OK);
    assert_eq!(step(sim, &sc.body_at(2, [0.0; 3]), &mut out), HOOD_OK, "{}", last_error());
    // SAFETY: a live sim, now idle.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
}

#[test]
fn free_racing_steps_on_another_thread_never_crashes() {
    let l = load(8, 14);
    let sc = scene(3);
    let n = sc.rest.len();
    let frames: Vec<Vec<[f32; 3]>> = (1..=6).map(|t| sc.body_at(t, [0.0; 3])).collect();
    for _ in 0..1000 {
        let sim = SendPtr(sc.sim(l.model));
        let frames = frames.clone();
        let stepper = std::thread::spawn(move || {
            let sim = sim;
            let mut out = vec![[0.0f32; 3]; n];
            let mut codes = Vec::new();
            for f in &frames {
                codes.push(step(sim.0, f, &mut out));
            }
            codes
        });
        // Free as soon as the sim is idle: BUSY while a step runs, then OK exactly once.
        let mut freed = 0;
        while freed == 0 {
            // SAFETY: a handle of this library (checked; refused while in use).
            match unsafe { hood_sim_free(sim.0) } {
                HOOD_OK => freed += 1,
                HOOD_ERR_BUSY => std::thread::yield_now(),
                other => panic!("free gave {other}: {}", last_error()),
            }
        }
        let codes = stepper.join().unwrap();
        // Steps before the free succeed; after it the handle is gone.
        let first_gone = codes.iter().position(|&c| c != HOOD_OK).unwrap_or(codes.len());
        assert!(codes[first_gone..].iter().all(|&c| c == HOOD_ERR_INVALID_HANDLE), "{codes:?}");
    }
}

#[test]
fn two_threads_stepping_one_sim_are_told_busy_and_never_race() {
    let l = load(8, 15);
    let sc = scene(3);
    let n = sc.rest.len();
    let body = sc.body_at(1, [0.0; 3]);
    let sim = SendPtr(sc.sim(l.model));
    let run = {
        let body = body.clone();
        move || {
            let sim = sim;
            let mut out = vec![[0.0f32; 3]; n];
            let mut ok = 0;
            for _ in 0..1000 {
                match step(sim.0, &body, &mut out) {
                    HOOD_OK => ok += 1,
                    HOOD_ERR_BUSY => {}
                    other => panic!("a step gave {other}: {}", last_error()),
                }
                // A read may overlap another read, never a step.
                let mut p = vec![[0.0f32; 3]; n];
                // SAFETY: `p` holds n points.
                let r = unsafe { hood_sim_positions(sim.0, p.as_mut_ptr().cast(), n) };
                assert!(r == HOOD_OK || r == HOOD_ERR_BUSY, "positions gave {r}");
            }
            ok
        }
    };
    let a = std::thread::spawn(run.clone());
    let b = std::thread::spawn(run);
    let steps = a.join().unwrap() + b.join().unwrap();
    assert!(steps > 0, "no step succeeded");
    // Whichever thread won each step, the sim took exactly `steps` of them, one at a time.
    let alone = sc.sim(l.model);
    let mut out = vec![[0.0f32; 3]; n];
    for _ in 0..steps {
        assert_eq!(step(alone, &body, &mut out), HOOD_OK);
    }
    assert_eq!(positions(sim.0, n), positions(alone, n));
    assert_eq!(velocities(sim.0, n), velocities(alone, n));
    // SAFETY: live handles, idle.
    unsafe {
        assert_eq!(hood_sim_free(sim.0), HOOD_OK);
        assert_eq!(hood_sim_free(alone), HOOD_OK);
    }
}

#[test]
fn one_model_shared_by_sims_on_several_threads() {
    let l = load(8, 12);
    let model = l.model as usize; // raw pointers are not Send; the header allows this sharing
    let run = move || {
        let sc = scene(6);
        let sim = sc.sim(model as *const hood_model);
        let mut out = vec![[0.0f32; 3]; sc.rest.len()];
        for t in 1..=4 {
            assert_eq!(step(sim, &sc.body_at(t, [0.0; 3]), &mut out), HOOD_OK, "{}", last_error());
        }
        // SAFETY: a live sim used by this thread only.
        assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
        out
    };
    let threads: Vec<_> = (0..3).map(|_| std::thread::spawn(run)).collect();
    let results: Vec<Vec<[f32; 3]>> = threads.into_iter().map(|t| t.join().unwrap()).collect();
    assert!(results.windows(2).all(|w| w[0] == w[1]), "sims on different threads disagree");
    assert_eq!(results[0], run());
}

#[test]
fn an_inside_out_body_is_refused_and_a_coarse_one_reported() {
    let m = load(16, 3);
    let sc = scene(6);
    // The test scene's body: 194 vertices over an ellipsoid, outward, and coarse.
    let sim = sc.sim(m.model);
    let mut survey = hood_body_survey { struct_size: size_of_u32::<hood_body_survey>(), ..Default::default() };
    // SAFETY: live handle, writable out.
    assert_eq!(unsafe { hood_sim_body_survey(sim, &mut survey) }, HOOD_OK, "{}", last_error());
    assert!(survey.volume > 0.0 && survey.too_coarse == 1, "{survey:?}");
    // SAFETY: live handle.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
    // The same body with every face reversed.
    let flipped: Vec<[u32; 3]> = sc.body_faces.iter().map(|f| [f[0], f[2], f[1]]).collect();
    let g = sc.garment();
    let bd = hood_body_desc { indices: flipped.as_ptr().cast(), ..sc.body_desc() };
    let mut out = null_mut();
    // SAFETY: live handles, valid descriptors.
    assert_eq!(unsafe { hood_sim_new(m.model, g, &bd, null(), &mut out) }, HOOD_ERR_INSIDE_OUT);
    assert!(out.is_null() && last_error().contains("inside out"), "{}", last_error());
    // A finer body of the same shape: not coarse.
    let (fine, fine_faces) = hood::body::shapes::ellipsoid(40, 64, [0.25, 0.3, 0.25], [0.0; 3]);
    let bd = common::body_desc(&fine, &fine_faces);
    // SAFETY: as above.
    assert_eq!(unsafe { hood_sim_new(m.model, g, &bd, null(), &mut out) }, HOOD_OK, "{}", last_error());
    // SAFETY: live handle, writable out.
    assert_eq!(unsafe { hood_sim_body_survey(out, &mut survey) }, HOOD_OK);
    assert_eq!(survey.too_coarse, 0, "{survey:?}");
    // SAFETY: live handles.
    unsafe {
        assert_eq!(hood_sim_free(out), HOOD_OK);
        assert_eq!(hood_garment_free(g), HOOD_OK);
    }
}

/// A struct as a caller built against a newer header (whose struct has grown by 16 bytes) passes
/// it: the current struct, then bytes this library does not know.
#[repr(C)]
#[derive(Clone, Copy)]
struct Grown<T> {
    known: T,
    tail: [u8; 16],
}

/// `v` with its leading `struct_size` set to `size` and a zero tail.
fn grown<T: Copy>(v: T, size: usize) -> Grown<T> {
    let mut g = Grown { known: v, tail: [0; 16] };
    // SAFETY: every struct given here is one of the header's, which start with `uint32_t struct_size`.
    unsafe { (&mut g.known as *mut T).cast::<u32>().write(size as u32) };
    g
}

/// The struct_size rule on one kind of struct: `call` passes the struct to the library and returns
/// the status (it checks itself that a refused call wrote no out-parameter). Sizes below `oldest`
/// (the struct's size in the oldest header the library reads), absurd or misaligned are refused
/// without reading past the struct; a larger size is accepted with a zero tail and refused with
/// any nonzero byte in it; bytes past struct_size are not read.
fn check_struct_size_rule<T: Copy>(v: T, oldest: usize, mut call: impl FnMut(*const T) -> hood_status) {
    let name = std::any::type_name::<T>();
    let (size, align) = (size_of::<T>(), align_of::<T>());
    assert_eq!(call(&v), HOOD_OK, "{name}: the current size: {}", last_error());
    // u32::MAX and 4104 are larger than the 16 spare bytes: the library must not scan them.
    for bad in [0, 4, oldest - 1, oldest - align, size + 1, size + align / 2, 4096 + align, u32::MAX as usize] {
        let g = grown(v, bad);
        assert_eq!(call(&g.known), HOOD_ERR_STRUCT_SIZE, "{name}: struct_size {bad}");
        let e = last_error();
        assert!(e.contains("struct_size") && e.contains("another hood.h"), "{e}");
    }
    let g = grown(v, size + 16);
    assert_eq!(call(&g.known), HOOD_OK, "{name}: a zero tail: {}", last_error());
    for k in [0, 7, 15] {
        let mut g = grown(v, size + 16);
        g.tail[k] = 1;
        assert_eq!(call(&g.known), HOOD_ERR_STRUCT_SIZE, "{name}: tail byte {k}");
        assert!(last_error().contains(&format!("byte {} is not zero", size + k)), "{}", last_error());
    }
    // struct_size covers half the tail: the other half is not the struct's.
    let mut g = grown(v, size + 8);
    g.tail[8..].fill(0xff);
    assert_eq!(call(&g.known), HOOD_OK, "{name}: bytes past struct_size were read: {}", last_error());
}

#[test]
fn sim_config_and_body_struct_sizes_are_checked() {
    let l = load(8, 15);
    let sc = scene(5);
    let g = sc.garment();
    let bd = sc.body_desc();
    // SAFETY: writable out-parameter.
    let cfg = default_config();
    assert_eq!(cfg.struct_size as usize, size_of::<hood_sim_config>(), "hood_sim_config_default sets struct_size");
    let dangling = std::ptr::dangling_mut::<hood_sim>();
    // Creates a sim (freed at once); a refusal must leave `out` alone.
    let new_sim = |body: *const hood_body_desc, config: *const hood_sim_config| {
        let mut out = dangling;
        // SAFETY: live handles; the structs hold the bytes their struct_size states, or are
        // refused before the library reads past them.
        let s = unsafe { hood_sim_new(l.model, g, body, config, &mut out) };
        if s == HOOD_OK {
            // SAFETY: the new sim.
            assert_eq!(unsafe { hood_sim_free(out) }, HOOD_OK);
        } else {
            assert_eq!(out, dangling, "out written on error");
        }
        s
    };
    check_struct_size_rule(bd, size_of::<hood_body_desc>(), |b| new_sim(b, &cfg));
    // The config has grown since 0.2.0: a caller built against that header is read with the
    // fields added since as zero (here a set budget byte past its struct_size stays unread:
    // read, it would be refused without solver_iterations).
    let old = std::mem::offset_of!(hood_sim_config, solver_budget_us);
    check_struct_size_rule(cfg, old, |c| new_sim(&bd, c));
    let older = grown(hood_sim_config { solver_budget_us: 5000, ..cfg }, old);
    assert_eq!(new_sim(&bd, &older.known), HOOD_OK, "a 0.2.0 config: {}", last_error());
    // SAFETY: live handles.
    unsafe {
        assert_eq!(hood_garment_free(g), HOOD_OK);
        // No refused creation left the model counted as in use.
        assert_eq!(hood_model_free(l.model), HOOD_OK, "{}", last_error());
    }
}

#[test]
fn executor_struct_size_is_checked_and_a_refused_one_changes_nothing() {
    let l = load(8, 16);
    let sc = scene(6);
    let n = sc.rest.len();
    let sim = sc.sim(l.model);
    let (installed, other) = (TestExec::new(0), TestExec::new(0));
    let calls = |e: &TestExec| e.calls.load(std::sync::atomic::Ordering::SeqCst);
    // SAFETY: `installed` outlives its use (the sim is freed below).
    assert_eq!(
        unsafe { hood_sim_set_executor(sim, &executor(&installed as *const _ as *mut _, 2, Some(test_run))) },
        HOOD_OK
    );
    let mut out = vec![[0.0f32; 3]; n];
    let mut t = 0;
    check_struct_size_rule(
        executor(&other as *const _ as *mut _, 2, Some(test_run)),
        size_of::<hood_executor>(),
        |e| {
            let before = (calls(&installed), calls(&other));
            // SAFETY: `e` holds the bytes its struct_size states, or is refused before more are read;
            // `other` outlives the sim.
            let s = unsafe { hood_sim_set_executor(sim, e) };
            t += 1;
            assert_eq!(step(sim, &sc.body_at(t, [0.0; 3]), &mut out), HOOD_OK, "{}", last_error());
            let after = (calls(&installed), calls(&other));
            if s == HOOD_OK {
                assert!(after.1 > before.1 && after.0 == before.0, "the new executor did not run the step");
                // SAFETY: as above.
                assert_eq!(
                    unsafe {
                        hood_sim_set_executor(sim, &executor(&installed as *const _ as *mut _, 2, Some(test_run)))
                    },
                    HOOD_OK
                );
            } else {
                assert!(after.0 > before.0 && after.1 == before.1, "a refused executor replaced the installed one");
            }
            s
        },
    );
    // SAFETY: a live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
}

#[test]
fn material_arrays_with_a_larger_stride_give_the_same_sim() {
    let l = load(8, 17);
    let sc = scene(6);
    let n = sc.rest.len();
    // Per-vertex materials that differ from the default, so that misread ones would show.
    let mats: Vec<hood_material> =
        (0..n).map(|i| material(0.12 + 0.02 * (i % 5) as f32, 1.5e4 + 1e3 * (i % 3) as f32, 3e4, 2e-6)).collect();
    let big = size_of::<Grown<hood_material>>();
    let wide: Vec<Grown<hood_material>> = mats.iter().map(|m| grown(*m, big)).collect();
    let dangling = std::ptr::dangling_mut::<hood_garment>();
    let garment = |p: *const hood_material, count: usize| {
        let mut g = dangling;
        // SAFETY: `count` elements of the struct_size they carry (or refused before more is read).
        let s = unsafe {
            hood_garment_new(
                sc.rest.as_ptr().cast(),
                n,
                sc.faces.as_ptr().cast(),
                sc.faces.len(),
                p,
                count,
                sc.pinned.as_ptr(),
                &mut g,
            )
        };
        if s != HOOD_OK {
            assert_eq!(g, dangling, "out written on error");
        }
        (s, g)
    };
    // Steps a sim of the garment (freed) and returns its positions after 3 frames.
    let run = |g: *mut hood_garment| {
        let bd = sc.body_desc();
        let mut sim = null_mut();
        // SAFETY: live handles.
        unsafe {
            assert_eq!(hood_sim_new(l.model, g, &bd, null(), &mut sim), HOOD_OK, "{}", last_error());
            assert_eq!(hood_garment_free(g), HOOD_OK);
        }
        let mut out = vec![[0.0f32; 3]; n];
        for t in 1..=3 {
            assert_eq!(step(sim, &sc.body_at(t, [0.0; 3]), &mut out), HOOD_OK);
        }
        // SAFETY: a live sim.
        assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
        out
    };
    let (s, g) = garment(mats.as_ptr(), n);
    assert_eq!(s, HOOD_OK, "{}", last_error());
    let normal = run(g);
    let (s, g) = garment(wide.as_ptr().cast(), n);
    assert_eq!(s, HOOD_OK, "{}", last_error());
    assert_eq!(run(g), normal, "the wider stride gave another sim");
    assert_ne!(run(sc.garment()), normal, "the materials made no difference: the test would not see misreads");
    // One material for all, in either size.
    let (s, g) = garment(mats.as_ptr(), 1);
    assert_eq!(s, HOOD_OK, "{}", last_error());
    let one = run(g);
    let (s, g) = garment(wide.as_ptr().cast(), 1);
    assert_eq!(s, HOOD_OK, "{}", last_error());
    assert_eq!(run(g), one);
    // A count other than 0, 1 or n_vertices is refused before an element is read (or room for
    // them allocated: 2^50 of them would abort the process).
    for count in [2, n + 1, 1 << 50] {
        assert_eq!(garment(mats.as_ptr(), count).0, HOOD_ERR_SIZE_MISMATCH, "{count} materials");
        assert!(last_error().contains("materials"), "{}", last_error());
    }

    // A nonzero byte in one element's tail.
    let mut bad = wide.clone();
    bad[3].tail[2] = 1;
    assert_eq!(garment(bad.as_ptr().cast(), n).0, HOOD_ERR_STRUCT_SIZE);
    assert!(last_error().contains("hood_material[3]"), "{}", last_error());
    // An element whose struct_size differs from the first's (even a plausible one).
    for other in [size_of::<hood_material>(), 4096] {
        let mut bad = wide.clone();
        bad[5] = grown(bad[5].known, other);
        assert_eq!(garment(bad.as_ptr().cast(), n).0, HOOD_ERR_STRUCT_SIZE, "{other}");
        assert!(
            last_error().contains("hood_material[5]") && last_error().contains("every element"),
            "{}",
            last_error()
        );
    }
    let mut bad = mats.clone();
    bad[n - 1].struct_size = big as u32;
    assert_eq!(garment(bad.as_ptr(), n).0, HOOD_ERR_STRUCT_SIZE);
    // The first element's struct_size one too small (the stride of a caller's older struct).
    let mut bad = mats.clone();
    bad.iter_mut().for_each(|m| m.struct_size -= 1);
    assert_eq!(garment(bad.as_ptr(), n).0, HOOD_ERR_STRUCT_SIZE);
    assert!(last_error().contains("hood_material[0]"), "{}", last_error());
}

#[test]
fn status_string_is_static_and_leaves_the_last_error() {
    // SAFETY: a freed (never created) handle, refused without being dereferenced.
    assert_eq!(unsafe { hood_sim_free(std::ptr::dangling_mut::<hood_sim>()) }, HOOD_ERR_INVALID_HANDLE);
    let e = last_error();
    let p = hood_status_string(HOOD_ERR_BUSY);
    // SAFETY: static NUL-terminated strings.
    let text = |p| unsafe { CStr::from_ptr(p) }.to_str().unwrap();
    assert_eq!(text(p), "HOOD_ERR_BUSY: the handle is in use by another call: a sim on another thread, or a model or garment being read");
    assert_eq!(text(hood_status_string(HOOD_ERR_STRUCT_SIZE)).split(':').next(), Some("HOOD_ERR_STRUCT_SIZE"));
    assert_eq!(text(hood_status_string(108)), "unknown status");
    assert_eq!(last_error(), e, "hood_status_string changed the last error");
    // Still valid after other calls, and the same storage.
    assert_eq!(hood_status_string(HOOD_ERR_BUSY), p);
    assert_eq!(text(p), "HOOD_ERR_BUSY: the handle is in use by another call: a sim on another thread, or a model or garment being read");
}

#[test]
fn saved_state_round_trips_bitwise_and_damaged_bytes_change_nothing() {
    let l = load(8, 7);
    let sc = scene(6);
    let n = sc.rest.len();
    let (a, b) = (sc.sim(l.model), sc.sim(l.model));
    let mut out_a = vec![[0.0f32; 3]; n];
    let mut out_b = vec![[0.0f32; 3]; n];
    for t in 1..=5 {
        assert_eq!(step(a, &sc.body_at(t, [0.0; 3]), &mut out_a), HOOD_OK);
    }
    let mut len = 0usize;
    // SAFETY: live handle, writable out.
    assert_eq!(unsafe { hood_sim_state_size(a, &mut len) }, HOOD_OK);
    let mut saved = vec![0u8; len];
    // SAFETY: `len` writable bytes; a wrong length is refused.
    unsafe {
        assert_eq!(hood_sim_save_state(a, saved.as_mut_ptr(), len - 1), HOOD_ERR_SIZE_MISMATCH);
        assert_eq!(hood_sim_save_state(a, saved.as_mut_ptr(), len), HOOD_OK, "{}", last_error());
        assert_eq!(hood_sim_load_state(b, saved.as_ptr(), len), HOOD_OK, "{}", last_error());
    }
    assert_eq!(positions(b, n), positions(a, n));
    assert_eq!(velocities(b, n), velocities(a, n));
    for t in 6..=9 {
        assert_eq!(step(a, &sc.body_at(t, [0.0; 3]), &mut out_a), HOOD_OK);
        assert_eq!(step(b, &sc.body_at(t, [0.0; 3]), &mut out_b), HOOD_OK);
        assert_eq!(out_a, out_b, "frame {t}");
    }
    // A damaged copy: refused, the sim unchanged.
    let before = (positions(b, n), velocities(b, n));
    let mut bad = saved.clone();
    bad[len / 2] ^= 1;
    // SAFETY: `len` readable bytes.
    assert_eq!(unsafe { hood_sim_load_state(b, bad.as_ptr(), len) }, HOOD_ERR_CORRUPT_DATA);
    assert!(last_error().contains("checksum"), "{}", last_error());
    // SAFETY: as above; NULL bytes give a status.
    unsafe {
        assert_eq!(hood_sim_load_state(b, saved.as_ptr(), len - 3), HOOD_ERR_CORRUPT_DATA);
        assert_eq!(hood_sim_load_state(b, null(), len), HOOD_ERR_NULL_POINTER);
    }
    assert_eq!((positions(b, n), velocities(b, n)), before);
    // SAFETY: live sims.
    unsafe {
        assert_eq!(hood_sim_free(a), HOOD_OK);
        assert_eq!(hood_sim_free(b), HOOD_OK);
    }
}

#[test]
fn config_init_writes_the_callers_size_and_refuses_what_it_cannot_serve() {
    let mut def = default_config();
    // A caller built against a newer header: 16 more bytes, which init zeroes.
    #[repr(C)]
    #[derive(Clone, Copy)]
    struct Newer {
        cfg: hood_sim_config,
        extra: [u32; 4],
    }
    let mut newer = Newer { cfg: def, extra: [0xDEAD_BEEF; 4] };
    let size = std::mem::size_of::<Newer>();
    // SAFETY: `size` writable bytes.
    assert_eq!(unsafe { hood_sim_config_init(&mut newer.cfg, size) }, HOOD_OK, "{}", last_error());
    assert_eq!(newer.extra, [0; 4]);
    assert_eq!(newer.cfg.struct_size as usize, size);
    let same = hood_sim_config { struct_size: newer.cfg.struct_size, ..def };
    assert_eq!(newer.cfg, same);
    // A caller built against the 0.2.0 header: its fields written, not one byte more.
    let old = std::mem::offset_of!(hood_sim_config, solver_budget_us);
    let mut older = Newer { cfg: hood_sim_config { solver_budget_us: 77, ..def }, extra: [7; 4] };
    // SAFETY: `old` writable bytes (and more).
    assert_eq!(unsafe { hood_sim_config_init(&mut older.cfg, old) }, HOOD_OK, "{}", last_error());
    assert_eq!(older.cfg, hood_sim_config { struct_size: old as u32, solver_budget_us: 77, ..def });
    // Too small, too large, misaligned: refused, nothing written.
    for bad in [old - 4, 8192, std::mem::size_of::<hood_sim_config>() + 2] {
        let mut c = Newer { cfg: def, extra: [7; 4] };
        c.cfg.effects = 12345;
        // SAFETY: at least `size` writable bytes; refused sizes write nothing.
        let s = unsafe { hood_sim_config_init(&mut c.cfg, bad) };
        assert_eq!(s, HOOD_ERR_STRUCT_SIZE, "size {bad}");
        assert_eq!((c.cfg.effects, c.extra), (12345, [7; 4]), "size {bad}");
    }
    // The current size: identical to the header's hood_sim_config_default.
    let mut cur = def;
    cur.effects = 0;
    // SAFETY: a whole struct.
    assert_eq!(unsafe { hood_sim_config_init(&mut cur, std::mem::size_of::<hood_sim_config>()) }, HOOD_OK);
    def.struct_size = std::mem::size_of::<hood_sim_config>() as u32;
    assert_eq!(cur, def);
    // SAFETY: NULL gives a status.
    assert_eq!(unsafe { hood_sim_config_init(null_mut(), 64) }, HOOD_ERR_NULL_POINTER);
}

/// The exported `hood_sim_config_default` (a program built against the 0.2.0 header calls it;
/// the header now maps the name to `hood_sim_config_init`) writes the 0.2.0 struct and not a
/// byte past it, where the caller's struct may end.
#[test]
fn config_default_symbol_writes_only_the_oldest_struct() {
    #[repr(C)]
    struct Padded {
        cfg: std::mem::MaybeUninit<hood_sim_config>,
        extra: [u32; 4],
    }
    let old = std::mem::offset_of!(hood_sim_config, solver_budget_us);
    let mut p = Padded { cfg: std::mem::MaybeUninit::uninit(), extra: [0; 4] };
    let base = &mut p as *mut Padded as *mut u8;
    let len = size_of::<Padded>();
    // SAFETY: `len` bytes of `p`; then the call writes within its first `old` bytes (the test's
    // claim), and every byte is initialised before it is read.
    let bytes = unsafe {
        std::ptr::write_bytes(base, 0xAB, len);
        hood_sim_config_default(p.cfg.as_mut_ptr());
        std::slice::from_raw_parts(base, len).to_vec()
    };
    assert!(bytes[old..].iter().all(|&b| b == 0xAB), "wrote past the 0.2.0 struct");
    let mut want = default_config();
    // SAFETY: a whole struct, and more than `old` bytes.
    assert_eq!(unsafe { hood_sim_config_init(&mut want, old) }, HOOD_OK);
    // SAFETY: `want` is plain data of at least `old` bytes.
    let want = unsafe { std::slice::from_raw_parts(&want as *const hood_sim_config as *const u8, old) };
    assert_eq!(&bytes[..old], want);
    assert_eq!(u32::from_ne_bytes(bytes[..4].try_into().unwrap()) as usize, old, "struct_size");
}

fn last_effects(sim: *const hood_sim) -> u32 {
    let mut flags = u32::MAX;
    // SAFETY: a live sim; `flags` writable.
    assert_eq!(unsafe { hood_sim_last_effects(sim, &mut flags) }, HOOD_OK, "{}", last_error());
    flags
}

/// A sim of `sc` with the network's config changed by `f`.
fn sim_with(sc: &Scene, model: *const hood_model, f: impl FnOnce(&mut hood_sim_config)) -> *mut hood_sim {
    let mut cfg = network_config();
    f(&mut cfg);
    let g = sc.garment();
    let bd = sc.body_desc();
    let mut sim = null_mut();
    // SAFETY: live handles, valid descriptors.
    unsafe {
        assert_eq!(hood_sim_new(model, g, &bd, &cfg, &mut sim), HOOD_OK, "{}", last_error());
        assert_eq!(hood_garment_free(g), HOOD_OK);
    }
    sim
}

#[test]
fn last_effects_name_what_each_step_did() {
    let l = load(8, 16);
    let sc = scene(5);
    let n = sc.rest.len();
    let mut out = vec![[0.0f32; 3]; n];
    let sim = sim_with(&sc, l.model, |_| {});
    assert_eq!(last_effects(sim), 0, "no step yet");
    // SAFETY: a live sim; NULL flags.
    assert_eq!(unsafe { hood_sim_last_effects(sim, null_mut()) }, HOOD_ERR_NULL_POINTER);
    assert_eq!(unsafe { hood_sim_last_effects(null(), null_mut()) }, HOOD_ERR_NULL_POINTER);
    assert_eq!(step(sim, &sc.body_at(0, [0.0; 3]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_STARTUP);
    assert_eq!(step(sim, &sc.body_at(1, [0.0; 3]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), 0);
    // Faster than the speed limit (0.12 m/frame), slower than a teleport (0.45 m).
    assert_eq!(step(sim, &sc.body_at(2, [0.2, 0.0, 0.0]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_SPEED_LIMITED);
    // A refused step leaves the flags.
    let mut bad = sc.body_at(3, [0.2, 0.0, 0.0]);
    bad[0][1] = f32::NAN;
    assert_eq!(step(sim, &bad, &mut out), HOOD_ERR_NON_FINITE);
    assert_eq!(last_effects(sim), HOOD_STEP_SPEED_LIMITED);
    // A jump of a metre.
    assert_eq!(step(sim, &sc.body_at(3, [1.2, 0.0, 0.0]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_TELEPORTED);
    // SAFETY: a live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);

    // Sleeping after one frame at rest (a threshold nothing here exceeds).
    let sim = sim_with(&sc, l.model, |c| {
        c.effects |= HOOD_EFFECT_SLEEPING;
        c.sleep_threshold = 1e3;
        c.sleep_frames = 1;
    });
    let still = sc.body_at(0, [0.0; 3]);
    assert_eq!(step(sim, &still, &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_STARTUP);
    assert_eq!(step(sim, &still, &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_SLEPT);
    // SAFETY: a live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);

    // Refinement.
    let sim = sim_with(&sc, l.model, |c| {
        c.effects |= HOOD_EFFECT_REFINE;
        c.refine_iterations = 2;
    });
    assert_eq!(step(sim, &sc.body_at(0, [0.0; 3]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_STARTUP | HOOD_STEP_REFINED);
    assert_eq!(step(sim, &sc.body_at(1, [0.0; 3]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_REFINED);
    // SAFETY: a live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
    // The projection, with the cloth's middle placed 1 cm inside the body's top.
    let sim = sim_with(&sc, l.model, |c| c.effects |= HOOD_EFFECT_COLLISION_PROJECTION);
    let inside: Vec<[f32; 3]> = sc.rest.iter().map(|p| [p[0], 0.29, p[2]]).collect();
    // SAFETY: a live sim; `inside` holds n points.
    assert_eq!(unsafe { hood_sim_reset(sim, inside.as_ptr().cast(), n, null(), 0) }, HOOD_OK);
    assert_eq!(step(sim, &sc.body_at(0, [0.0; 3]), &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_STARTUP | HOOD_STEP_PROJECTED);
    // SAFETY: a live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
    // Tethers with no slack, the body dropping 10 cm from under the cloth (under the speed
    // limit): the cloth is pulled after it.
    let sim = sim_with(&sc, l.model, |c| {
        c.effects |= HOOD_EFFECT_TETHER;
        c.tether_slack = 0.0;
    });
    assert_eq!(step(sim, &sc.body_at(0, [0.0, -0.1, 0.0]), &mut out), HOOD_OK);
    assert_ne!(last_effects(sim) & HOOD_STEP_TETHERED, 0);
    // SAFETY: a live sim.
    assert_eq!(unsafe { hood_sim_free(sim) }, HOOD_OK);
}

#[test]
fn model_info_and_texts_describe_the_model() {
    let l = load(16, 17);
    let mut info = hood_model_info { struct_size: size_of_u32::<hood_model_info>(), ..Default::default() };
    // SAFETY: a live model; `info` of its size.
    assert_eq!(unsafe { hood_model_get_info(l.model, &mut info) }, HOOD_OK, "{}", last_error());
    let bytes = random_model_bytes(16, 17);
    let aligned = ModelBytes::new(&bytes);
    let m = aligned.model().unwrap();
    let spec = m.spec();
    let want = hood_model_info {
        struct_size: size_of_u32::<hood_model_info>(),
        format_version: hood::model::file::FORMAT_VERSION,
        latent: 16,
        hidden_layers: spec.hidden_layers as u32,
        blocks: spec.blocks.len() as u32,
        levels: spec.levels as u32,
        has_bf16: 0,
        effects: HOOD_EFFECT_BODY_COLLISION | HOOD_EFFECT_PINNING,
        local_materials: spec.effects.local_materials as u32,
        frame_time: 1.0 / 30.0,
        length_unit: 1.0,
        up_axis: 1,
        parameters: spec.parameter_count(),
        schedule_len: hood::model::spec::format_schedule(&spec.blocks).len(),
        provenance_len: "kind: random hood-ffi test model\n".len(),
    };
    assert_eq!(info, want);
    let text = |which: u32, len: usize| -> (hood_status, Vec<u8>) {
        let mut buf = vec![0xAAu8; len];
        // SAFETY: `buf` holds `len` bytes.
        let s = unsafe { hood_model_text(l.model, which, buf.as_mut_ptr().cast(), len) };
        (s, buf)
    };
    let (s, buf) = text(HOOD_MODEL_TEXT_PROVENANCE, info.provenance_len + 1);
    assert_eq!(s, HOOD_OK, "{}", last_error());
    assert_eq!(&buf[..], b"kind: random hood-ffi test model\n\0");
    let (s, buf) = text(HOOD_MODEL_TEXT_SCHEDULE, info.schedule_len + 8);
    assert_eq!(s, HOOD_OK);
    assert_eq!(
        &buf[..=info.schedule_len],
        format!("{}\0", hood::model::spec::format_schedule(&spec.blocks)).as_bytes()
    );
    assert!(buf[info.schedule_len + 1..].iter().all(|&b| b == 0xAA), "wrote past the NUL");
    // Too small a buffer, an unknown text, NULLs: refused, nothing written.
    let (s, buf) = text(HOOD_MODEL_TEXT_PROVENANCE, info.provenance_len);
    assert_eq!(s, HOOD_ERR_SIZE_MISMATCH);
    assert!(buf.iter().all(|&b| b == 0xAA));
    assert_eq!(text(2, 64).0, HOOD_ERR_OUT_OF_RANGE);
    // SAFETY: NULL pointers and a freed-looking handle are what the library must catch.
    unsafe {
        assert_eq!(hood_model_text(l.model, 0, null_mut(), 8), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_model_get_info(l.model, null_mut()), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_model_get_info(null(), &mut info), HOOD_ERR_NULL_POINTER);
    }
    // bf16 weights show.
    let bf =
        ModelBytes::new(&hood::model::write_model(&hood::model::Params::init(spec, 1).unwrap(), true, &[]).unwrap());
    let mut model = null_mut();
    // SAFETY: aligned bytes that outlive the model (freed below).
    unsafe {
        assert_eq!(hood_model_load(bf.as_bytes().as_ptr(), bf.as_bytes().len(), &mut model), HOOD_OK);
        assert_eq!(hood_model_get_info(model, &mut info), HOOD_OK);
        assert_eq!((info.has_bf16, info.provenance_len), (1, 0));
        assert_eq!(hood_model_free(model), HOOD_OK);
    }
}

/// Output structs follow the `struct_size` rule: a size too small or misaligned is refused and
/// nothing is written; a larger one (a newer header) gets the known fields and zeros after them.
#[test]
fn output_struct_sizes_are_checked_and_tails_zeroed() {
    let l = load(8, 18);
    let sc = scene(5);
    let sim = sc.sim(l.model);
    fn check<T: Copy>(v: T, call: impl Fn(*mut T) -> hood_status) {
        let size = size_of::<T>();
        let sized = |struct_size: usize, fill: u8| {
            let mut g = Grown { known: v, tail: [fill; 16] };
            // SAFETY: every output struct starts with its u32 struct_size.
            unsafe { (&mut g.known as *mut T).cast::<u32>().write(struct_size as u32) };
            g
        };
        for bad in [0, size - 4, size + 1, 5000] {
            let mut g = sized(bad, 0xEE);
            assert_eq!(call(&mut g.known), HOOD_ERR_STRUCT_SIZE, "struct_size {bad}");
            assert!(last_error().contains("struct_size"), "{}", last_error());
            assert_eq!(g.tail, [0xEE; 16], "a refused call wrote past the struct");
        }
        let mut g = sized(size + 16, 0xEE);
        assert_eq!(call(&mut g.known), HOOD_OK, "{}", last_error());
        assert_eq!(g.tail, [0; 16], "a newer header's fields read zero");
        // SAFETY: as above.
        assert_eq!(unsafe { (&g.known as *const T).cast::<u32>().read() } as usize, size + 16);
    }
    // SAFETY: live handles; every pointer is a grown struct of the size it states.
    unsafe {
        check(hood_model_info::default(), |p| hood_model_get_info(l.model, p));
        check(hood_body_survey::default(), |p| hood_sim_body_survey(sim, p));
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        let refined = sim_with(&sc, l.model, |c| c.effects |= HOOD_EFFECT_REFINE);
        check(hood_refinement::default(), |p| hood_sim_last_refinement(refined, p));
        assert_eq!(hood_sim_free(refined), HOOD_OK);
    }
}

#[test]
fn driver_matches_the_rust_fixed_step_bitwise() {
    let bytes = ModelBytes::new(&random_model_bytes(8, 19));
    let model = bytes.model().unwrap();
    let sc = scene(5);
    let n = sc.rest.len();
    let pins: Vec<bool> = sc.pinned.iter().map(|&p| p != 0).collect();
    let garment = hood::mesh::Garment::new(hood::mesh::GarmentDesc::new(&sc.rest, &sc.faces).pinned(&pins)).unwrap();
    let mesh = hood::body::BodyMesh::new(sc.body.len(), &sc.body_faces).unwrap();
    let body = hood::sim::BodyDesc { mesh: &mesh, positions: &sc.body };
    let sim = hood::sim::Sim::new(&model, &garment, Some(body), hood::sim::SimConfig::network()).unwrap();
    let mut rust = hood::sim::FixedStep::new(sim);

    let mut h_model = null_mut();
    let mut driver = null_mut();
    // SAFETY: aligned bytes that outlive the model (freed below).
    unsafe { assert_eq!(hood_model_load(bytes.as_bytes().as_ptr(), bytes.as_bytes().len(), &mut h_model), HOOD_OK) };
    let sim = sc.sim(h_model);
    // SAFETY: a live sim; `driver` writable.
    assert_eq!(unsafe { hood_driver_new(sim, &mut driver) }, HOOD_OK, "{}", last_error());
    let body_at = |t: f32| -> Vec<[f32; 3]> {
        let dx = 0.05 * (2.0 * t).sin();
        sc.body.iter().map(|p| [p[0] + dx, p[1], p[2]]).collect()
    };
    let update = |dt: f32, b: &[[f32; 3]], out: &mut [[f32; 3]]| {
        // SAFETY: arrays of the stated lengths.
        unsafe { hood_driver_update(driver, dt, b.as_ptr().cast(), b.len(), out.as_mut_ptr().cast(), out.len()) }
    };
    // Engine frames of 60, 144, 30 and 20 Hz, a zero-length one, and some uneven ones.
    let dts = [1.0 / 60.0, 1.0 / 144.0, 1.0 / 30.0, 0.05, 0.0, 0.013, 0.041, 1.0 / 144.0, 0.1];
    let mut t = 0.0f32;
    let mut out = vec![[0.0f32; 3]; n];
    for k in 0..120 {
        let dt = dts[k % dts.len()];
        t += dt;
        let b = body_at(t);
        let want = rust.update(dt, &b).unwrap().to_vec();
        assert_eq!(update(dt, &b, &mut out), HOOD_OK, "{}", last_error());
        assert_eq!(out, want, "update {k}");
        let mut steps = 0;
        // SAFETY: a live driver.
        assert_eq!(unsafe { hood_driver_model_steps(driver, &mut steps) }, HOOD_OK);
        assert_eq!(steps, rust.model_steps());
    }
    assert!(rust.model_steps() > 100, "{}", rust.model_steps());
    // Refused input changes nothing; then both go on alike.
    let sentinel = vec![[5.0f32; 3]; n];
    let mut o = sentinel.clone();
    let b = body_at(t);
    assert_eq!(update(-0.01, &b, &mut o), HOOD_ERR_OUT_OF_RANGE);
    assert_eq!(update(f32::NAN, &b, &mut o), HOOD_ERR_OUT_OF_RANGE);
    let mut nan = b.clone();
    nan[3][0] = f32::NAN;
    assert_eq!(update(0.1, &nan, &mut o), HOOD_ERR_NON_FINITE);
    assert_eq!(update(0.1, &b[1..], &mut o), HOOD_ERR_SIZE_MISMATCH);
    assert_eq!(update(0.1, &b, &mut o[1..]), HOOD_ERR_SIZE_MISMATCH);
    assert_eq!(o, sentinel);
    assert_eq!(update(0.1, &b, &mut out), HOOD_OK);
    assert_eq!(out, rust.update(0.1, &b).unwrap());
    // SAFETY: NULL and freed handles are what the library must catch.
    unsafe {
        let mut steps = 0;
        assert_eq!(hood_driver_update(null_mut(), 0.1, null(), 0, out.as_mut_ptr().cast(), n), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_driver_model_steps(driver, null_mut()), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_driver_model_steps(sim.cast(), &mut steps), HOOD_ERR_INVALID_HANDLE);
        // The sim freed under the driver: its updates are refused, the driver can still go.
        assert_eq!(hood_sim_free(sim), HOOD_OK);
        assert_eq!(update(0.1, &b, &mut out), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(hood_driver_free(driver), HOOD_OK);
        assert_eq!(hood_driver_free(driver), HOOD_ERR_INVALID_HANDLE);
        assert_eq!(hood_driver_free(null_mut()), HOOD_OK);
        assert_eq!(hood_model_free(h_model), HOOD_OK);
    }
}

/// In a Rust program the library has allocated before any call (the test harness did), so an
/// allocator is refused; `tests/examples.rs` installs one from C.
#[test]
fn an_allocator_after_the_first_allocation_is_refused() {
    unsafe extern "C-unwind" fn no_alloc(_: usize, _: usize, _: *mut std::ffi::c_void) -> *mut std::ffi::c_void {
        null_mut()
    }
    unsafe extern "C-unwind" fn no_free(_: *mut std::ffi::c_void, _: usize, _: usize, _: *mut std::ffi::c_void) {}
    let a = hood_allocator {
        struct_size: size_of_u32::<hood_allocator>(),
        user: null_mut(),
        alloc: Some(no_alloc),
        free: Some(no_free),
    };
    // SAFETY: a valid allocator struct (never installed), and NULLs.
    unsafe {
        assert_eq!(hood_set_allocator(&a), HOOD_ERR_TOO_LATE);
        assert!(last_error().contains("before any other"), "{}", last_error());
        assert_eq!(hood_set_allocator(null()), HOOD_ERR_NULL_POINTER);
        assert_eq!(hood_set_allocator(&hood_allocator { free: None, ..a }), HOOD_ERR_NULL_POINTER);
    }
}

/// `hood_garment_push_out` on caller arrays; `moved` starts at a sentinel.
fn push_out(body: *const hood_body_desc, x: &mut [[f32; 3]], pinned: *const u8, moved: &mut usize) -> hood_status {
    // SAFETY: `x` holds its length in points; `pinned` is NULL or holds as many flags.
    unsafe { hood_garment_push_out(body, x.as_mut_ptr().cast(), x.len(), pinned, moved) }
}

/// The scene's cloth lowered into the body's top (y = 0.25 inside a body 0.3 high), pinned at
/// its two outer corners and at one vertex inside the body.
fn cloth_in_body(sc: &Scene) -> (Vec<[f32; 3]>, Vec<u8>) {
    let x: Vec<[f32; 3]> = sc.rest.iter().map(|p| [p[0], 0.25, p[2]]).collect();
    let mut pinned = sc.pinned.clone();
    let r2 = |p: &[f32; 3]| p[0] * p[0] + p[2] * p[2];
    let inner = (0..x.len()).min_by(|&a, &b| r2(&x[a]).total_cmp(&r2(&x[b]))).unwrap();
    pinned[inner] = 1;
    (x, pinned)
}

fn bits(x: &[[f32; 3]]) -> Vec<[u32; 3]> {
    x.iter().map(|p| p.map(f32::to_bits)).collect()
}

#[test]
fn garment_push_out_moves_cloth_out_of_the_body_as_rust_does() {
    use hood::solve::INITIAL_CLEARANCE;
    let sc = scene(9);
    let bd = sc.body_desc();
    let (start, pinned) = cloth_in_body(&sc);
    let n = start.len();
    // The Rust function on the same input, and the faces it pushes along (nearest by centroid).
    let mesh = hood::body::BodyMesh::new(sc.body.len(), &sc.body_faces).unwrap();
    let pins: Vec<bool> = pinned.iter().map(|&p| p != 0).collect();
    let mut want = start.clone();
    let want_moved = hood::solve::push_out_of(&mesh, &sc.body, &mut want, &pins).unwrap();
    let mut frame = hood::body::BodyFrame::new(&mesh).unwrap();
    frame.update(&mesh, &sc.body).unwrap();
    let mut near = vec![hood::body::Nearest { index: 0, distance: 0.0 }; n];
    frame.nearest_faces(&start, &mut near).unwrap();
    let faces = hood::physics::FaceFrame { centroids: frame.centroids(), normals: frame.face_normals() };
    let plane = |p: [f32; 3], i: usize| hood::physics::plane_distance(p, near[i].index as usize, faces);
    let inside = |x: &[[f32; 3]], i: usize| {
        let p = x[i].map(f64::from);
        hood::body::winding_number_exact(&sc.body_faces, &sc.body, p).abs() > 0.5
    };

    let mut x = start.clone();
    let mut moved = usize::MAX;
    assert_eq!(push_out(&bd, &mut x, pinned.as_ptr(), &mut moved), HOOD_OK, "{}", last_error());
    assert_eq!(bits(&x), bits(&want), "the C result differs from hood::solve::push_out_of");
    assert_eq!(moved, want_moved);
    let changed = (0..n).filter(|&i| x[i] != start[i]).count();
    assert_eq!(moved, changed, "moved counts the vertices that moved");
    let was_inside = (0..n).filter(|&i| !pins[i] && inside(&start, i)).count();
    assert!(was_inside >= 4 && moved >= was_inside, "{was_inside} unpinned vertices inside, {moved} moved");
    for i in 0..n {
        if pins[i] {
            assert_eq!(x[i].map(f32::to_bits), start[i].map(f32::to_bits), "pinned vertex {i} moved");
        } else {
            let d = plane(x[i], i);
            assert!(d >= INITIAL_CLEARANCE - 1e-6, "vertex {i}: {d} m in front of its face");
            assert!(!inside(&x, i), "vertex {i} is still inside the body");
            if x[i] != start[i] {
                assert!(plane(start[i], i) < INITIAL_CLEARANCE, "vertex {i} moved from {} m", plane(start[i], i));
            }
        }
    }
    // The pinned vertex inside stays inside.
    assert!((0..n).any(|i| pins[i] && inside(&x, i)));
    // `moved` and `pinned` are optional; without pins every vertex inside moves.
    let mut y = start.clone();
    // SAFETY: `y` holds n points.
    assert_eq!(unsafe { hood_garment_push_out(&bd, y.as_mut_ptr().cast(), n, pinned.as_ptr(), null_mut()) }, HOOD_OK);
    assert_eq!(bits(&y), bits(&x));
    let mut y = start.clone();
    let mut unpinned = start.clone();
    let unpinned_moved = hood::solve::push_out_of(&mesh, &sc.body, &mut unpinned, &[]).unwrap();
    assert_eq!(push_out(&bd, &mut y, null(), &mut moved), HOOD_OK);
    assert_eq!((bits(&y), moved), (bits(&unpinned), unpinned_moved));
    assert!(moved > changed && (0..n).all(|i| !inside(&y, i)), "the pinned vertex inside moves too");
    // Zero vertices: nothing to do.
    // SAFETY: zero points at a valid address.
    assert_eq!(unsafe { hood_garment_push_out(&bd, y.as_mut_ptr().cast(), 0, null(), &mut moved) }, HOOD_OK);
    assert_eq!(moved, 0);
}

#[test]
fn garment_push_out_refuses_bad_input_and_writes_nothing() {
    let sc = scene(9);
    let bd = sc.body_desc();
    let (start, pinned) = cloth_in_body(&sc);
    let n = start.len();
    // Calls on a copy of the cloth; a refusal must leave it and `moved` alone.
    let call = |body: *const hood_body_desc, x: &mut [[f32; 3]], pinned: *const u8| {
        let before = bits(x);
        let mut moved = usize::MAX;
        let s = push_out(body, x, pinned, &mut moved);
        if s != HOOD_OK {
            assert_eq!(bits(x), before, "positions written on error ({s})");
            assert_eq!(moved, usize::MAX, "moved written on error ({s})");
        }
        s
    };
    let fresh = || start.clone();
    assert_eq!(call(&bd, &mut fresh(), pinned.as_ptr()), HOOD_OK, "{}", last_error());
    // NULL pointers.
    assert_eq!(call(null(), &mut fresh(), null()), HOOD_ERR_NULL_POINTER);
    let mut moved = 7usize;
    // SAFETY: NULL positions are what the library must catch.
    assert_eq!(unsafe { hood_garment_push_out(&bd, null_mut(), n, null(), &mut moved) }, HOOD_ERR_NULL_POINTER);
    assert_eq!(moved, 7);
    for b in [hood_body_desc { positions: null(), ..bd }, hood_body_desc { indices: null(), ..bd }] {
        assert_eq!(call(&b, &mut fresh(), null()), HOOD_ERR_NULL_POINTER);
        assert!(last_error().contains("body"), "{}", last_error());
    }
    // Wrong sizes: struct_size, faces naming vertices past n_vertices, no faces, an absurd count.
    check_struct_size_rule(bd, size_of::<hood_body_desc>(), |b| call(b, &mut fresh(), null()));
    assert_eq!(call(&hood_body_desc { n_vertices: 10, ..bd }, &mut fresh(), null()), HOOD_ERR_INDEX_OUT_OF_RANGE);
    assert_eq!(call(&hood_body_desc { n_faces: 0, ..bd }, &mut fresh(), null()), HOOD_ERR_EMPTY);
    let mut x = fresh();
    // SAFETY: refused before the count is used to read (beyond the vertex limit).
    let s = unsafe { hood_garment_push_out(&bd, x.as_mut_ptr().cast(), usize::MAX / 4, null(), &mut moved) };
    assert_eq!(s, HOOD_ERR_CAPACITY_EXCEEDED, "{}", last_error());
    assert_eq!((bits(&x), moved), (bits(&start), 7));
    // Non-finite garment positions (a pinned one too) and body positions.
    for (i, v) in [(5, f32::NAN), (0, f32::INFINITY), (n - 1, f32::NEG_INFINITY)] {
        let mut x = fresh();
        x[i][1] = v;
        assert_eq!(call(&bd, &mut x, pinned.as_ptr()), HOOD_ERR_NON_FINITE);
        assert!(last_error().contains(&format!("garment position {i}")), "{}", last_error());
    }
    let mut body = sc.body.clone();
    body[3][2] = f32::NAN;
    let nan_body = common::body_desc(&body, &sc.body_faces);
    assert_eq!(call(&nan_body, &mut fresh(), null()), HOOD_ERR_NON_FINITE);
    assert!(last_error().contains("body vertex 3"), "{}", last_error());
    // A body wound inside out would push the cloth into it.
    let flipped: Vec<[u32; 3]> = sc.body_faces.iter().map(|f| [f[0], f[2], f[1]]).collect();
    let inside_out = hood_body_desc { indices: flipped.as_ptr().cast(), ..bd };
    assert_eq!(call(&inside_out, &mut fresh(), null()), HOOD_ERR_INSIDE_OUT);
    // The in/out array overlapping an input, or misaligned.
    let mut body = sc.body.clone();
    let aliased = common::body_desc(&body, &sc.body_faces);
    assert_eq!(call(&aliased, &mut body[2..2 + n.min(20)], null()), HOOD_ERR_BAD_POINTER);
    let mut x = fresh();
    let flags = x.as_ptr().cast::<u8>();
    assert_eq!(call(&bd, &mut x, flags), HOOD_ERR_BAD_POINTER);
    let mut raw = vec![0.0f32; 3 * n + 1];
    let odd = raw.as_mut_ptr().cast::<u8>().wrapping_add(1).cast::<f32>();
    // SAFETY: refused before `odd` is read (misaligned).
    assert_eq!(unsafe { hood_garment_push_out(&bd, odd, n, null(), &mut moved) }, HOOD_ERR_BAD_POINTER);
    assert!(raw.iter().all(|&v| v == 0.0) && moved == 7);
}

/// The calls that place the garment without a step: a teleport reads as a teleported step;
/// a reset or a loaded state as no step yet; refused, they leave the flags.
#[test]
fn last_effects_after_teleport_reset_and_load_state() {
    let l = load(8, 21);
    let sc = scene(5);
    let n = sc.rest.len();
    let mut out = vec![[0.0f32; 3]; n];
    let sim = sim_with(&sc, l.model, |_| {});
    let still = sc.body_at(0, [0.0; 3]);
    assert_eq!(step(sim, &still, &mut out), HOOD_OK);
    assert_eq!(last_effects(sim), HOOD_STEP_STARTUP);
    let mut len = 0usize;
    // SAFETY: a live sim; writable out.
    assert_eq!(unsafe { hood_sim_state_size(sim, &mut len) }, HOOD_OK);
    let mut saved = vec![0u8; len];
    // SAFETY: `len` writable bytes.
    assert_eq!(unsafe { hood_sim_save_state(sim, saved.as_mut_ptr(), len) }, HOOD_OK);
    let t = [0.5f32, 0.0, 0.0];
    let bad_rotation = [2.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    // SAFETY: a live sim; 9 and 3 floats; NULL body with 0 keeps the current one (moved).
    unsafe {
        assert_eq!(hood_sim_teleport(sim, null(), t.as_ptr(), null(), 0), HOOD_OK, "{}", last_error());
        assert_eq!(last_effects(sim), HOOD_STEP_TELEPORTED);
        assert_eq!(step(sim, &sc.body_at(0, t), &mut out), HOOD_OK);
        assert_eq!(last_effects(sim), 0, "a plain step after the teleport");
        assert_eq!(hood_sim_teleport(sim, bad_rotation.as_ptr(), null(), null(), 0), HOOD_ERR_OUT_OF_RANGE);
        assert_eq!(last_effects(sim), 0, "a refused teleport leaves the flags");
        assert_eq!(hood_sim_teleport(sim, null(), t.as_ptr(), null(), 0), HOOD_OK);
        // A refused load leaves the flags; a load clears them.
        assert_eq!(hood_sim_load_state(sim, saved.as_ptr(), len - 1), HOOD_ERR_CORRUPT_DATA);
        assert_eq!(last_effects(sim), HOOD_STEP_TELEPORTED);
        assert_eq!(hood_sim_load_state(sim, saved.as_ptr(), len), HOOD_OK, "{}", last_error());
        assert_eq!(last_effects(sim), 0);
        // A reset likewise (after an automatic teleport, a jump of a metre).
        assert_eq!(step(sim, &sc.body_at(1, [1.0, 0.0, 0.0]), &mut out), HOOD_OK);
        assert_eq!(last_effects(sim), HOOD_STEP_TELEPORTED);
        let mut nan = sc.rest.clone();
        nan[2][0] = f32::NAN;
        assert_eq!(hood_sim_reset(sim, nan.as_ptr().cast(), n, null(), 0), HOOD_ERR_NON_FINITE);
        assert_eq!(last_effects(sim), HOOD_STEP_TELEPORTED);
        assert_eq!(hood_sim_reset(sim, sc.rest.as_ptr().cast(), n, still.as_ptr().cast(), still.len()), HOOD_OK);
        assert_eq!(last_effects(sim), 0);
        // The reset sim starts over: its next step runs the start-up pass again.
        assert_eq!(step(sim, &still, &mut out), HOOD_OK);
        assert_eq!(last_effects(sim), HOOD_STEP_STARTUP);
        assert_eq!(hood_sim_free(sim), HOOD_OK);
    }
}
