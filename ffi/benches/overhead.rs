//! The C ABI's cost on a step: `hood_sim_step` (handle check and claim, argument checks, the
//! copy into the caller's array) against `Sim::step` on the same small garment, body and model.
//! Both restart every timed step from the same saved state (outside the timing).

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use hood::body::BodyMesh;
use hood::mesh::{Garment, GarmentDesc};
use hood::model::ModelBytes;
use hood::sim::{BodyDesc, Sim, SimConfig};
use hood_ffi::*;
use std::hint::black_box;
use std::ptr::{null, null_mut};
use std::time::{Duration, Instant};

fn overhead(c: &mut Criterion) {
    let bytes = ModelBytes::new(&common::random_model_bytes(16, 7));
    let model = bytes.model().unwrap();
    let (rest, faces) = hood::mesh::shapes::grid(8, 8, 0.5, 0.5, 0.32);
    let mut pinned = vec![false; rest.len()];
    pinned[0] = true;
    pinned[7] = true;
    let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
    let (body, body_faces) = hood::body::shapes::ellipsoid(12, 16, [0.25, 0.3, 0.25], [0.0; 3]);
    let mesh = BodyMesh::new(body.len(), &body_faces).unwrap();
    let next: Vec<[f32; 3]> = body.iter().map(|p| [p[0] + 0.01, p[1], p[2]]).collect();
    let n = rest.len();

    // Rust: one step to leave the start-up behind, then every timed step from that state. The
    // default config on both sides (the C side's NULL config is the same).
    let mut sim =
        Sim::new(&model, &garment, Some(BodyDesc { mesh: &mesh, positions: &body }), SimConfig::default()).unwrap();
    sim.step(&body).unwrap();
    let start = sim.state().clone();

    // C: the same scene through the exported functions.
    let mut h_model = null_mut();
    let mut h_garment = null_mut();
    let mut h_sim = null_mut();
    let pins: Vec<u8> = pinned.iter().map(|&p| p as u8).collect();
    let desc = common::body_desc(&body, &body_faces);
    let mut out = vec![[0.0f32; 3]; n];
    let mut saved = Vec::new();
    // SAFETY: arrays of the stated lengths; `bytes` outlives the model (freed below).
    unsafe {
        let b = bytes.as_bytes();
        assert_eq!(hood_model_load(b.as_ptr(), b.len(), &mut h_model), HOOD_OK);
        let (r, f) = (rest.as_ptr().cast(), faces.as_ptr().cast());
        assert_eq!(hood_garment_new(r, n, f, faces.len(), null(), 0, pins.as_ptr(), &mut h_garment), HOOD_OK);
        assert_eq!(hood_sim_new(h_model, h_garment, &desc, null(), &mut h_sim), HOOD_OK);
        assert_eq!(hood_sim_step(h_sim, body.as_ptr().cast(), body.len(), out.as_mut_ptr().cast(), n), HOOD_OK);
        let mut len = 0;
        assert_eq!(hood_sim_state_size(h_sim, &mut len), HOOD_OK);
        saved.resize(len, 0u8);
        assert_eq!(hood_sim_save_state(h_sim, saved.as_mut_ptr(), len), HOOD_OK);
    }

    let mut g = c.benchmark_group("ffi_step_8x8");
    g.bench_function("rust_sim_step", |bch| {
        bch.iter_custom(|iters| {
            timed(
                iters,
                &mut sim,
                |s| s.set_state(&start).unwrap(),
                |s| {
                    black_box(s.step(black_box(&next)).unwrap());
                },
            )
        })
    });
    g.bench_function("c_hood_sim_step", |bch| {
        bch.iter_custom(|iters| {
            timed(
                iters,
                &mut out,
                // SAFETY: a live sim; `saved` holds its state.
                |_| assert_eq!(unsafe { hood_sim_load_state(h_sim, saved.as_ptr(), saved.len()) }, HOOD_OK),
                |out| {
                    // SAFETY: arrays of the stated lengths.
                    let s = unsafe {
                        hood_sim_step(black_box(h_sim), next.as_ptr().cast(), next.len(), out.as_mut_ptr().cast(), n)
                    };
                    assert_eq!(s, HOOD_OK);
                },
            )
        })
    });
    g.finish();
    // SAFETY: live handles, freed once.
    unsafe {
        assert_eq!(hood_sim_free(h_sim), HOOD_OK);
        assert_eq!(hood_garment_free(h_garment), HOOD_OK);
        assert_eq!(hood_model_free(h_model), HOOD_OK);
    }
}

/// Total time of `iters` runs of `step` on `x`, each after an untimed `restore`.
fn timed<X>(iters: u64, x: &mut X, mut restore: impl FnMut(&mut X), mut step: impl FnMut(&mut X)) -> Duration {
    let mut total = Duration::ZERO;
    for _ in 0..iters {
        restore(x);
        let t = Instant::now();
        step(x);
        total += t.elapsed();
    }
    total
}

criterion_group!(benches, overhead);
criterion_main!(benches);
