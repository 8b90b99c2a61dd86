use super::*;
use crate::error::Error;
use crate::mesh::shapes::grid;
use crate::mesh::{Garment, GarmentDesc, Material};
use alloc::vec;
use alloc::vec::Vec;
use std::println;

/// splitmix64, seeded.
pub(crate) struct Rng(u64);
impl Rng {
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    pub(crate) fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// A small bumpy grid garment with random per-vertex materials.
fn random_garment(rng: &mut Rng, nx: usize, nz: usize) -> Garment {
    let (mut rest, faces) = grid(nx, nz, 0.4, 0.3, 0.0);
    for p in rest.iter_mut() {
        p[1] += rng.uniform(-0.01, 0.01) as f32;
        p[0] += rng.uniform(-0.005, 0.005) as f32;
    }
    let mats: Vec<Material> = (0..rest.len())
        .map(|_| Material {
            density: rng.uniform(0.05, 0.6) as f32,
            mu: rng.uniform(16000.0, 60000.0) as f32,
            lambda: rng.uniform(4000.0, 90000.0) as f32,
            bending: rng.uniform(1e-6, 1e-3) as f32,
        })
        .collect();
    Garment::new(GarmentDesc::new(&rest, &faces).materials(&mats)).unwrap()
}

fn perturbed(rng: &mut Rng, base: &[[f32; 3]], amp: f64) -> Vec<[f64; 3]> {
    base.iter().map(|p| p.map(|c| c as f64 + rng.uniform(-amp, amp))).collect()
}

/// Central differences of `f` at `x`, step `h`.
fn numeric_grad(x: &[[f64; 3]], h: f64, mut f: impl FnMut(&[[f64; 3]]) -> f64) -> Vec<[f64; 3]> {
    let mut xs = x.to_vec();
    let mut g = vec![[0.0; 3]; x.len()];
    for i in 0..x.len() {
        for k in 0..3 {
            let x0 = xs[i][k];
            xs[i][k] = x0 + h;
            let ep = f(&xs);
            xs[i][k] = x0 - h;
            let em = f(&xs);
            xs[i][k] = x0;
            g[i][k] = (ep - em) / (2.0 * h);
        }
    }
    g
}

/// `||a - b|| / ||b||`.
pub(crate) fn rel_err(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (p, q) in a.iter().zip(b) {
        for k in 0..3 {
            num += (p[k] - q[k]) * (p[k] - q[k]);
            den += q[k] * q[k];
        }
    }
    (num / den.max(1e-300)).sqrt()
}

/// Checks the analytic gradient of `term` (value, with gradient added into a buffer) against
/// central differences; returns the relative error.
fn check_term(
    name: &str,
    x: &[[f64; 3]],
    h: f64,
    mut term: impl FnMut(&[[f64; 3]], Option<&mut [[f64; 3]]>) -> f64,
) -> f64 {
    let mut g = vec![[0.0; 3]; x.len()];
    let e = term(x, Some(&mut g));
    let e_only = term(x, None);
    assert_eq!(e, e_only, "{name}: value must not depend on whether the gradient is asked for");
    let num = numeric_grad(x, h, |y| term(y, None));
    let err = rel_err(&g, &num);
    let gn: f64 = g.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    println!("{name}: E = {e:.6e}, |g| = {gn:.3e}, rel err = {err:.3e}");
    assert!(gn > 0.0, "{name}: zero gradient makes the check vacuous");
    assert!(err < 1e-6, "{name}: gradient rel err {err:e}");
    err
}

/// A bumpy body sheet under the garment with two frames (a: as built, b: moved a little).
struct TestBody {
    cent: [Vec<[f64; 3]>; 2],
    norm: [Vec<[f64; 3]>; 2],
}

fn test_body(rng: &mut Rng, y: f32) -> TestBody {
    let (mut pos, faces) = grid(9, 8, 0.5, 0.4, y);
    for p in pos.iter_mut() {
        p[1] += rng.uniform(-0.004, 0.004) as f32;
    }
    let moved: Vec<[f32; 3]> = pos.iter().map(|p| [p[0] + 0.003, p[1] + 0.002, p[2] - 0.002]).collect();
    let nf = faces.len();
    let mut out =
        TestBody { cent: [vec![[0.0; 3]; nf], vec![[0.0; 3]; nf]], norm: [vec![[0.0; 3]; nf], vec![[0.0; 3]; nf]] };
    for (s, p) in [&pos, &moved].into_iter().enumerate() {
        let [c0, c1] = &mut out.cent;
        let [n0, n1] = &mut out.norm;
        let (c, n) = if s == 0 { (c0, n0) } else { (c1, n1) };
        face_frames(p, &faces, c, n).unwrap();
    }
    out
}

fn brute_nearest(points: &[[f64; 3]], cent: &[[f64; 3]]) -> Vec<u32> {
    let q = BruteForceCentroids { centroids: cent.iter().map(|c| c.map(|v| v as f32)).collect() };
    points.iter().map(|p| q.nearest(p.map(|v| v as f32))).collect()
}

#[test]
fn gradient_check_stretching_and_bending() {
    let mut rng = Rng(1);
    for trial in 0..4 {
        let g = random_garment(&mut rng, 5 + trial, 4 + trial % 2);
        let cloth = Cloth::<f64>::new(&g);
        let x = perturbed(&mut rng, g.rest(), 0.02);
        check_term("stretching", &x, 1e-6, |y, gr| stretching(&cloth, y, gr).unwrap());
        check_term("bending", &x, 1e-6, |y, gr| bending(&cloth, y, gr).unwrap());
    }
    // Inconsistently oriented triangles (every third one flipped): the angle jumps by pi there,
    // the gradient must still be exact.
    let g = random_garment(&mut rng, 6, 5);
    let faces: Vec<[u32; 3]> =
        g.faces().iter().enumerate().map(|(i, f)| if i % 3 == 0 { [f[0], f[2], f[1]] } else { *f }).collect();
    let g = Garment::new(GarmentDesc::new(g.rest(), &faces).materials(g.materials())).unwrap();
    let cloth = Cloth::<f64>::new(&g);
    assert!(cloth.hinges().iter().any(|h| !h.consistent));
    let x = perturbed(&mut rng, g.rest(), 0.02);
    check_term("bending, mixed orientation", &x, 1e-6, |y, gr| bending(&cloth, y, gr).unwrap());
}

#[test]
fn gradient_check_inertia_and_gravity() {
    let mut rng = Rng(2);
    let g = random_garment(&mut rng, 6, 5);
    let cloth = Cloth::<f64>::new(&g);
    let pos = perturbed(&mut rng, g.rest(), 0.01);
    let vel: Vec<[f64; 3]> = (0..pos.len()).map(|_| [0.0; 3].map(|_| rng.uniform(-0.01, 0.01))).collect();
    let x = perturbed(&mut rng, g.rest(), 0.02);
    check_term("inertia", &x, 1e-6, |y, gr| inertia(&cloth, &pos, &vel, 1.0 / 30.0, y, gr).unwrap());
    check_term("gravity", &x, 1e-6, |y, gr| gravity(&cloth, y, gr).unwrap());
}

#[test]
fn gradient_check_collision() {
    let mut rng = Rng(3);
    let g = random_garment(&mut rng, 7, 6);
    let body = test_body(&mut rng, 0.0);
    let pos = perturbed(&mut rng, g.rest(), 0.003);
    let near = brute_nearest(&pos, &body.cent[0]);
    let next = FaceFrame { centroids: &body.cent[1], normals: &body.norm[1] };
    let x = perturbed(&mut rng, g.rest(), 0.006);
    // Keep clear of the kink at d = eps so the finite differences see one branch.
    let mut d = vec![0.0; x.len()];
    collision::plane_distances(&x, &near, next, &mut d);
    let eps = 2e-3;
    assert!(d.iter().all(|v| (v - eps).abs() > 1e-5), "state too close to the kink; change the seed");
    let active = d.iter().filter(|&&v| v < eps).count();
    assert!(active > 5, "only {active} vertices in contact");
    check_term("collision", &x, 1e-7, |y, gr| collision(y, &near, next, eps, 5e3, gr).unwrap());
}

#[test]
fn gradient_check_friction() {
    let mut rng = Rng(4);
    let g = random_garment(&mut rng, 7, 6);
    let cloth = Cloth::<f64>::new(&g);
    let body = test_body(&mut rng, -0.002);
    let pos = perturbed(&mut rng, g.rest(), 0.003);
    let x = perturbed(&mut rng, g.rest(), 0.006);
    let fa = FaceFrame { centroids: &body.cent[0], normals: &body.norm[0] };
    let fb = FaceFrame { centroids: &body.cent[1], normals: &body.norm[1] };
    let near_a = brute_nearest(&pos, &body.cent[0]);
    let near_b = brute_nearest(&x, &body.cent[1]);
    for (mode, radius) in [(RadiusMode::Distance, 0.03), (RadiusMode::SquaredDistance, 4e-4)] {
        for axis in [1, 2] {
            let params = FrictionParams {
                mu: 0.5,
                radius,
                radius_mode: mode,
                floor_axis: axis,
                frames: FrictionFrames::CurrentNext,
            };
            // Away from the radius kink: no vertex within 1e-4 of it.
            for i in 0..x.len() {
                let db = crate::math::sub3(x[i], body.cent[1][near_b[i] as usize]);
                let mut r = crate::math::dot3(db, db);
                if mode == RadiusMode::Distance {
                    r = r.sqrt();
                }
                assert!((r - radius).abs() > 1e-5 * radius.max(1e-2));
            }
            check_term(&std::format!("friction {mode:?} axis {axis}"), &x, 1e-7, |y, gr| {
                friction(&cloth, &pos, y, fa, fb, &near_a, &near_b, &params, gr).unwrap()
            });
        }
    }
}

/// A garment in motion over a test body, with every input of the full objective.
struct ObjectiveScene {
    g: Garment,
    cloth: Cloth<f64>,
    body: TestBody,
    pos: Vec<[f64; 3]>,
    vel: Vec<[f64; 3]>,
    x: Vec<[f64; 3]>,
    near_cur: Vec<u32>,
    near_b: Vec<u32>,
}

impl ObjectiveScene {
    /// An `nx x nz` random garment from seed `seed`.
    fn new(seed: u64, nx: usize, nz: usize) -> ObjectiveScene {
        let mut rng = Rng(seed);
        let g = random_garment(&mut rng, nx, nz);
        let cloth = Cloth::<f64>::new(&g);
        let body = test_body(&mut rng, -0.002);
        let pos = perturbed(&mut rng, g.rest(), 0.003);
        let vel: Vec<[f64; 3]> = (0..pos.len()).map(|_| [0.0; 3].map(|_| rng.uniform(-0.005, 0.005))).collect();
        let x = perturbed(&mut rng, g.rest(), 0.006);
        let near_cur = brute_nearest(&pos, &body.cent[0]);
        let near_b = brute_nearest(&x, &body.cent[1]);
        ObjectiveScene { g, cloth, body, pos, vel, x, near_cur, near_b }
    }

    fn inputs(&self) -> StepInputs<'_, f64> {
        let next = FaceFrame { centroids: &self.body.cent[1], normals: &self.body.norm[1] };
        StepInputs {
            pos: &self.pos,
            velocity: &self.vel,
            dt: 1.0 / 30.0,
            collision: Some(CollisionInput { nearest: &self.near_cur, next }),
            friction: Some(FrictionInput {
                frame_a: FaceFrame { centroids: &self.body.cent[0], normals: &self.body.norm[0] },
                frame_b: next,
                nearest_a: &self.near_cur,
                nearest_b: &self.near_b,
            }),
        }
    }

    /// Every term, with a friction radius wide enough for the test body's vertices to take part.
    fn objective() -> Objective {
        Objective {
            friction: Some(FrictionParams { radius: 0.03, ..FrictionParams::PHYSICAL }),
            ..Objective::training(5e3)
        }
    }
}

#[test]
fn gradient_check_objective_sums_terms() {
    let sc = ObjectiveScene::new(5, 6, 6);
    let ObjectiveScene { g, cloth, body, pos, vel, x, near_cur, near_b } = &sc;
    let (cloth, pos, vel, x) = (cloth, &pos[..], &vel[..], &x[..]);
    let inputs = sc.inputs();
    let obj = ObjectiveScene::objective();
    let mut grad = vec![[7.0; 3]; x.len()]; // overwritten, not accumulated
    let t = obj.eval(cloth, &inputs, x, Some(&mut grad)).unwrap();
    // The parts add up to the total, term by term.
    let mut sum = vec![[0.0; 3]; x.len()];
    let parts = [
        stretching(cloth, x, Some(&mut sum)).unwrap(),
        bending(cloth, x, Some(&mut sum)).unwrap(),
        inertia(cloth, pos, vel, 1.0 / 30.0, x, Some(&mut sum)).unwrap(),
        gravity(cloth, x, Some(&mut sum)).unwrap(),
    ];
    assert_eq!([t.stretching, t.bending, t.inertia, t.gravity], parts);
    assert!(t.collision > 0.0 && t.friction > 0.0, "{t:?}");
    check_term("objective", x, 1e-7, |y, gr| obj.eval(cloth, &inputs, y, gr).unwrap().total());
    // f32 evaluation of the same objective agrees to f32 precision.
    let c32 = Cloth::<f32>::new(g);
    let to32 = |v: &[[f64; 3]]| -> Vec<[f32; 3]> { v.iter().map(|p| p.map(|c| c as f32)).collect() };
    let (x32, pos32, vel32) = (to32(x), to32(pos), to32(vel));
    let (c0, n0, c1, n1) = (to32(&body.cent[0]), to32(&body.norm[0]), to32(&body.cent[1]), to32(&body.norm[1]));
    let in32 = StepInputs {
        pos: &pos32,
        velocity: &vel32,
        dt: 1.0f32 / 30.0,
        collision: Some(CollisionInput { nearest: near_cur, next: FaceFrame { centroids: &c1, normals: &n1 } }),
        friction: Some(FrictionInput {
            frame_a: FaceFrame { centroids: &c0, normals: &n0 },
            frame_b: FaceFrame { centroids: &c1, normals: &n1 },
            nearest_a: near_cur,
            nearest_b: near_b,
        }),
    };
    let mut g32 = vec![[0.0f32; 3]; x.len()];
    let t32 = obj.eval(&c32, &in32, &x32, Some(&mut g32)).unwrap().to_f64();
    for ((name, a), (_, b)) in t32.named().iter().zip(t.named()) {
        assert!((a - b).abs() <= 1e-3 * b.abs() + 1e-9, "{name}: f32 {a} vs f64 {b}");
    }
    let g32_64: Vec<[f64; 3]> = g32.iter().map(|p| p.map(|c| c as f64)).collect();
    assert!(rel_err(&g32_64, &grad) < 1e-3);
}

#[test]
fn physics_flat_rest_has_zero_stretching_and_bending() {
    let (rest, faces) = grid(8, 6, 0.5, 0.4, 0.3);
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    let cloth = Cloth::<f64>::new(&g);
    let x: Vec<[f64; 3]> = rest.iter().map(|p| p.map(|c| c as f64)).collect();
    let mut gr = vec![[0.0; 3]; x.len()];
    let s = stretching(&cloth, &x, Some(&mut gr)).unwrap();
    let b = bending(&cloth, &x, Some(&mut gr)).unwrap();
    // Dm^-1 is stored in f32, so the rest strain is ~1e-7 rather than 0: E ~ 1e-15 J where a 1 % strain gives ~1e-4 J.
    assert!(s.abs() < 1e-12 && b.abs() < 1e-18, "stretching {s}, bending {b}");
    assert!(gr.iter().flatten().all(|v| v.abs() < 1e-6));
}

#[test]
fn physics_rigid_motion_leaves_stretching_and_bending_unchanged() {
    let mut rng = Rng(6);
    let g = random_garment(&mut rng, 7, 6);
    let cloth = Cloth::<f64>::new(&g);
    let x = perturbed(&mut rng, g.rest(), 0.02);
    let (s0, b0) = (stretching(&cloth, &x, None).unwrap(), bending(&cloth, &x, None).unwrap());
    assert!(s0 > 0.0 && b0 > 0.0);
    // Rotation about an arbitrary axis (Rodrigues) plus a translation.
    let axis = {
        let a = [0.3, -0.8, 0.5];
        let l = crate::math::norm3(a);
        a.map(|c| c / l)
    };
    let (sn, cs) = (0.9f64.sin(), 0.9f64.cos());
    let moved: Vec<[f64; 3]> = x
        .iter()
        .map(|p| {
            let kxp = crate::math::cross3(axis, *p);
            let kdp = crate::math::dot3(axis, *p);
            let mut r = [0.0; 3];
            for k in 0..3 {
                r[k] = p[k] * cs + kxp[k] * sn + axis[k] * kdp * (1.0 - cs) + [1.5, -2.0, 0.7][k];
            }
            r
        })
        .collect();
    let (s1, b1) = (stretching(&cloth, &moved, None).unwrap(), bending(&cloth, &moved, None).unwrap());
    assert!((s1 - s0).abs() < 1e-9 * s0, "{s0} vs {s1}");
    assert!((b1 - b0).abs() < 1e-9 * b0, "{b0} vs {b1}");
}

#[test]
fn physics_gravity_gradient_is_mg_on_y() {
    let mut rng = Rng(7);
    let g = random_garment(&mut rng, 5, 5);
    let cloth = Cloth::<f64>::new(&g);
    let x = perturbed(&mut rng, g.rest(), 0.05);
    let mut gr = vec![[0.0; 3]; x.len()];
    let e = gravity(&cloth, &x, Some(&mut gr)).unwrap();
    let mut want = 0.0;
    for (i, m) in g.vertex_mass().iter().enumerate() {
        let mg = *m as f64 * 9.81;
        assert!((gr[i][1] - mg).abs() < 1e-12 && gr[i][0] == 0.0 && gr[i][2] == 0.0);
        want += mg * x[i][1];
    }
    assert!((e - want).abs() < 1e-12);
}

#[test]
fn physics_stretching_of_uniform_scale_matches_closed_form() {
    // Stretch a flat grid by s in both directions: G = (s² - 1)/2 I, psi = 2 mu g² + 2 lambda g².
    let (rest, faces) = grid(5, 4, 0.4, 0.3, 0.0);
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    let cloth = Cloth::<f64>::new(&g);
    let s = 1.1;
    let x: Vec<[f64; 3]> = rest.iter().map(|p| [p[0] as f64 * s, 0.0, p[2] as f64 * s]).collect();
    let m = Material::default();
    let gg = (s * s - 1.0) / 2.0;
    let psi = m.mu as f64 * 2.0 * gg * gg + m.lambda as f64 / 2.0 * (2.0 * gg) * (2.0 * gg);
    let want = g.total_area() * THICKNESS * psi;
    let got = stretching(&cloth, &x, None).unwrap();
    assert!((got - want).abs() < 1e-6 * want, "{got} vs {want}");
}

/// The grid's hinted centroid query gives the brute-force answers whatever the hints: last
/// answers, wrong faces, out-of-range indices.
#[test]
fn physics_centroid_query_hints_change_no_answer() {
    let mut rng = Rng(41);
    let cent: Vec<[f32; 3]> = (0..700)
        .map(|_| [rng.uniform(-0.3, 0.3) as f32, rng.uniform(0.0, 1.0) as f32, rng.uniform(-0.2, 0.2) as f32])
        .collect();
    let mut grid = crate::body::PointGrid::new(cent.len(), 8 * cent.len()).unwrap();
    grid.rebuild(&cent).unwrap();
    let brute = BruteForceCentroids { centroids: cent.clone() };
    let pts: Vec<[f32; 3]> = (0..500)
        .map(|_| [rng.uniform(-0.6, 0.6) as f32, rng.uniform(-0.3, 1.3) as f32, rng.uniform(-0.5, 0.5) as f32])
        .collect();
    let mut want = vec![0u32; pts.len()];
    brute.nearest_into(&pts, &mut want);
    let n = cent.len() as u64;
    let hint_sets: [Vec<u32>; 3] = [
        want.clone(),
        (0..pts.len()).map(|_| (rng.next_u64() % n) as u32).collect(),
        (0..pts.len()).map(|i| if i % 2 == 0 { u32::MAX } else { n as u32 + i as u32 }).collect(),
    ];
    for hints in &hint_sets {
        let mut got = vec![0u32; pts.len()];
        grid.nearest_into_hinted(&pts, hints, &mut got);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            // Ties (equal distance) may pick either face.
            let d2 = |c: u32| (0..3).map(|k| (pts[i][k] - cent[c as usize][k]).powi(2)).sum::<f32>();
            assert!(g == w || d2(*g) == d2(*w), "point {i}: {g} vs {w}");
        }
    }
}

/// The task-split objective: the terms and gradient of [`Objective::eval`] within rounding, the
/// same bits whatever the executor, errors as values that do not outlive their evaluation.
#[test]
fn physics_objective_tasks_match_eval_for_any_executor() {
    use crate::exec::{Executor, Serial, ThreadPool};
    // Several blocks of vertices, triangles and hinges, so that tasks split them differently.
    let sc = ObjectiveScene::new(11, 40, 30);
    let (cloth, body, x, near_cur) = (&sc.cloth, &sc.body, &sc.x, &sc.near_cur);
    let inputs = sc.inputs();
    let next = inputs.collision.unwrap().next;
    let obj = ObjectiveScene::objective();
    let mut want_g = vec![[0.0; 3]; x.len()];
    let want = obj.eval(cloth, &inputs, x, Some(&mut want_g)).unwrap();
    assert!(want.named().iter().all(|(_, v)| *v != 0.0), "every term takes part: {want:?}");
    let mut tasks = ObjectiveTasks::new(cloth);
    let mut run = |exec: &dyn Executor, o: &Objective| {
        let mut g = vec![[7.0; 3]; x.len()]; // overwritten, not accumulated
        let t = tasks.eval(exec, o, cloth, &inputs, x, Some(&mut g)).unwrap();
        assert_eq!(tasks.eval(exec, o, cloth, &inputs, x, None).unwrap(), t, "value without the gradient");
        (t, g)
    };
    let (serial, serial_g) = run(&Serial, &obj);
    for ((name, a), (_, b)) in serial.named().iter().zip(want.named()) {
        assert!((a - b).abs() <= 1e-12 * b.abs(), "{name}: tasks {a} against eval {b}");
    }
    assert!(rel_err(&serial_g, &want_g) < 1e-12, "gradient {}", rel_err(&serial_g, &want_g));
    for threads in [2, 3, 5] {
        let pool = ThreadPool::new(threads);
        assert_eq!(run(&pool, &obj), (serial, serial_g.clone()), "{threads} threads");
    }
    // Terms switched off are zero and leave the rest as they were.
    let cloth_only = Objective::cloth_only();
    let (t, _) = run(&ThreadPool::new(2), &cloth_only);
    assert_eq!((t.collision, t.friction), (0.0, 0.0));
    assert_eq!(
        [t.stretching, t.bending, t.inertia, t.gravity],
        [serial.stretching, serial.bending, serial.inertia, serial.gravity]
    );
    // A bad face index is an error value, and the next evaluation does not see it again.
    let mut bad = near_cur.clone();
    bad[x.len() - 3] = body.cent[1].len() as u32;
    let bad_inputs = StepInputs { collision: Some(CollisionInput { nearest: &bad, next }), ..inputs };
    let pool = ThreadPool::new(3);
    let err = tasks.eval(&pool, &obj, cloth, &bad_inputs, x, None).unwrap_err();
    assert_eq!(err, obj.eval(cloth, &bad_inputs, x, None).unwrap_err());
    assert_eq!(tasks.eval(&pool, &obj, cloth, &inputs, x, None).unwrap(), serial);
    // Buffers made for another garment are refused: other counts, or the same counts with the
    // triangles in another order.
    let other = Cloth::<f64>::new(&random_garment(&mut Rng(12), 6, 6));
    assert!(matches!(tasks.eval(&Serial, &obj, &other, &inputs, x, None), Err(Error::SizeMismatch { .. })));
    let (rest, mut faces) = grid(40, 30, 0.4, 0.3, 0.0);
    faces.reverse();
    let reordered = Cloth::<f64>::new(&Garment::new(GarmentDesc::new(&rest, &faces)).unwrap());
    let mut g = vec![[0.0; 3]; x.len()];
    let foreign = tasks.eval(&pool, &obj, &reordered, &inputs, x, Some(&mut g));
    assert!(matches!(foreign, Err(Error::OutOfRange { .. })), "{foreign:?}");
    assert_eq!(tasks.eval(&pool, &obj, cloth, &inputs, x, None).unwrap(), serial);
}
