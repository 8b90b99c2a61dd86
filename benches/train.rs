//! The trainer's optimiser step on the fixture t-shirt (1,311 vertices, 13,380-vertex body) at
//! h = 32, 64, 128 on 1 and 2 threads: the whole step (inputs, forward, losses, backward,
//! clipping, Adam) and its parts. Skipped with a message when the assets folder ([`hood::assets`]) is absent.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hood::bench::ThreadPair;
use hood::body::{BodyFrame, Nearest};
use hood::features::DT;
use hood::mesh::Garment;
use hood::model::{ModelSpec, Params};
use hood::physics::{face_frames, Cloth, CollisionInput, FaceFrame, Objective, StepInputs};
use hood::sim::{Graph, SimState, ThreadPool};
use hood::train::{
    clip_global_norm, learning_rate, Adam, BodyFrames, FastWorkspace, GarmentState, InputBuilder, Network, Stats,
    StepData,
};
use hood::workloads::workload;
use std::hint::black_box;
use std::time::Duration;

/// One training sample's step and everything an optimiser step keeps between steps.
struct Trainer<'a> {
    garment: &'a Garment,
    graph: &'a Graph,
    mesh: &'a hood::body::BodyMesh,
    state: &'a SimState,
    next: &'a [[f32; 3]],
    spec: ModelSpec,
    net: Network,
    stats: Stats<f32>,
    theta: Vec<f32>,
    adam: Adam,
    grad: Vec<f32>,
    dx: Vec<[f32; 3]>,
    builder: InputBuilder,
    step: StepData,
    body_frame: BodyFrame,
    nearest: Vec<Nearest>,
    nearest_idx: Vec<u32>,
    centroids: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    cloth: Cloth<f32>,
    objective: Objective,
    ws: FastWorkspace,
}

impl<'a> Trainer<'a> {
    fn new(
        h: usize,
        garment: &'a Garment,
        graph: &'a Graph,
        mesh: &'a hood::body::BodyMesh,
        state: &'a SimState,
        next: &'a [[f32; 3]],
    ) -> Trainer<'a> {
        let spec = ModelSpec::hood(h);
        let mut params = Params::init(&spec, 1).unwrap();
        let n = garment.n_vertices();
        let mut t = Trainer {
            garment,
            graph,
            mesh,
            state,
            next,
            spec: spec.clone(),
            net: Network::of(&params).unwrap(),
            stats: Stats::of(&params),
            theta: Vec::new(),
            adam: Adam::new(0),
            grad: Vec::new(),
            dx: vec![[0.0; 3]; n],
            builder: InputBuilder::default(),
            step: StepData::default(),
            body_frame: BodyFrame::new(mesh).unwrap(),
            nearest: vec![Nearest { index: 0, distance: 0.0 }; n],
            nearest_idx: vec![0; n],
            centroids: vec![[0.0; 3]; mesh.n_faces()],
            normals: vec![[0.0; 3]; mesh.n_faces()],
            cloth: Cloth::new(garment),
            objective: Objective { friction: None, ..Objective::training(5e3) },
            ws: FastWorkspace::default(),
        };
        t.inputs();
        // Normalisers fitted to this step (the trainer accumulates them the same way).
        let nz = &mut params.normalisers;
        nz.node.accumulate(&t.step.node_features, 24);
        nz.edge.accumulate(&t.step.edge_features[3], 12);
        nz.body_edge.accumulate(&t.step.g2b_features, 9);
        nz.output.accumulate(&vec![1e-3f32; 64 * 3], 3);
        t.stats = Stats::of(&params);
        t.theta = t.net.layout.flatten(&params);
        t.adam = Adam::new(t.theta.len());
        t.grad = vec![0.0; t.theta.len()];
        t
    }

    /// The step's network inputs and the objective's body data.
    fn inputs(&mut self) {
        let g = self.garment;
        let gs = GarmentState {
            pos: &self.state.pos,
            velocity: &self.state.velocity,
            pinned: g.pinned(),
            pin_targets: g.rest(),
        };
        let bf =
            BodyFrames { mesh: self.mesh, prev: &self.state.body_prev, pos: &self.state.body_pos, next: self.next };
        self.builder.build(&self.spec, g, self.graph, &gs, Some(&bf), DT, &mut self.step).unwrap();
        self.body_frame.update(self.mesh, &self.state.body_pos).unwrap();
        self.body_frame.nearest_faces(&self.step.pos, &mut self.nearest).unwrap();
        for (i, q) in self.nearest_idx.iter_mut().zip(&self.nearest) {
            *i = q.index;
        }
        face_frames(self.next, self.mesh.faces(), &mut self.centroids, &mut self.normals).unwrap();
    }

    fn forward(&mut self, pool: &ThreadPool) {
        self.net.forward_fast(&mut self.ws, pool, &self.theta, &self.stats, self.graph, &self.step).unwrap();
    }

    fn losses(&mut self) -> f32 {
        let inputs = StepInputs {
            pos: &self.step.pos,
            velocity: &self.step.velocity,
            dt: DT,
            collision: Some(CollisionInput {
                nearest: &self.nearest_idx,
                next: FaceFrame { centroids: &self.centroids, normals: &self.normals },
            }),
            friction: None,
        };
        self.objective.eval(&self.cloth, &inputs, &self.ws.new_pos, Some(&mut self.dx)).unwrap().total()
    }

    fn backward(&mut self, pool: &ThreadPool) {
        self.grad.iter_mut().for_each(|g| *g = 0.0);
        let (net, ws) = (&self.net, &mut self.ws);
        net.backward_fast(ws, pool, &self.theta, &self.stats, self.graph, &self.step, &self.dx, &mut self.grad)
            .unwrap();
    }

    /// One whole optimiser step.
    fn optimiser_step(&mut self, pool: &ThreadPool) -> f32 {
        self.inputs();
        self.forward(pool);
        let loss = self.losses();
        self.backward(pool);
        clip_global_norm(&mut self.grad, 1.0);
        self.adam.step_on(pool, &mut self.theta, &self.grad, learning_rate(self.adam.t));
        loss
    }
}

fn bench_train(c: &mut Criterion) {
    let Ok(w) = workload("tee", &hood::assets::locate(None).unwrap_or_default()) else {
        eprintln!("train: skipped (the fixture t-shirt beside the assets folder is absent)");
        return;
    };
    let (mesh, frames) = w.body.as_ref().unwrap();
    let state = w.fixed_state.clone().unwrap();
    let graph = w.graph.clone().unwrap();
    let mut g = c.benchmark_group("train");
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(4));
    for h in [32, 64, 128] {
        let mut t = Trainer::new(h, &w.garment, &graph, mesh, &state, &frames[1]);
        for threads in [1, 2] {
            let pool = ThreadPool::new(threads);
            let id = |what: &str| BenchmarkId::new(what, format!("h{h}/t{threads}"));
            // Where the two threads ran (see `ThreadPair`): before and after their figures.
            let placement = || {
                if let Some(pair) = (threads > 1).then(ThreadPair::measure).flatten() {
                    eprintln!("train h{h}/t{threads}: two threads: {pair}");
                }
            };
            placement();
            g.bench_function(id("step"), |b| b.iter(|| black_box(t.optimiser_step(&pool))));
            t.optimiser_step(&pool);
            g.bench_function(id("forward"), |b| b.iter(|| t.forward(&pool)));
            g.bench_function(id("backward"), |b| b.iter(|| t.backward(&pool)));
            placement();
        }
        g.bench_function(BenchmarkId::new("losses", format!("h{h}")), |b| b.iter(|| black_box(t.losses())));
        g.bench_function(BenchmarkId::new("inputs", format!("h{h}")), |b| b.iter(|| t.inputs()));
    }
    g.finish();
}

/// The trainer's matrix products alone, a forward product (`C = A·B`) and a weight gradient
/// (`C += Aᵀ·B`) of a training step's shapes, on the f32 path `Gemm::best` would take without
/// AMX and, where the CPU has AMX, on the split-bf16 tiles (throughput in FLOP/s: the f32
/// product's work, whatever the path does to get it).
fn bench_products(c: &mut Criterion) {
    use hood::train::{Gemm, Mat, Out};
    let f32_path = Gemm::at_most(hood::kernels::Kernels::best_f32().tier());
    #[allow(unused_mut)] // off x86-64 there is no tile path
    let mut paths = vec![(f32_path.tier().name(), f32_path)];
    #[cfg(target_arch = "x86_64")]
    match Gemm::tiles() {
        Some(tiles) => paths.push(("tiles", tiles)),
        None => eprintln!("train_products: no AMX in this process, the f32 path only"),
    }
    #[cfg(target_arch = "x86_64")]
    if let Some(choice) = Gemm::tile_choice() {
        eprintln!("train_products: {}", choice.describe());
    }
    let mut g = c.benchmark_group("train_products");
    g.sample_size(20).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(2));
    for (rows, h) in [(2048, 64), (8192, 128)] {
        let x: Vec<f32> = (0..rows * h).map(|i| ((i * 7919 % 1000) as f32 - 500.0) * 1e-3).collect();
        let w: Vec<f32> = (0..h * h).map(|i| ((i * 104_729 % 1000) as f32 - 500.0) * 1e-4).collect();
        let mut y = vec![0.0f32; rows * h];
        let mut dw = vec![0.0f32; h * h];
        g.throughput(criterion::Throughput::Elements((2 * rows * h * h) as u64));
        for (name, p) in &paths {
            let id = |what: &str| BenchmarkId::new(what, format!("{name}/{rows}x{h}"));
            g.bench_function(id("nn"), |b| {
                b.iter(|| p.nn_out(rows, h, h, Mat { data: &x, ld: h }, Mat { data: &w, ld: h }, Out::Set, &mut y, h))
            });
            g.bench_function(id("tn"), |b| {
                b.iter(|| p.tn(rows, h, h, Mat { data: &x, ld: h }, Mat { data: &y, ld: h }, &mut dw, h))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench_train, bench_products);
criterion_main!(benches);
