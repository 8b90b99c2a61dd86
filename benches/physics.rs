//! Physics benches: the objective with its gradient on a ~12k-vertex garment (f32; one thread,
//! and as executor tasks on one and two) and the implicit step on a ~4.4k-vertex garment.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use hood::exec::{Serial, ThreadPool};
use hood::mesh::shapes::grid;
use hood::mesh::{Garment, GarmentDesc};
use hood::physics::{
    face_frames, BruteForceCentroids, CentroidQuery, Cloth, CollisionInput, FaceFrame, FrictionInput, Objective,
    ObjectiveTasks, StepInputs,
};
use hood::solve::{ImplicitStep, LbfgsParams, StepState};

/// splitmix64.
struct Rng(u64);
impl Rng {
    fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        lo + (hi - lo) * ((z >> 40) as f32 / (1u64 << 24) as f32)
    }
}

fn objective_12k(c: &mut Criterion) {
    let mut rng = Rng(7);
    let (rest, faces) = grid(110, 110, 1.2, 1.2, 0.0);
    let garment = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    let cloth = Cloth::<f32>::new(&garment);
    let n = rest.len();
    let pos: Vec<[f32; 3]> = rest.iter().map(|p| [p[0], p[1] + rng.uniform(-2e-3, 2e-3), p[2]]).collect();
    let vel: Vec<[f32; 3]> = (0..n).map(|_| [0.0, -0.003, 0.0]).collect();
    let x: Vec<[f32; 3]> = pos.iter().map(|p| p.map(|c| c + rng.uniform(-3e-3, 3e-3))).collect();
    // A bumpy body sheet just under the garment: every vertex has contact terms to evaluate.
    let (mut body, body_faces) = grid(60, 60, 1.3, 1.3, -0.002);
    body.iter_mut().for_each(|p| p[1] += rng.uniform(-1e-3, 1e-3));
    let nf = body_faces.len();
    let (mut cent, mut norm) = (vec![[0.0f32; 3]; nf], vec![[0.0f32; 3]; nf]);
    face_frames(&body, &body_faces, &mut cent, &mut norm).unwrap();
    let query = BruteForceCentroids { centroids: cent.clone() };
    let mut near_pos = vec![0u32; n];
    query.nearest_into(&pos, &mut near_pos);
    let mut near_x = vec![0u32; n];
    query.nearest_into(&x, &mut near_x);
    let frame = FaceFrame { centroids: &cent, normals: &norm };
    let inputs = StepInputs {
        pos: &pos,
        velocity: &vel,
        dt: 1.0 / 30.0,
        collision: Some(CollisionInput { nearest: &near_pos, next: frame }),
        friction: Some(FrictionInput { frame_a: frame, frame_b: frame, nearest_a: &near_pos, nearest_b: &near_x }),
    };
    let mut grad = vec![[0.0f32; 3]; n];
    let all = Objective::training(5e3);
    let cloth_only = Objective::cloth_only();
    println!("objective bench: {} vertices, {} faces, {} hinges", n, faces.len(), garment.hinges().len());
    c.bench_function("objective_grad_12k_f32_all_terms", |b| {
        b.iter(|| all.eval(&cloth, &inputs, black_box(&x), Some(&mut grad)).unwrap())
    });
    // The same evaluation as executor tasks (the solver step's): one thread, then two.
    let mut tasks = ObjectiveTasks::new(&cloth);
    c.bench_function("objective_grad_12k_f32_all_terms_tasks_1_thread", |b| {
        b.iter(|| tasks.eval(&Serial, &all, &cloth, &inputs, black_box(&x), Some(&mut grad)).unwrap())
    });
    let pool = ThreadPool::new(2);
    c.bench_function("objective_grad_12k_f32_all_terms_tasks_2_threads", |b| {
        b.iter(|| tasks.eval(&pool, &all, &cloth, &inputs, black_box(&x), Some(&mut grad)).unwrap())
    });
    c.bench_function("objective_grad_12k_f32_cloth_terms", |b| {
        b.iter(|| cloth_only.eval(&cloth, &inputs, black_box(&x), Some(&mut grad)).unwrap())
    });
    c.bench_function("stretching_grad_12k_f32", |b| {
        b.iter(|| hood::physics::stretching(&cloth, black_box(&x), Some(&mut grad)).unwrap())
    });
    c.bench_function("bending_grad_12k_f32", |b| {
        b.iter(|| hood::physics::bending(&cloth, black_box(&x), Some(&mut grad)).unwrap())
    });
    c.bench_function("objective_value_12k_f32_all_terms", |b| {
        b.iter(|| all.eval(&cloth, &inputs, black_box(&x), None).unwrap())
    });
}

fn implicit_4k(c: &mut Criterion) {
    let nx = 66; // 4,356 vertices
    let (rest, faces) = grid(nx, nx, 1.0, 1.0, 1.0);
    let mut pinned = vec![false; rest.len()];
    pinned[0] = true;
    pinned[nx - 1] = true;
    let garment = Garment::new(GarmentDesc::new(&rest, &faces).pinned(&pinned)).unwrap();
    let n = rest.len();
    let objective = Objective::cloth_only();
    for (name, tol) in [("implicit_step_4k_f64_converged", 1e-6), ("implicit_step_4k_f64_50_iterations", 0.0)] {
        let cloth = Cloth::<f64>::new(&garment);
        let pos: Vec<[f64; 3]> = rest.iter().map(|p| p.map(|c| c as f64)).collect();
        // A state in motion: falling at 0.5 m/s.
        let vel: Vec<[f64; 3]> = (0..n).map(|i| if pinned[i] { [0.0; 3] } else { [0.0, -0.5 / 30.0, 0.0] }).collect();
        let mut x = vec![[0.0f64; 3]; n];
        let mut step = ImplicitStep::<f64>::new(n, 10);
        let params = if tol > 0.0 {
            LbfgsParams::default().with_max_iterations(2000).with_grad_tol(tol).with_rel_decrease_tol(1e-12)
        } else {
            LbfgsParams::default().with_max_iterations(50).with_grad_tol(0.0).with_rel_decrease_tol(0.0)
        };
        let state = StepState { pos: &pos, velocity: &vel, dt: 1.0 / 30.0, pinned: &pinned, targets: &pos };
        let mut group = c.benchmark_group("implicit");
        group.sample_size(10);
        let mut reported = false;
        group.bench_function(name, |b| {
            // Inside the closure so that a filtered-out bench costs nothing.
            if !reported {
                let r = step.step(&cloth, &objective, &state, None, &params, &mut x).unwrap();
                println!("{name}: {n} vertices, {r:?}");
                reported = true;
            }
            b.iter(|| step.step(&cloth, &objective, black_box(&state), None, &params, &mut x).unwrap())
        });
        group.finish();
    }
}

criterion_group!(objective, objective_12k);
criterion_group!(implicit, implicit_4k);
criterion_main!(objective, implicit);
