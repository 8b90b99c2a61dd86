//! `Sim::step` never allocates: a counting global allocator over every combination of effects,
//! precisions and thread settings; nor does an outfit's step, nor do the body queries. Their own
//! test binary, with a single test that runs the checks in turn: no other test may run beside a
//! counting window, since the harness allocates on its own threads when a test ends (it copies
//! the test's captured output), which two tests in this file running side by side once counted
//! as the body queries'.

mod common;
use common::*;
use hood::sim::{BodyDesc, Precision, Sim, SimConfig, Sleeping, StepMode};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

struct Counting;
static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
static TRACE: AtomicBool = AtomicBool::new(false);

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
            // Set HOOD_ALLOC_TRACE to see where the first allocation comes from.
            if TRACE.load(Ordering::Relaxed) && COUNTING.swap(false, Ordering::SeqCst) {
                eprintln!("allocation of {} bytes at:\n{}", layout.size(), std::backtrace::Backtrace::force_capture());
            }
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn alloc_free_step_and_body_queries() {
    step_every_effect_precision_and_thread_count();
    outfit_step();
    body_queries();
}

/// Garments of every step mode on one body, stepped together through their shared body query.
fn outfit_step() {
    use hood::sim::Outfit;
    let scene = Scene::new(12, 10);
    let bytes = random_model(16, 2, false);
    let model = bytes.model().unwrap();
    let configs = [
        SimConfig::network().with_refine(Some(2)).with_projection(Some(0.004)).with_normals(true),
        SimConfig::network().with_step(StepMode::Solver { iterations: 4 }).with_threads(2),
        SimConfig::network().with_step(StepMode::SolverBudget { micros: 1_000_000, max_iterations: 4 }),
        SimConfig::network().with_threads(2),
    ];
    let sims = configs.iter().map(|&cfg| scene.sim(&model, cfg).unwrap()).collect();
    let mut outfit = Outfit::new(sims).unwrap();
    let frames: Vec<Vec<[f32; 3]>> = (1..6).map(|t| scene.body_at(t)).collect();
    outfit.step(&frames[0]).unwrap();
    COUNTING.store(true, Ordering::SeqCst);
    ALLOCATIONS.store(0, Ordering::SeqCst);
    for f in &frames[1..] {
        outfit.step(f).unwrap();
    }
    COUNTING.store(false, Ordering::SeqCst);
    let n = ALLOCATIONS.load(Ordering::SeqCst);
    assert_eq!(n, 0, "{n} allocations in 4 steps of an outfit");
}

fn step_every_effect_precision_and_thread_count() {
    TRACE.store(std::env::var_os("HOOD_ALLOC_TRACE").is_some(), Ordering::SeqCst);
    let scene = Scene::new(12, 10);
    let bytes = random_model(16, 1, true);
    let model = bytes.model().unwrap();
    let mut combos = 0;
    for body in [true, false] {
        for pinning in [true, false] {
            for normals in [true, false] {
                for sleeping in [None, Some(Sleeping::default())] {
                    for precision in [Precision::F32, Precision::Bf16] {
                        for (threads, step) in [
                            (1, StepMode::Network),
                            (2, StepMode::Network),
                            (1, StepMode::Solver { iterations: 4 }),
                            (2, StepMode::Solver { iterations: 4 }),
                            (1, StepMode::SolverBudget { micros: 1_000_000, max_iterations: 4 }),
                        ] {
                            let network = step == StepMode::Network;
                            let cfg = SimConfig::network()
                                .with_body_collision(body)
                                .with_pinning(pinning)
                                .with_normals(normals)
                                .with_sleeping(sleeping)
                                .with_precision(precision)
                                .with_threads(threads)
                                // Collision projection and tethers (both need the body) ride
                                // with the normals, solver refinement with the sleeping, which
                                // keeps the combinations few.
                                .with_projection((body && normals).then_some(0.004))
                                .with_tether((body && normals).then_some(0.0))
                                .with_refine(sleeping.filter(|_| network).map(|_| 3))
                                .with_step(step);
                            let b0 = scene.body_at(0);
                            let desc = BodyDesc { mesh: &scene.body, positions: &b0 };
                            let mut sim = Sim::new(&model, &scene.garment, body.then_some(desc), cfg).unwrap();
                            // Buffers the caller owns are made before counting starts.
                            let frames: Vec<Vec<[f32; 3]>> = (1..6).map(|t| scene.body_at(t)).collect();
                            // The first step (with the start-up pass, and the solver's first
                            // preconditioner) allocates nothing either.
                            COUNTING.store(true, Ordering::SeqCst);
                            ALLOCATIONS.store(0, Ordering::SeqCst);
                            sim.step(&frames[0]).unwrap();
                            COUNTING.store(false, Ordering::SeqCst);
                            let n = ALLOCATIONS.load(Ordering::SeqCst);
                            assert_eq!(n, 0, "{n} allocations in the first step with {cfg:?}");
                            let placed = sim.state().clone();
                            COUNTING.store(true, Ordering::SeqCst);
                            let mut pulled = false;
                            ALLOCATIONS.store(0, Ordering::SeqCst);
                            for (i, f) in frames[1..].iter().enumerate() {
                                if i == 2 && cfg.tether.is_some() {
                                    // A new placement: the next step ties the tethers again.
                                    sim.set_state(&placed).unwrap();
                                }
                                sim.step(f).unwrap();
                                pulled |= sim.last_tethered() > 0;
                            }
                            COUNTING.store(false, Ordering::SeqCst);
                            let n = ALLOCATIONS.load(Ordering::SeqCst);
                            assert_eq!(n, 0, "{n} allocations in 4 steps with {cfg:?}");
                            // Tethers without slack pull (and the cloth follows) in those steps.
                            assert_eq!(pulled, cfg.tether.is_some(), "tethers pulled: {cfg:?}");
                            combos += 1;
                        }
                    }
                }
            }
        }
    }
    println!("{combos} configurations stepped without allocating");
}

/// The body queries after set-up: the frame's update, the whole query in one job, the separate
/// batch queries, serial and on a thread pool.
fn body_queries() {
    use hood::body::{BodyFrame, GarmentQuery, Nearest};
    use hood::sim::{Executor, Serial, ThreadPool};
    let scene = Scene::new(40, 40);
    let garment = scene.garment.rest();
    let n = garment.len();
    let pool = ThreadPool::new(2);
    let frames: Vec<Vec<[f32; 3]>> = (0..4).map(|t| scene.body_at(t)).collect();
    for (name, exec) in [("serial", &Serial as &dyn Executor), ("a 2-thread pool", &pool)] {
        let mut frame = BodyFrame::new(&scene.body).unwrap();
        let (mut edges, mut faces) = (vec![None; n], vec![Nearest { index: 0, distance: 0.0 }; n]);
        let (mut vertex_hints, mut face_hints) = (vec![u32::MAX; n], vec![0u32; n]);
        let mut kept = 0;
        COUNTING.store(true, Ordering::SeqCst);
        ALLOCATIONS.store(0, Ordering::SeqCst);
        for f in &frames {
            frame.update(&scene.body, f).unwrap();
            frame.body_edges_on(exec, &scene.body, garment, 0.05, &vertex_hints, &mut edges).unwrap();
            frame.nearest_faces_on(exec, garment, &face_hints, &mut faces).unwrap();
            let query =
                GarmentQuery { points: garment, radius: 0.05, vertex_hints: &vertex_hints, face_hints: &face_hints };
            kept += frame.update_and_query_on(exec, &scene.body, f, query, &mut edges, &mut faces).unwrap();
            for (h, e) in vertex_hints.iter_mut().zip(&edges) {
                *h = e.map_or(u32::MAX, |e| e.index);
            }
            for (h, f) in face_hints.iter_mut().zip(&faces) {
                *h = f.index;
            }
        }
        COUNTING.store(false, Ordering::SeqCst);
        let allocations = ALLOCATIONS.load(Ordering::SeqCst);
        assert_eq!(allocations, 0, "{allocations} allocations in the body queries on {name}");
        assert!(kept > 0, "the garment must come near the body");
    }
}
