//! Step latency (criterion): workloads x model sizes x precision x threads, and the cost of each
//! effect. `hood bench` prints the same measurements with FLOP counts and efficiency.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hood::model::{write_model, ModelBytes, ModelSpec, Params};
use hood::sim::{BodyDesc, Precision, Sim, SimConfig, SimState};
use hood::workloads::{default_shared_dir, workload, Workload};
use std::hint::black_box;
use std::time::Duration;

fn random_model(h: usize) -> ModelBytes {
    let mut p = Params::init(&ModelSpec::hood(h), 0).unwrap();
    p.normalisers = hood::model::Normalisers::unit_scale(1);
    ModelBytes::new(&write_model(&p, true, &[]).unwrap())
}

/// A sim for `w` and the state every timed step restarts from (if the workload fixes one).
fn sim<'m>(w: &Workload, model: &'m hood::model::Model<'m>, cfg: SimConfig) -> (Sim<'m>, Option<SimState>) {
    let body = w.body.as_ref().map(|(mesh, frames)| BodyDesc { mesh, positions: &frames[0] });
    let cfg = SimConfig { startup: w.fixed_state.is_none(), ..cfg };
    let mut s = match &w.graph {
        Some(g) => Sim::with_graph(model, &w.garment, g.clone(), body, cfg).unwrap(),
        None => Sim::new(model, &w.garment, body, cfg).unwrap(),
    };
    let state = w.fixed_state.clone().map(|mut st| {
        if !cfg.body_collision {
            st.body_prev.clear();
            st.body_pos.clear();
        }
        st
    });
    if let Some(st) = &state {
        s.set_state(st).unwrap();
    }
    (s, state)
}

fn step_once(s: &mut Sim<'_>, state: &Option<SimState>, w: &Workload, t: usize) {
    if let Some(st) = state {
        s.set_state(st).unwrap();
    }
    let frame: &[[f32; 3]] = match &w.body {
        Some((_, frames)) if s.config().body_collision => &frames[1 + t % (frames.len() - 1)],
        _ => &[],
    };
    black_box(s.step(frame).unwrap());
}

fn bench_step(c: &mut Criterion) {
    let shared = default_shared_dir();
    let mut g = c.benchmark_group("step");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(5));
    for name in ["grid-1k", "tee"] {
        let Ok(w) = workload(name, &shared) else {
            eprintln!("step/{name}: skipped (its files are absent)");
            continue;
        };
        for h in [128, 64, 32] {
            let bytes = random_model(h);
            let model = bytes.model().unwrap();
            for (precision, p) in [(Precision::F32, "f32"), (Precision::Bf16, "bf16")] {
                for threads in [1, 2] {
                    let (mut s, st) = sim(&w, &model, SimConfig { precision, threads, ..SimConfig::default() });
                    let mut t = 0;
                    let id = BenchmarkId::new(format!("{name}/h{h}/{p}"), format!("{threads}t"));
                    g.bench_function(id, |b| {
                        b.iter(|| {
                            t += 1;
                            step_once(&mut s, &st, &w, t)
                        })
                    });
                }
            }
        }
    }
    g.finish();
}

fn bench_effects(c: &mut Criterion) {
    let Ok(w) = workload("tee", &default_shared_dir()) else {
        eprintln!("effects: skipped (the fixture scene is absent)");
        return;
    };
    let bytes = random_model(32);
    let model = bytes.model().unwrap();
    let mut g = c.benchmark_group("effects");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
    let base = SimConfig::default();
    for (label, cfg) in [
        ("all-off", SimConfig { body_collision: false, pinning: false, ..base }),
        ("body", base),
        ("body+normals", SimConfig { normals: true, ..base }),
        ("body+sleeping", SimConfig { sleeping: Some(Default::default()), ..base }),
    ] {
        let (mut s, st) = sim(&w, &model, cfg);
        let mut t = 0;
        g.bench_function(label, |b| {
            b.iter(|| {
                t += 1;
                step_once(&mut s, &st, &w, t)
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_step, bench_effects);
criterion_main!(benches);
