//! Bodies in motion (criterion): diffused skinning weights for a ~5k-vertex garment (the
//! supplement's M = 10,000 samples) and skinning the procedural mannequin.

use criterion::{criterion_group, criterion_main, Criterion};
use hood::rig::fit::{diffused_weights, DIFFUSION_SAMPLES};
use hood::rig::procedural::{long_dress, Mannequin};
use std::hint::black_box;
use std::time::Duration;

fn bench_rig(c: &mut Criterion) {
    let m = Mannequin::new();
    let dress = long_dress(&m, 5000).unwrap();
    let mut g = c.benchmark_group("rig");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(8));
    let name = format!("diffused_weights/dress_{}v/M{}", dress.rest.len(), DIFFUSION_SAMPLES);
    g.bench_function(name, |b| {
        b.iter(|| black_box(diffused_weights(&dress.rest, m.rest(), m.weights(), DIFFUSION_SAMPLES, 0.01, 1).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench_rig);
criterion_main!(benches);
