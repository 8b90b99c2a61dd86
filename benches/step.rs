//! Step latency (criterion): workloads x model sizes x precision x threads, the solver step mode
//! on one and two threads, and the cost of each effect. `hood bench` prints the same measurements with FLOP counts and efficiency.

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, BenchmarkGroup, BenchmarkId, Criterion, SamplingMode};
use hood::model::{write_model, ModelBytes, ModelSpec, Params};
use hood::sim::{BodyDesc, Precision, Sim, SimConfig, SimState, DEFAULT_SOLVER_ITERATIONS};
use hood::workloads::{workload, Workload};
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
    let cfg = cfg.with_startup(w.startup());
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

/// One timed step: the workload's own start state, pins and body frame (`Workload::prepare_step`),
/// except with body collision off, where the fixed state without its body is restored.
fn step_once(s: &mut Sim<'_>, state: &Option<SimState>, w: &Workload, t: usize) {
    let frame: &[[f32; 3]] = if s.config().body_collision {
        w.prepare_step(s, t).unwrap()
    } else {
        if let Some(st) = state {
            s.set_state(st).unwrap();
        }
        &[]
    };
    black_box(s.step(frame).unwrap());
}

/// Times steps of a sim of `w` with `cfg` as bench `id`.
fn time_steps(
    g: &mut BenchmarkGroup<'_, WallTime>,
    id: BenchmarkId,
    w: &Workload,
    model: &hood::model::Model<'_>,
    cfg: SimConfig,
) {
    let (mut s, st) = sim(w, model, cfg);
    let mut t = 0;
    g.bench_function(id, |b| {
        b.iter(|| {
            t += 1;
            step_once(&mut s, &st, w, t)
        })
    });
}

/// `(latent, precision, threads)` timed per workload: everything on the small ones; on the walk
/// workloads (seconds per step) h = 128 in full and the smaller models at 2 threads only.
fn matrix(name: &str) -> Vec<(usize, Precision, usize)> {
    let mut m = Vec::new();
    for h in [128, 64, 32] {
        for precision in [Precision::F32, Precision::Bf16] {
            for threads in [1, 2] {
                let full = h == 128 || matches!(name, "grid-1k" | "tee");
                let wanted = match name {
                    "dress-12k" => h == 128 || (threads == 2 && precision == Precision::F32),
                    _ => full || threads == 2,
                };
                if wanted {
                    m.push((h, precision, threads));
                }
            }
        }
    }
    m
}

fn bench_step(c: &mut Criterion) {
    // Without an assets folder the asset workloads are skipped.
    let shared = hood::assets::locate(None).unwrap_or_default();
    let mut g = c.benchmark_group("step");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(5));
    for name in ["grid-1k", "skirt-4k", "dress-12k", "tee"] {
        let w = match workload(name, &shared) {
            Ok(w) => w,
            Err(e) => {
                eprintln!("step/{name}: skipped ({e})");
                continue;
            }
        };
        // Steps of the walk workloads take seconds: one step per sample.
        g.sampling_mode(if w.worn.is_some() { SamplingMode::Flat } else { SamplingMode::Auto });
        let mut last_h = 0;
        let mut bytes = random_model(128);
        for (h, precision, threads) in matrix(name) {
            if h != last_h {
                bytes = random_model(h);
                last_h = h;
            }
            let model = bytes.model().unwrap();
            let p = if precision == Precision::Bf16 { "bf16" } else { "f32" };
            let id = BenchmarkId::new(format!("{name}/h{h}/{p}"), format!("{threads}t"));
            time_steps(&mut g, id, &w, &model, SimConfig::network().with_precision(precision).with_threads(threads));
        }
        // The default step mode, the solver (the model is not run), on one and two threads.
        let model = bytes.model().unwrap();
        for threads in [1, 2] {
            let id = BenchmarkId::new(format!("{name}/solver{DEFAULT_SOLVER_ITERATIONS}"), format!("{threads}t"));
            time_steps(&mut g, id, &w, &model, SimConfig::default().with_threads(threads));
        }
    }
    g.finish();
}

fn bench_effects(c: &mut Criterion) {
    let Ok(w) = workload("tee", &hood::assets::locate(None).unwrap_or_default()) else {
        eprintln!("effects: skipped (the fixture scene is absent)");
        return;
    };
    let bytes = random_model(32);
    let model = bytes.model().unwrap();
    let mut g = c.benchmark_group("effects");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
    let base = SimConfig::network();
    for (label, cfg) in [
        ("all-off", base.with_body_collision(false).with_pinning(false)),
        ("body", base),
        ("body+normals", base.with_normals(true)),
        ("body+sleeping", base.with_sleeping(Some(Default::default()))),
        ("body+projection", base.with_projection(Some(hood::sim::DEFAULT_PROJECTION_MARGIN))),
        ("body+tether", base.with_tether(Some(hood::sim::DEFAULT_TETHER_SLACK))),
        ("body+refine 3", base.with_refine(Some(3))),
        ("body+refine 10", base.with_refine(Some(10))),
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
