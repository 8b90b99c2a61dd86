//! Garment preprocessing: `Garment::new` (validation, topology, rest frames, masses) plus
//! `Hierarchy::build` (centre candidates and three coarse levels), on procedural meshes of about
//! 1k, 4.4k and 12k vertices: flat grids and closed tubes (a sleeve-like shape whose centre
//! candidates fill a whole ring, the expensive case for the exact centre search).

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use hood::hierarchy::{Hierarchy, HierarchyConfig};
use hood::mesh::shapes::grid;
use hood::mesh::{Garment, GarmentDesc};

/// A tube of `around` x `along` vertices, radius 0.1 m, 1 m long along y, quads split along
/// alternating diagonals.
fn tube(around: usize, along: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut rest = Vec::with_capacity(around * along);
    for j in 0..along {
        for i in 0..around {
            let t = core::f32::consts::TAU * i as f32 / around as f32;
            rest.push([0.1 * t.cos(), j as f32 / (along - 1) as f32, 0.1 * t.sin()]);
        }
    }
    let id = |i: usize, j: usize| (j * around + i % around) as u32;
    let mut faces = Vec::with_capacity(2 * around * (along - 1));
    for j in 0..along - 1 {
        for i in 0..around {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                faces.extend([[a, c, b], [a, d, c]]);
            } else {
                faces.extend([[a, d, b], [b, d, c]]);
            }
        }
    }
    (rest, faces)
}

fn preprocess(rest: &[[f32; 3]], faces: &[[u32; 3]]) -> Hierarchy {
    let g = Garment::new(GarmentDesc::new(rest, faces)).expect("valid mesh");
    Hierarchy::build(&g, &HierarchyConfig::default()).expect("hierarchy")
}

fn bench_preprocess(c: &mut Criterion) {
    let mut group = c.benchmark_group("preprocess");
    group.sample_size(20);
    let meshes = [
        ("grid", grid(32, 32, 1.0, 1.0, 0.0)),
        ("grid", grid(66, 66, 1.0, 1.0, 0.0)),
        ("grid", grid(110, 110, 1.0, 1.0, 0.0)),
        ("tube", tube(32, 32)),
        ("tube", tube(64, 69)),
        ("tube", tube(96, 125)),
    ];
    for (name, (rest, faces)) in &meshes {
        group.bench_with_input(BenchmarkId::new(*name, rest.len()), &(rest, faces), |b, (rest, faces)| {
            b.iter(|| preprocess(black_box(rest), black_box(faces)))
        });
    }
    group.finish();

    // The two stages apart, at the largest grid.
    let (rest, faces) = grid(110, 110, 1.0, 1.0, 0.0);
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).expect("valid mesh");
    c.bench_function("preprocess/garment_new/12100", |b| {
        b.iter(|| Garment::new(GarmentDesc::new(black_box(&rest), black_box(&faces))))
    });
    c.bench_function("preprocess/hierarchy_build/12100", |b| {
        b.iter(|| Hierarchy::build(black_box(&g), &HierarchyConfig::default()))
    });
}

criterion_group!(benches, bench_preprocess);
criterion_main!(benches);
