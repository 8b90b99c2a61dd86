//! Body queries of one frame: grid rebuild, body edges (nearest body vertex within 0.03 m) and
//! nearest face centroid, for ~4.4k garment points near the body (in a spatially coherent
//! order, as a garment's vertices are; one variant in random order). Uses the real MakeHuman body
//! from `../shared/assets` when present, else a procedural ellipsoid of ~13k vertices.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use hood::body::{shapes::ellipsoid, BodyFrame, BodyMesh, GarmentQuery, Nearest, PointGrid};
use hood::io::obj::Obj;
use hood::sim::{Executor, ThreadPool};

const N_GARMENT: usize = 4400;
const RADIUS: f32 = 0.03;

fn load_body() -> (Vec<[f32; 3]>, Vec<[u32; 3]>, &'static str) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/assets/body/base.obj");
    if let Ok(mut obj) = Obj::read(path) {
        obj.scale(0.1); // decimetres to metres
        if let Ok(body) = obj.extract_groups(&["body"]) {
            return (body.rest, body.faces, "MakeHuman body");
        }
    }
    eprintln!("{path} not found: using a procedural ellipsoid body");
    let (v, f) = ellipsoid(100, 133, [0.25, 0.85, 0.15], [0.0, 0.9, 0.0]);
    (v, f, "ellipsoid body")
}

/// splitmix64.
fn next(state: &mut u64) -> f32 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

/// Garment-like points: random body vertices pushed along their normal by -1 cm .. +5 cm, in
/// a spatially coherent order (Morton order of 1 cm cells), as a garment's vertices come in mesh
/// order, neighbours close together.
fn garment_points(mesh: &BodyMesh, body: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let mut normals = vec![[0.0; 3]; body.len()];
    mesh.vertex_normals(body, &mut normals).unwrap();
    let mut s = 7u64;
    let mut points: Vec<[f32; 3]> = (0..N_GARMENT)
        .map(|_| {
            let i = ((next(&mut s) * body.len() as f32) as usize).min(body.len() - 1);
            let off = -0.01 + 0.06 * next(&mut s);
            [0, 1, 2].map(|a| body[i][a] + off * normals[i][a])
        })
        .collect();
    points.sort_by_key(|p| morton(*p));
    points
}

/// Morton code of the 1 cm cell of `p` (within 10.24 m of (-2, -2, -2) m).
fn morton(p: [f32; 3]) -> u64 {
    let c = p.map(|x| ((x + 2.0) * 100.0).clamp(0.0, 1023.0) as u64);
    let mut m = 0u64;
    for bit in 0..10 {
        for (a, c) in c.iter().enumerate() {
            m |= ((c >> bit) & 1) << (3 * bit + a);
        }
    }
    m
}

fn bench(c: &mut Criterion) {
    let (body, faces, what) = load_body();
    let mesh = BodyMesh::new(body.len(), &faces).unwrap();
    let garment = garment_points(&mesh, &body);
    let mut frame = BodyFrame::new(&mesh).unwrap();
    frame.update(&mesh, &body).unwrap();
    let mut edges = vec![None; garment.len()];
    let mut nearest = vec![Nearest { index: 0, distance: 0.0 }; garment.len()];
    let n_edges = frame.body_edges(&mesh, &garment, RADIUS, &mut edges).unwrap();
    eprintln!(
        "{what}: {} vertices, {} faces, {} garment points, {n_edges} body edges; vertex grid {:?} cells of {:.4} m, centroid grid {:?} cells of {:.4} m",
        body.len(),
        faces.len(),
        garment.len(),
        frame.vertex_grid().cells(),
        frame.vertex_grid().cell_size(),
        frame.centroid_grid().cells(),
        frame.centroid_grid().cell_size()
    );

    let mut g = c.benchmark_group("body_query");
    g.bench_function("rebuild_grids (centroids + 2 grids)", |b| {
        b.iter(|| frame.update_grids(&mesh, black_box(&body)).unwrap())
    });
    g.bench_function("body_edges r=0.03", |b| {
        b.iter(|| frame.body_edges(&mesh, black_box(&garment), RADIUS, &mut edges).unwrap())
    });
    g.bench_function("nearest_face_centroid", |b| {
        b.iter(|| frame.nearest_faces(black_box(&garment), &mut nearest).unwrap())
    });
    // Last frame's answers as hints: the garment 3 mm away from where it is now.
    let moved: Vec<[f32; 3]> = garment.iter().map(|p| [p[0] + 0.002, p[1] - 0.002, p[2] + 0.001]).collect();
    frame.nearest_faces(&moved, &mut nearest).unwrap();
    let face_hints: Vec<u32> = nearest.iter().map(|n| n.index).collect();
    frame.body_edges(&mesh, &moved, RADIUS, &mut edges).unwrap();
    let vertex_hints: Vec<u32> = edges.iter().map(|e| e.map_or(u32::MAX, |e| e.index)).collect();
    g.bench_function("nearest_face_centroid hinted", |b| {
        b.iter(|| frame.nearest_faces_hinted(black_box(&garment), &face_hints, &mut nearest).unwrap())
    });
    g.bench_function("whole body query", |b| {
        b.iter(|| {
            frame.update_grids(&mesh, black_box(&body)).unwrap();
            frame.body_edges(&mesh, &garment, RADIUS, &mut edges).unwrap();
            frame.nearest_faces(&garment, &mut nearest).unwrap();
        })
    });
    g.bench_function("whole body query hinted", |b| {
        b.iter(|| {
            frame.update_grids(&mesh, black_box(&body)).unwrap();
            frame.body_edges_hinted(&mesh, &garment, RADIUS, &vertex_hints, &mut edges).unwrap();
            frame.nearest_faces_hinted(&garment, &face_hints, &mut nearest).unwrap();
        })
    });
    // The same in one job of a 2-thread pool: both rebuilds side by side, each query chunk as soon
    // as its grid is ready.
    let pool = ThreadPool::new(2);
    let exec: &dyn Executor = &pool;
    for (name, exec, vh, fh) in [
        ("whole body query 2 threads", exec, &[][..], &[][..]),
        ("whole body query hinted 2 threads", exec, &vertex_hints[..], &face_hints[..]),
        (
            "whole body query hinted 1 thread, one job",
            &hood::sim::Serial as &dyn Executor,
            &vertex_hints[..],
            &face_hints[..],
        ),
    ] {
        let query = GarmentQuery { points: &garment, radius: RADIUS, vertex_hints: vh, face_hints: fh };
        g.bench_function(name, |b| {
            b.iter(|| {
                frame.update_and_query_on(exec, &mesh, black_box(&body), query, &mut edges, &mut nearest).unwrap()
            })
        });
    }
    // The separate calls on the same pool (three jobs: the rebuilds as two tasks, then each query).
    g.bench_function("whole body query hinted 2 threads, three jobs", |b| {
        b.iter(|| {
            frame.update_grids_on(exec, &mesh, black_box(&body)).unwrap();
            frame.body_edges_on(exec, &mesh, &garment, RADIUS, &vertex_hints, &mut edges).unwrap();
            frame.nearest_faces_on(exec, &garment, &face_hints, &mut nearest).unwrap();
        })
    });
    // What the runtime does per step (sim::Sim): the vertex grid and the body edges only, hinted
    // by last step's answers.
    let mut grid = PointGrid::new(body.len(), 8 * body.len()).unwrap();
    for (name, exec) in [
        ("runtime body edges hinted 1 thread", &hood::sim::Serial as &dyn Executor),
        ("runtime body edges hinted 2 threads", exec),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                grid.rebuild(black_box(&body)).unwrap();
                grid.nearest_within_on(exec, &garment, RADIUS, &vertex_hints, &mut edges).unwrap();
                mesh.keep_not_omitted(&mut edges)
            })
        });
    }
    // The same queries in random order: neighbouring queries far apart, so that tiles of eight
    // are not worth searching together and every query is searched on its own.
    let mut shuffled: Vec<usize> = (0..garment.len()).collect();
    let mut state = 11u64;
    for k in (1..shuffled.len()).rev() {
        shuffled.swap(k, ((next(&mut state) * (k + 1) as f32) as usize).min(k));
    }
    let scattered: Vec<[f32; 3]> = shuffled.iter().map(|&i| garment[i]).collect();
    let scattered_hints: Vec<u32> = shuffled.iter().map(|&i| vertex_hints[i]).collect();
    g.bench_function("runtime body edges hinted 1 thread scattered", |b| {
        b.iter(|| {
            grid.rebuild(black_box(&body)).unwrap();
            grid.nearest_within_on(&hood::sim::Serial, &scattered, RADIUS, &scattered_hints, &mut edges).unwrap();
            mesh.keep_not_omitted(&mut edges)
        })
    });
    g.bench_function("rebuild vertex grid", |b| b.iter(|| grid.rebuild(black_box(&body)).unwrap()));
    g.bench_function("update (centroids, normals, 2 grids)", |b| {
        b.iter(|| frame.update(&mesh, black_box(&body)).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
