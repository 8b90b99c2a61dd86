//! The C ABI's garment and body constructors with arbitrary arrays (NaN, huge and negative
//! coordinates, out-of-range indices, bad materials, absurd counts over small arrays), then a
//! sim of what was accepted, stepped once, and the body's push-out. Every call must return a
//! status; `HOOD_ERR_PANIC` (a panic caught at the boundary) is a bug.

use super::common::{tiny, Bytes};
use hood_ffi::*;
use std::ptr::{null, null_mut};
use std::sync::OnceLock;

/// The tiny model, loaded once through the C ABI (its bytes are static, so it may live forever).
fn model() -> *const hood_model {
    static MODEL: OnceLock<usize> = OnceLock::new();
    *MODEL.get_or_init(|| {
        let bytes = tiny().model.as_bytes();
        let mut m = null_mut();
        // SAFETY: aligned bytes of a static that outlives the model (never freed).
        let s = unsafe { hood_model_load(bytes.as_ptr(), bytes.len(), &mut m) };
        assert_eq!(s, HOOD_OK, "the tiny model loads");
        m as usize
    }) as *const hood_model
}

/// A status the C ABI may return: anything but a caught panic.
fn ok(s: hood_status, call: &str) -> hood_status {
    assert_ne!(s, HOOD_ERR_PANIC, "{call} panicked inside the library");
    s
}

/// Vertex counts past the limit over small arrays: the library must refuse them unread.
const ABSURD_VERTICES: [usize; 3] = [HOOD_MAX_VERTICES + 1, 100_000_000, usize::MAX / 4];
/// Face counts past the limit, likewise.
const ABSURD_FACES: [usize; 3] = [HOOD_MAX_FACES + 1, 100_000_000, usize::MAX / 4];

/// Arrays of a mesh read from the fuzz input, with the counts declared for them.
struct Mesh {
    positions: Vec<[f32; 3]>,
    faces: Vec<[u32; 3]>,
    flags: Vec<u8>,
    n_vertices: usize,
    n_faces: usize,
}

impl Mesh {
    fn read(b: &mut Bytes<'_>, max_vertices: u8, max_faces: u8) -> Mesh {
        let n = (b.u8() % max_vertices) as usize;
        let positions: Vec<[f32; 3]> = (0..n).map(|_| [b.coordinate(), b.coordinate(), b.coordinate()]).collect();
        let m = (b.u8() % max_faces) as usize;
        let faces = (0..m).map(|_| [b.index(n), b.index(n), b.index(n)]).collect();
        let flags = (0..n).map(|_| b.u8() & 1).collect();
        Mesh { positions, faces, flags, n_vertices: n, n_faces: m }
    }

    /// Declares an absurd vertex or face count (the arrays stay as they are).
    fn absurd(&mut self, which: u8) {
        let k = (which >> 1) as usize % 3;
        if which & 1 == 0 {
            self.n_vertices = ABSURD_VERTICES[k];
        } else {
            self.n_faces = ABSURD_FACES[k];
        }
    }

    fn is_absurd(&self) -> bool {
        self.n_vertices > HOOD_MAX_VERTICES || self.n_faces > HOOD_MAX_FACES
    }

    fn body_desc(&self, omitted: bool) -> hood_body_desc {
        hood_body_desc {
            struct_size: size_of::<hood_body_desc>() as u32,
            positions: self.positions.as_ptr().cast(),
            n_vertices: self.n_vertices,
            indices: self.faces.as_ptr().cast(),
            n_faces: self.n_faces,
            omitted: if omitted { self.flags.as_ptr() } else { null() },
        }
    }
}

/// See the module docs. Input layout: a flag byte, the garment (count, coordinates, faces,
/// pinned flags), materials, the body likewise, the config's effects and thread count.
pub fn mesh(data: &[u8]) {
    let mut b = Bytes::new(data);
    let flags = b.u8();
    let mut garment = Mesh::read(&mut b, 48, 80);
    let materials: Vec<hood_material> = match b.u8() % 3 {
        0 => Vec::new(),
        k => (0..if k == 1 { 1 } else { garment.n_vertices })
            .map(|_| hood_material {
                struct_size: size_of::<hood_material>() as u32,
                density: b.coordinate(),
                mu: b.coordinate() * 1e4,
                lambda: b.coordinate() * 1e4,
                bending: b.coordinate() * 1e-5,
            })
            .collect(),
    };
    let mut body = Mesh::read(&mut b, 64, 120);
    if flags & 1 != 0 {
        garment.absurd(b.u8());
    }
    if flags & 2 != 0 {
        body.absurd(b.u8());
    }
    let effects = b.u32() & (HOOD_EFFECT_REFINE * 2 - 1);
    let threads = (b.u8() % 4) as u32;
    let pinned = if flags & 4 != 0 { garment.flags.as_ptr() } else { null() };
    let mut g = null_mut();
    // SAFETY: every array holds its declared count, except absurd counts, which the library
    // refuses before reading (what this target checks, under the sanitizer).
    let s = unsafe {
        hood_garment_new(
            garment.positions.as_ptr().cast(),
            garment.n_vertices,
            garment.faces.as_ptr().cast(),
            garment.n_faces,
            if materials.is_empty() { null() } else { materials.as_ptr() },
            materials.len(),
            pinned,
            &mut g,
        )
    };
    ok(s, "hood_garment_new");
    if garment.is_absurd() {
        assert_eq!(s, HOOD_ERR_CAPACITY_EXCEEDED, "an absurd garment was not refused as such");
    }
    let desc = body.body_desc(flags & 8 != 0);
    if s == HOOD_OK {
        let mut cfg = std::mem::MaybeUninit::<hood_sim_config>::zeroed();
        // SAFETY: writable; the library fills every field.
        let mut cfg = unsafe {
            hood_sim_config_default(cfg.as_mut_ptr());
            cfg.assume_init()
        };
        cfg.effects = effects;
        cfg.threads = threads;
        cfg.refine_iterations = 2;
        cfg.solver_iterations = if flags & 16 != 0 { 3 } else { 0 };
        let mut sim = null_mut();
        let body_arg = if flags & 32 != 0 { null() } else { &desc as *const hood_body_desc };
        // SAFETY: live handles; the descriptor's arrays hold their counts (or are absurd, see above).
        let s = ok(unsafe { hood_sim_new(model(), g, body_arg, &cfg, &mut sim) }, "hood_sim_new");
        if !body_arg.is_null() && body.is_absurd() {
            assert_eq!(s, HOOD_ERR_CAPACITY_EXCEEDED, "an absurd body was not refused as such");
        }
        if s == HOOD_OK {
            let n = garment.n_vertices;
            let mut out = vec![[0.0f32; 3]; n];
            let nb = if body_arg.is_null() { 0 } else { body.n_vertices };
            // SAFETY: a live sim; the body array holds `nb` points, `out` holds `n`.
            unsafe {
                ok(hood_sim_step(sim, body.positions.as_ptr().cast(), nb, out.as_mut_ptr().cast(), n), "hood_sim_step");
                assert_eq!(hood_sim_free(sim), HOOD_OK);
            }
        }
        // SAFETY: a live garment.
        assert_eq!(unsafe { hood_garment_free(g) }, HOOD_OK);
    }
    let mut positions = garment.positions.clone();
    let mut moved = 0usize;
    // SAFETY: `positions` holds its count (absurd garment counts are not passed here); the body
    // descriptor as above.
    let s = unsafe { hood_garment_push_out(&desc, positions.as_mut_ptr().cast(), positions.len(), pinned, &mut moved) };
    ok(s, "hood_garment_push_out");
    if body.is_absurd() {
        assert_eq!(s, HOOD_ERR_CAPACITY_EXCEEDED, "an absurd body was not refused as such");
    }
}
