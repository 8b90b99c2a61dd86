//! The trainer's core: the differentiable forward against the runtime, the full gradient
//! against finite differences, the optimiser, and the step time on the fixture t-shirt.
#![cfg(feature = "train")]

mod common;
use common::*;
use hood::body::BodyMesh;
use hood::features::DT;
use hood::hierarchy::{Hierarchy, HierarchyConfig};
use hood::mesh::{Garment, GarmentDesc};
use hood::model::{ModelSpec, Params};
use hood::physics::{face_frames, Cloth, CollisionInput, CollisionParams, FaceFrame, Objective, StepInputs};
use hood::rng::Rng;
use hood::sim::{BodyDesc, Graph, Sim, SimConfig, SimState};
use hood::train::{BodyFrames, GarmentState, Network, Stats, StepData};

fn graph_of(garment: &Garment, levels: usize) -> Graph {
    let h = Hierarchy::build(garment, &HierarchyConfig::default().with_levels(levels)).unwrap();
    Graph::new(garment, &h).unwrap()
}

/// A start state near the rest shape: positions jittered by up to 5 mm, small velocities.
fn jittered(rest: &[[f32; 3]], rng: &mut Rng) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let pos = rest.iter().map(|p| p.map(|c| c + rng.uniform(-5e-3, 5e-3) as f32)).collect();
    let vel = rest.iter().map(|_| [0.0; 3].map(|_: f32| rng.uniform(-2e-3, 2e-3) as f32)).collect();
    (pos, vel)
}

#[test]
fn train_forward_matches_runtime() {
    let scene = Scene::new(14, 12);
    let bytes = random_model(16, 11, false);
    let model = bytes.model().unwrap();
    let params = model.to_params();
    let graph = graph_of(&scene.garment, params.spec.levels);
    let mut rng = Rng::new(7);
    let (pos, vel) = jittered(scene.garment.rest(), &mut rng);
    let (b0, b1, b2) = (scene.body_at(0), scene.body_at(1), scene.body_at(2));
    let cfg = SimConfig::network().with_startup(false);
    let mut sim = Sim::with_graph(
        &model,
        &scene.garment,
        graph.clone(),
        Some(BodyDesc { mesh: &scene.body, positions: &b0 }),
        cfg,
    )
    .unwrap();
    let state = SimState {
        pos: pos.clone(),
        velocity: vel.clone(),
        body_prev: b0.clone(),
        body_pos: b1.clone(),
        started: true,
    };
    sim.set_state(&state).unwrap();
    let expected = sim.step(&b2).unwrap().to_vec();

    let gs =
        GarmentState { pos: &pos, velocity: &vel, pinned: scene.garment.pinned(), pin_targets: scene.garment.rest() };
    let bf = BodyFrames { mesh: &scene.body, prev: &b0, pos: &b1, next: &b2 };
    let step = StepData::build(&params.spec, &scene.garment, &graph, &gs, Some(&bf), DT).unwrap();
    assert!(step.prefix[0] > 0 && step.prefix[1] > 0, "the scene must have body edges: {:?}", step.prefix);
    let net = Network::of(&params).unwrap();
    let theta = net.layout.flatten::<f32>(&params);
    let tape = net.forward(&theta, &Stats::of(&params), &graph, &step).unwrap();
    let mut worst = 0.0f32;
    let mut moved = 0.0f32;
    for ((a, b), p) in tape.new_pos.iter().zip(&expected).zip(&pos) {
        for k in 0..3 {
            worst = worst.max((a[k] - b[k]).abs());
            moved = moved.max((b[k] - p[k]).abs());
        }
    }
    assert!(worst < 1e-5, "largest position difference {worst} m");
    assert!(moved > 1e-4, "the step should move the garment ({moved} m)");
    // The f64 forward agrees too (same data path, other precision).
    let theta64 = net.layout.flatten::<f64>(&params);
    let t64 = net.forward(&theta64, &Stats::of(&params), &graph, &step).unwrap();
    let worst64 = t64
        .new_pos
        .iter()
        .zip(&expected)
        .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k] as f64).abs()))
        .fold(0.0, f64::max);
    assert!(worst64 < 1e-5, "f64 forward differs by {worst64} m");
}

/// Everything the objective reads for a step with a body, in f64.
struct Loss {
    cloth: Cloth<f64>,
    objective: Objective,
    pos: Vec<[f64; 3]>,
    vel: Vec<[f64; 3]>,
    nearest: Vec<u32>,
    centroids: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
}

impl Loss {
    fn new(garment: &Garment, body: &BodyMesh, cur: &[[f32; 3]], next: &[[f32; 3]], step: &StepData) -> Loss {
        let nf = body.n_faces();
        let (mut c0, mut n0) = (vec![[0.0f64; 3]; nf], vec![[0.0f64; 3]; nf]);
        face_frames(cur, body.faces(), &mut c0, &mut n0).unwrap();
        let nearest = step
            .pos
            .iter()
            .map(|p| {
                let d = |c: &[f64; 3]| (0..3).map(|k| (c[k] - p[k] as f64).powi(2)).sum::<f64>();
                (0..nf).min_by(|&a, &b| d(&c0[a]).total_cmp(&d(&c0[b]))).unwrap() as u32
            })
            .collect();
        let (mut centroids, mut normals) = (vec![[0.0f64; 3]; nf], vec![[0.0f64; 3]; nf]);
        face_frames(next, body.faces(), &mut centroids, &mut normals).unwrap();
        Loss {
            cloth: Cloth::new(garment),
            objective: Objective {
                collision: Some(CollisionParams::training(5e3)),
                friction: None,
                ..Objective::training(5e3)
            },
            pos: step.pos.iter().map(|p| p.map(f64::from)).collect(),
            vel: step.velocity.iter().map(|p| p.map(f64::from)).collect(),
            nearest,
            centroids,
            normals,
        }
    }

    fn eval(&self, x: &[[f64; 3]], grad: Option<&mut [[f64; 3]]>) -> (f64, f64) {
        let inputs = StepInputs {
            pos: &self.pos,
            velocity: &self.vel,
            dt: DT as f64,
            collision: Some(CollisionInput {
                nearest: &self.nearest,
                next: FaceFrame { centroids: &self.centroids, normals: &self.normals },
            }),
            friction: None,
        };
        let t = self.objective.eval(&self.cloth, &inputs, x, grad).unwrap();
        (t.total(), t.collision)
    }
}

#[test]
fn gradient_check_network() {
    let spec = ModelSpec::with_schedule(8, 2, 2, "f,c0 | d:c0,c1 | u:f,c0").unwrap();
    let mut params = Params::init(&spec, 21).unwrap();
    // A 10 x 10 cloth 1 mm above the top of an ellipsoid: body edges and an active collision term.
    let (rest, faces) = hood::mesh::shapes::grid(10, 10, 0.36, 0.36, 0.301);
    let mut pinned = vec![false; rest.len()];
    pinned[0] = true;
    let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
    let (bv, bf) = hood::body::shapes::ellipsoid(24, 32, [0.25, 0.3, 0.25], [0.0, 0.0, 0.0]);
    let body = BodyMesh::new(bv.len(), &bf).unwrap();
    let b_next: Vec<[f32; 3]> = bv.iter().map(|p| [p[0] + 0.004, p[1] + 0.002, p[2]]).collect();
    let graph = graph_of(&garment, 2);
    println!("coarse edges per level: {:?}", graph.coarse().iter().map(|c| c.edges.target.len()).collect::<Vec<_>>());
    assert!(graph.coarse().iter().all(|c| !c.edges.target.is_empty()), "every level needs edges");
    let mut rng = Rng::new(5);
    let (pos, vel) = jittered(&rest, &mut rng);
    let gs = GarmentState { pos: &pos, velocity: &vel, pinned: &pinned, pin_targets: &rest };
    let frames = BodyFrames { mesh: &body, prev: &bv, pos: &bv, next: &b_next };
    let step = StepData::build(&spec, &garment, &graph, &gs, Some(&frames), DT).unwrap();
    assert!(step.prefix[0] >= 4 && step.prefix[1] > 0, "body edges: {:?}", step.prefix);
    // Normalisers fitted to this step's features (node rows: unit scale, as the embeddings are).
    let n = &mut params.normalisers;
    n.node.accumulate(&(0..64 * 21).map(|_| rng.normal() as f32).collect::<Vec<_>>(), 21);
    n.node.accumulate(&step.node_features, 24);
    n.edge.accumulate(&step.edge_features[3], 12);
    n.body_edge.accumulate(&step.g2b_features, 9);
    n.body_edge.accumulate(&step.b2g_features, 9);
    n.output.accumulate(&(0..64 * 3).map(|_| (rng.normal() * 2e-3) as f32).collect::<Vec<_>>(), 3);
    let net = Network::of(&params).unwrap();
    let stats = Stats::<f64>::of(&params);
    let theta = net.layout.flatten::<f64>(&params);
    let loss = Loss::new(&garment, &body, &bv, &b_next, &step);
    let eval = |th: &[f64]| -> f64 {
        let t = net.forward(th, &stats, &graph, &step).unwrap();
        loss.eval(&t.new_pos, None).0
    };
    let tape = net.forward(&theta, &stats, &graph, &step).unwrap();
    let mut dx = vec![[0.0f64; 3]; rest.len()];
    let (l0, coll) = loss.eval(&tape.new_pos, Some(&mut dx));
    assert!(coll > 0.0, "the collision term must be active (loss {l0})");
    let mut grad = vec![0.0f64; theta.len()];
    net.backward(&theta, &stats, &graph, &step, &tape, &dx, &mut grad).unwrap();

    let tensors = net.layout.tensors(&spec);
    let mut checked = 0;
    let mut worst = (0.0f64, String::new());
    for (name, range) in &tensors {
        let g = &grad[range.clone()];
        let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(gmax > 0.0, "{name}: zero gradient");
        // The largest entry and two random entries of non-negligible size.
        let big: Vec<usize> = (0..g.len()).filter(|&i| g[i].abs() > 1e-2 * gmax).collect();
        let mut picks = vec![(0..g.len()).max_by(|&a, &b| g[a].abs().total_cmp(&g[b].abs())).unwrap()];
        for _ in 0..2 {
            picks.push(big[(rng.next_u64() % big.len() as u64) as usize]);
        }
        for &i in &picks {
            let at = range.start + i;
            let mut best = f64::INFINITY;
            // Round-off favours larger steps, a ReLU kink inside the interval smaller ones: try several.
            for step_rel in [1e-5, 1e-4, 1e-6, 1e-7] {
                let hstep = step_rel * theta[at].abs().max(1.0);
                let central = |hs: f64| {
                    let mut th = theta.clone();
                    th[at] = theta[at] + hs;
                    let lp = eval(&th);
                    th[at] = theta[at] - hs;
                    (lp - eval(&th)) / (2.0 * hs)
                };
                let (f1, f2) = (central(hstep), central(0.5 * hstep));
                // Richardson extrapolation removes the O(h²) truncation error.
                for fd in [f2, (4.0 * f2 - f1) / 3.0] {
                    best = best.min((fd - grad[at]).abs() / fd.abs().max(grad[at].abs()));
                }
                if best < 1e-6 {
                    break;
                }
            }
            assert!(best < 1e-5, "{name}[{i}]: analytic {} relative error {best:e}", grad[at]);
            if best > worst.0 {
                worst = (best, format!("{name}[{i}] (gradient {:e})", grad[at]));
            }
            checked += 1;
        }
    }
    println!(
        "gradient_check_network: loss {l0:e}, {checked} samples over {} tensors, worst {:e} at {}",
        tensors.len(),
        worst.0,
        worst.1
    );
}

/// Times one optimiser step (forward, objective, backward, clipping and Adam) in f32, single
/// thread, on the fixture t-shirt at h = 32, 64, 128 (run with `--ignored --nocapture`).
#[test]
#[ignore]
fn train_step_timing_tee() {
    use hood::body::{BodyFrame, Nearest};
    use hood::train::{clip_global_norm, learning_rate, Adam};
    use std::time::Instant;
    let w = match hood::workloads::workload("tee", &common::shared_dir().join("assets")) {
        Ok(w) => w,
        Err(e) => {
            println!("train_step_timing_tee: skipped ({e})");
            return;
        }
    };
    let (mesh, frames) = w.body.as_ref().unwrap();
    let state = w.fixed_state.clone().unwrap();
    let graph = w.graph.clone().unwrap();
    let garment = &w.garment;
    let n = garment.n_vertices();
    let reps = 3;
    let sizes: Vec<usize> = std::env::var("HOOD_TRAIN_SIZES")
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or(vec![32, 64, 128]);
    for h in sizes {
        let spec = ModelSpec::hood(h);
        let mut params = Params::init(&spec, 1).unwrap();
        // Step inputs and the objective's body data (per-sample preparation, timed apart).
        let t0 = Instant::now();
        let gs = GarmentState {
            pos: &state.pos,
            velocity: &state.velocity,
            pinned: garment.pinned(),
            pin_targets: garment.rest(),
        };
        let bf = BodyFrames { mesh, prev: &state.body_prev, pos: &state.body_pos, next: &frames[1] };
        let step = StepData::build(&spec, garment, &graph, &gs, Some(&bf), DT).unwrap();
        let mut cur = BodyFrame::new(mesh).unwrap();
        cur.update(mesh, &state.body_pos).unwrap();
        let mut nearest = vec![Nearest { index: 0, distance: 0.0 }; n];
        cur.nearest_faces(&step.pos, &mut nearest).unwrap();
        let nearest: Vec<u32> = nearest.iter().map(|q| q.index).collect();
        let nf = mesh.n_faces();
        let (mut centroids, mut normals) = (vec![[0.0f32; 3]; nf], vec![[0.0f32; 3]; nf]);
        face_frames(&frames[1], mesh.faces(), &mut centroids, &mut normals).unwrap();
        let prep = t0.elapsed().as_secs_f64();
        let nz = &mut params.normalisers;
        nz.node.accumulate(&step.node_features, 24);
        nz.edge.accumulate(&step.edge_features[3], 12);
        nz.body_edge.accumulate(&step.g2b_features, 9);
        nz.output.accumulate(&vec![1e-3f32; 64 * 3], 3);
        let net = Network::of(&params).unwrap();
        let stats = Stats::<f32>::of(&params);
        let mut theta = net.layout.flatten::<f32>(&params);
        let mut adam = Adam::new(theta.len());
        let cloth = Cloth::<f32>::new(garment);
        let objective = Objective { friction: None, ..Objective::training(5e3) };
        let inputs = StepInputs {
            pos: &step.pos,
            velocity: &step.velocity,
            dt: DT,
            collision: Some(CollisionInput {
                nearest: &nearest,
                next: FaceFrame { centroids: &centroids, normals: &normals },
            }),
            friction: None,
        };
        let mut best = [f64::INFINITY; 4];
        let mut dx = vec![[0.0f32; 3]; n];
        let mut grad = vec![0.0f32; theta.len()];
        let generic_reps = if std::env::var("HOOD_TRAIN_FAST_ONLY").is_ok() { 0 } else { reps };
        for _ in 0..generic_reps {
            let t = Instant::now();
            let tape = net.forward(&theta, &stats, &graph, &step).unwrap();
            let t_fwd = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let terms = objective.eval(&cloth, &inputs, &tape.new_pos, Some(&mut dx)).unwrap();
            let t_loss = t.elapsed().as_secs_f64();
            assert!(terms.total().is_finite());
            let t = Instant::now();
            grad.iter_mut().for_each(|g| *g = 0.0);
            net.backward(&theta, &stats, &graph, &step, &tape, &dx, &mut grad).unwrap();
            let t_bwd = t.elapsed().as_secs_f64();
            let t = Instant::now();
            clip_global_norm(&mut grad, 1.0);
            adam.step(&mut theta, &grad, learning_rate(adam.t));
            let t_adam = t.elapsed().as_secs_f64();
            for (b, x) in best.iter_mut().zip([t_fwd, t_loss, t_bwd, t_adam]) {
                *b = b.min(x);
            }
        }
        for threads in [1usize, 2] {
            let pool = hood::sim::ThreadPool::new(threads);
            let mut ws = hood::train::FastWorkspace::default();
            let mut fbest = [f64::INFINITY; 4];
            // CPU time of this thread (ns), to see through a busy machine.
            let cpu = || -> f64 {
                std::fs::read_to_string("/proc/thread-self/schedstat")
                    .ok()
                    .and_then(|s| s.split_whitespace().next().and_then(|x| x.parse::<f64>().ok()))
                    .unwrap_or(f64::NAN)
            };
            let mut cpu_best = f64::INFINITY;
            for _ in 0..reps + 2 {
                let c0 = cpu();
                let t = Instant::now();
                net.forward_fast(&mut ws, &pool, &theta, &stats, &graph, &step).unwrap();
                let t_fwd = t.elapsed().as_secs_f64();
                let t = Instant::now();
                let terms = objective.eval(&cloth, &inputs, &ws.new_pos, Some(&mut dx)).unwrap();
                let t_loss = t.elapsed().as_secs_f64();
                assert!(terms.total().is_finite());
                let t = Instant::now();
                grad.iter_mut().for_each(|g| *g = 0.0);
                net.backward_fast(&mut ws, &pool, &theta, &stats, &graph, &step, &dx, &mut grad).unwrap();
                let t_bwd = t.elapsed().as_secs_f64();
                let t = Instant::now();
                clip_global_norm(&mut grad, 1.0);
                adam.step(&mut theta, &grad, learning_rate(adam.t));
                let t_adam = t.elapsed().as_secs_f64();
                for (b, x) in fbest.iter_mut().zip([t_fwd, t_loss, t_bwd, t_adam]) {
                    *b = b.min(x);
                }
                cpu_best = cpu_best.min(cpu() - c0);
            }
            println!(
                "fast train step tee h={h}, {threads} threads: {:.1} ms (forward {:.1}, losses {:.2}, backward {:.1}, \
                 clip+adam {:.2}; calling thread's CPU time {:.1} ms)",
                fbest.iter().sum::<f64>() * 1e3,
                fbest[0] * 1e3,
                fbest[1] * 1e3,
                fbest[2] * 1e3,
                fbest[3] * 1e3,
                cpu_best * 1e-6
            );
        }
        let total: f64 = best.iter().sum();
        println!(
            "train step tee h={h}: {:.1} ms (forward {:.1}, losses {:.2}, backward {:.1}, clip+adam {:.2}; \
             step inputs {:.1} ms, not included), {} body edges, {} params",
            total * 1e3,
            best[0] * 1e3,
            best[1] * 1e3,
            best[2] * 1e3,
            best[3] * 1e3,
            prep * 1e3,
            step.prefix[0],
            theta.len()
        );
    }
}

/// The fast f32 path (SIMD products, workspace, executor) against the generic f32 path on a
/// hierarchical scene with body edges and pins, random non-zero parameters and a random
/// position gradient; one and two threads bitwise identical; scalar products agree too.
#[test]
fn train_fast_matches_generic() {
    use hood::sim::{Serial, ThreadPool};
    use hood::train::{FastWorkspace, Gemm};
    let spec = ModelSpec::with_schedule(16, 2, 2, "f,c0 | d:c0,c1 | u:f,c0").unwrap();
    let mut params = Params::init(&spec, 3).unwrap();
    let (rest, faces) = hood::mesh::shapes::grid(14, 12, 0.36, 0.36, 0.301);
    let mut pinned = vec![false; rest.len()];
    pinned[0] = true;
    pinned[13] = true;
    let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
    let (bv, bf) = hood::body::shapes::ellipsoid(24, 32, [0.25, 0.3, 0.25], [0.0, 0.0, 0.0]);
    let body = BodyMesh::new(bv.len(), &bf).unwrap();
    let b_next: Vec<[f32; 3]> = bv.iter().map(|p| [p[0] + 0.004, p[1] + 0.002, p[2]]).collect();
    let graph = graph_of(&garment, 2);
    let mut rng = Rng::new(9);
    let (pos, vel) = jittered(&rest, &mut rng);
    let gs = GarmentState { pos: &pos, velocity: &vel, pinned: &pinned, pin_targets: &rest };
    let frames = BodyFrames { mesh: &body, prev: &bv, pos: &bv, next: &b_next };
    let step = StepData::build(&spec, &garment, &graph, &gs, Some(&frames), DT).unwrap();
    assert!(step.prefix[0] >= 4 && step.prefix[1] > 0, "body edges: {:?}", step.prefix);
    let n = &mut params.normalisers;
    n.node.accumulate(&(0..64 * 21).map(|_| rng.normal() as f32).collect::<Vec<_>>(), 21);
    n.node.accumulate(&step.node_features, 24);
    n.edge.accumulate(&step.edge_features[3], 12);
    n.body_edge.accumulate(&step.g2b_features, 9);
    n.output.accumulate(&(0..64 * 3).map(|_| (rng.normal() * 2e-3) as f32).collect::<Vec<_>>(), 3);
    let net = Network::of(&params).unwrap();
    let stats = Stats::<f32>::of(&params);
    // Every parameter perturbed (LayerNorm gains away from 1, biases away from 0).
    let theta: Vec<f32> = net.layout.flatten::<f32>(&params).iter().map(|&t| t + 0.05 * rng.normal() as f32).collect();
    let dpos: Vec<[f32; 3]> = (0..rest.len()).map(|_| [0.0; 3].map(|_: f32| rng.normal() as f32)).collect();

    let tape = net.forward(&theta, &stats, &graph, &step).unwrap();
    let mut g_ref = vec![0.0f32; theta.len()];
    net.backward(&theta, &stats, &graph, &step, &tape, &dpos, &mut g_ref).unwrap();

    let pool = ThreadPool::new(2);
    let run = |ws: &mut FastWorkspace, exec: &dyn hood::sim::Executor| {
        net.forward_fast(ws, exec, &theta, &stats, &graph, &step).unwrap();
        let mut g = vec![0.0f32; theta.len()];
        net.backward_fast(ws, exec, &theta, &stats, &graph, &step, &dpos, &mut g).unwrap();
        (ws.new_pos.clone(), g)
    };
    let mut ws = FastWorkspace::new(Gemm::best());
    let (p1, g1) = run(&mut ws, &Serial);
    let (p2, g2) = run(&mut ws, &pool);
    assert!(p1 == p2 && g1 == g2, "one and two threads differ");
    let (p3, g3) = run(&mut FastWorkspace::new(Gemm::best()), &pool);
    assert!(p3 == p1 && g3 == g1, "a fresh workspace differs from a reused one");
    let (ps, gs_) = run(&mut FastWorkspace::new(Gemm::scalar()), &Serial);
    // The split-bf16 AMX path, on its software model of the tiles and, where this process may
    // use them, on the tiles themselves: thread counts agree bitwise, and the gradients are
    // within the same bound.
    #[allow(unused_mut)] // off x86-64 there is no tile path
    let mut tiles: Vec<(Vec<[f32; 3]>, Vec<f32>)> = Vec::new();
    #[cfg(target_arch = "x86_64")]
    for g in [Some(Gemm::tile_model()), Gemm::tiles()].into_iter().flatten() {
        let mut ws = FastWorkspace::new(g);
        let (pt, gt) = run(&mut ws, &Serial);
        assert!(run(&mut ws, &pool) == (pt.clone(), gt.clone()), "one and two threads differ on the tiles");
        tiles.push((pt, gt));
    }

    let pos_err = |p: &[[f32; 3]]| {
        p.iter().zip(&tape.new_pos).flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs())).fold(0.0f32, f32::max)
    };
    assert!(pos_err(&p1) < 1e-6 && pos_err(&ps) < 1e-6, "positions differ: {} {}", pos_err(&p1), pos_err(&ps));
    for (pt, _) in &tiles {
        assert!(pos_err(pt) < 1e-6, "positions differ on the tiles: {}", pos_err(pt));
    }
    let mut paths = vec![("best", &g1, (0.0f64, String::new())), ("scalar", &gs_, (0.0, String::new()))];
    paths.extend(tiles.iter().zip(["tile model", "tiles"]).map(|((_, g), path)| (path, g, (0.0, String::new()))));
    for (name, r) in net.layout.tensors(&spec) {
        let gmax = g_ref[r.clone()].iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        assert!(gmax > 0.0, "{name}: zero reference gradient");
        for (path, g, worst) in &mut paths {
            let d = g[r.clone()].iter().zip(&g_ref[r.clone()]).fold(0.0f32, |m, (a, b)| m.max((a - b).abs())) as f64;
            let rel = d / gmax;
            assert!(rel < 1e-4, "{name}: fast gradient ({path} products) differs by {rel:e} of its largest entry");
            if rel > worst.0 {
                *worst = (rel, name.clone());
            }
        }
    }
    for (path, _, worst) in &paths {
        println!(
            "train_fast_matches_generic: {path} products, worst tensor relative difference {:e} ({})",
            worst.0, worst.1
        );
    }
}

/// An `InputBuilder` reused across steps (other states, bodies of other sizes, no body) builds
/// exactly what a fresh `StepData::build` builds.
#[test]
fn train_input_builder_matches_build() {
    use hood::train::InputBuilder;
    let spec = ModelSpec::with_schedule(8, 2, 2, "f,c0 | d:c0,c1 | u:f,c0").unwrap();
    let (rest, faces) = hood::mesh::shapes::grid(12, 10, 0.36, 0.36, 0.301);
    let mut pinned = vec![false; rest.len()];
    pinned[3] = true;
    let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
    let graph = graph_of(&garment, 2);
    let mut rng = Rng::new(17);
    let bodies: Vec<(BodyMesh, Vec<[f32; 3]>)> = [(24, 32, 0.0f32), (16, 20, 0.01), (24, 32, -0.02)]
        .iter()
        .map(|&(a, b, dy)| {
            let (bv, bf) = hood::body::shapes::ellipsoid(a, b, [0.25, 0.3, 0.25], [0.0, dy, 0.0]);
            (BodyMesh::new(bv.len(), &bf).unwrap(), bv)
        })
        .collect();
    let mut builder = InputBuilder::default();
    let mut reused = StepData::build(
        &spec,
        &garment,
        &graph,
        &GarmentState { pos: &rest, velocity: &vec![[0.0; 3]; rest.len()], pinned: &pinned, pin_targets: &rest },
        None,
        DT,
    )
    .unwrap();
    let mut with_body_edges = 0;
    for round in 0..6 {
        let (pos, vel) = jittered(&rest, &mut rng);
        let gs = GarmentState { pos: &pos, velocity: &vel, pinned: &pinned, pin_targets: &rest };
        let (mesh, bv) = &bodies[round % 3];
        let next: Vec<[f32; 3]> = bv.iter().map(|p| [p[0] + 0.003, p[1], p[2] - 0.001]).collect();
        let frames = BodyFrames { mesh, prev: bv, pos: bv, next: &next };
        let body = if round == 4 { None } else { Some(&frames) };
        let dt = if round == 1 { hood::features::DT_STARTUP } else { DT };
        let fresh = StepData::build(&spec, &garment, &graph, &gs, body, dt).unwrap();
        builder.build(&spec, &garment, &graph, &gs, body, dt, &mut reused).unwrap();
        assert_eq!(reused, fresh, "round {round}");
        with_body_edges += usize::from(fresh.prefix[0] > 0);
    }
    assert!(with_body_edges >= 3, "the scenes must have body edges");
}

/// Counts allocations made by threads that opt in (the other tests of this binary run
/// alongside and are not counted).
struct CountingAlloc;

static ALLOCS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

std::thread_local! {
    static COUNTING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl std::alloc::GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        // SAFETY: the caller's contract is the system allocator's.
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: as above.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        if COUNTING.with(|c| c.get()) {
            ALLOCS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        // SAFETY: as above.
        unsafe { std::alloc::System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// After warm-up steps, a fast forward + backward and an `InputBuilder` step allocate nothing.
#[test]
fn train_fast_step_allocates_nothing() {
    use hood::sim::Serial;
    use hood::train::{FastWorkspace, InputBuilder};
    let scene = Scene::new(14, 12);
    let mut params = Params::init(&ModelSpec::with_schedule(16, 2, 2, "f,c0 | d:c0,c1 | u:f,c0").unwrap(), 4).unwrap();
    params.normalisers = hood::model::Normalisers::unit_scale(1);
    let graph = graph_of(&scene.garment, params.spec.levels);
    let net = Network::of(&params).unwrap();
    let stats = Stats::<f32>::of(&params);
    let theta = net.layout.flatten::<f32>(&params);
    let mut rng = Rng::new(8);
    let (b0, b1, b2) = (scene.body_at(0), scene.body_at(1), scene.body_at(2));
    let states: Vec<_> = (0..3).map(|_| jittered(scene.garment.rest(), &mut rng)).collect();
    let dpos = vec![[1e-3f32, -2e-3, 5e-4]; scene.garment.n_vertices()];
    let mut ws = FastWorkspace::default();
    let mut builder = InputBuilder::default();
    let mut step = StepData::default();
    let mut grad = vec![0.0f32; theta.len()];
    let mut run = |i: usize, count: bool| -> usize {
        let (pos, vel) = &states[i % states.len()];
        let gs = GarmentState { pos, velocity: vel, pinned: scene.garment.pinned(), pin_targets: scene.garment.rest() };
        let bf = BodyFrames { mesh: &scene.body, prev: &b0, pos: &b1, next: &b2 };
        ALLOCS.store(0, std::sync::atomic::Ordering::Relaxed);
        COUNTING.with(|c| c.set(count));
        builder.build(&params.spec, &scene.garment, &graph, &gs, Some(&bf), DT, &mut step).unwrap();
        net.forward_fast(&mut ws, &Serial, &theta, &stats, &graph, &step).unwrap();
        grad.iter_mut().for_each(|g| *g = 0.0);
        net.backward_fast(&mut ws, &Serial, &theta, &stats, &graph, &step, &dpos, &mut grad).unwrap();
        COUNTING.with(|c| c.set(false));
        assert!(step.prefix[0] > 0, "the scene must have body edges");
        ALLOCS.load(std::sync::atomic::Ordering::Relaxed)
    };
    assert!(run(0, true) > 0, "the counter must see the first step's allocations");
    for i in 1..6 {
        run(i, false);
    }
    let steady: usize = (6..9).map(|i| run(i, true)).sum();
    assert_eq!(steady, 0, "allocations in steady-state steps");
}
