use super::*;
use crate::mesh::shapes::grid;

fn quad() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    (vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]], vec![[0, 2, 1], [0, 3, 2]])
}

#[test]
fn garment_quad_topology() {
    let (rest, faces) = quad();
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    assert_eq!(g.edges(), &[[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]);
    assert_eq!(g.directed_edges().len(), 10);
    assert_eq!(g.hinges(), &[Hinge { edge: [0, 2], faces: [0, 1], opposite: [1, 3] }]);
    assert_eq!(g.boundary_loops().len(), 1);
    assert_eq!(g.boundary_loops()[0].len(), 4);
    assert_eq!(g.n_components(), 1);
    assert!((g.total_area() - 1.0).abs() < 1e-9);
    let m = Material::default().density;
    // Vertices 0 and 2 touch both triangles (area 1/2 each), 1 and 3 one.
    let want = [m / 3.0, m / 6.0, m / 3.0, m / 6.0];
    for (got, want) in g.vertex_mass().iter().zip(want) {
        assert!((got - want).abs() < 1e-7);
    }
}

#[test]
fn garment_directed_edges_are_csr_by_target() {
    let (rest, faces) = grid(7, 5, 1.0, 0.6, 0.0);
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    let t = g.topology();
    assert_eq!(t.directed.len(), 2 * t.edges.len());
    for v in 0..g.n_vertices() {
        let (lo, hi) = (t.in_offsets[v] as usize, t.in_offsets[v + 1] as usize);
        assert!(hi > lo);
        for e in &t.directed[lo..hi] {
            assert_eq!(e[1] as usize, v);
        }
        assert!(t.directed[lo..hi].windows(2).all(|w| w[0][0] < w[1][0]));
    }
}

#[test]
fn garment_grid_counts_and_euler() {
    let (rest, faces) = grid(10, 8, 1.0, 1.0, 0.5);
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    // V - E + F = 1 for a disc.
    assert_eq!(g.n_vertices() as i64 - g.edges().len() as i64 + faces.len() as i64, 1);
    let boundary = g.edges().len() - g.hinges().len();
    assert_eq!(boundary, 2 * (9 + 7));
    assert_eq!(g.boundary_loops().len(), 1);
    assert_eq!(g.boundary_loops()[0].len(), boundary);
    // Normals of a flat grid with CCW faces seen from +y point up.
    let mut n = vec![[0.0; 3]; g.n_vertices()];
    g.normals_into(g.rest(), &mut n).unwrap();
    assert!(n.iter().all(|v| (v[1] - 1.0).abs() < 1e-6));
    // Rest frames map the rest triangle to an isometry: F = Ds Dm^-1 has F^T F = I.
    for (f, d) in faces.iter().zip(g.dm_inv()) {
        let x = f.map(|i| rest[i as usize]);
        let ds = |r: usize, c: usize| x[c][r] - x[2][r];
        let mut ftf = [[0.0f32; 2]; 2];
        let fcol = |r: usize, c: usize| ds(r, 0) * d[0][c] + ds(r, 1) * d[1][c];
        for a in 0..2 {
            for b in 0..2 {
                ftf[a][b] = (0..3).map(|r| fcol(r, a) * fcol(r, b)).sum();
            }
        }
        assert!((ftf[0][0] - 1.0).abs() < 1e-5 && (ftf[1][1] - 1.0).abs() < 1e-5 && ftf[0][1].abs() < 1e-5);
    }
}

#[test]
fn garment_components_are_found() {
    let (mut rest, mut faces) = grid(4, 4, 1.0, 1.0, 0.0);
    let (r2, f2) = grid(3, 3, 0.5, 0.5, 1.0);
    let off = rest.len() as u32;
    rest.extend(r2);
    faces.extend(f2.iter().map(|f| f.map(|v| v + off)));
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    assert_eq!(g.n_components(), 2);
    assert!(g.component_of()[..16].iter().all(|&c| c == 0));
    assert!(g.component_of()[16..].iter().all(|&c| c == 1));
    assert_eq!(g.boundary_loops().len(), 2);
}

#[test]
fn garment_non_manifold_edge_is_recorded() {
    // Three triangles on the edge (0, 1).
    let rest = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -1.0, 0.0], [0.5, 0.0, 1.0]];
    let faces = [[0, 1, 2], [1, 0, 3], [0, 1, 4]];
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    assert_eq!(g.topology().non_manifold_edges.len(), 1);
    let e = g.topology().non_manifold_edges[0] as usize;
    assert_eq!(g.edges()[e], [0, 1]);
    let h = g.hinges().iter().find(|h| h.edge == [0, 1]).unwrap();
    assert_eq!(h.faces, [0, 1]);
}

#[test]
fn garment_bad_input_names_the_index() {
    let (rest, faces) = quad();
    let bad = [[0, 2, 1], [0, 3, 7]];
    assert_eq!(
        Garment::new(GarmentDesc::new(&rest, &bad)).unwrap_err(),
        Error::IndexOutOfRange { what: "face", at: 1, index: 7, len: 4 }
    );
    let bad = [[0, 2, 1], [3, 3, 2]];
    assert_eq!(Garment::new(GarmentDesc::new(&rest, &bad)).unwrap_err(), Error::RepeatedVertex { face: 1, vertex: 3 });
    let mut nan = rest.clone();
    nan[2][1] = f32::NAN;
    assert_eq!(
        Garment::new(GarmentDesc::new(&nan, &faces)).unwrap_err(),
        Error::NonFinite { what: "rest position", index: 2 }
    );
    let mut flat = rest.clone();
    flat.push([2.0, 0.0, 0.0]);
    let line = [[0, 2, 1], [0, 3, 2], [0, 1, 4]];
    assert_eq!(Garment::new(GarmentDesc::new(&flat, &line)).unwrap_err(), Error::DegenerateFace { face: 2 });
    assert_eq!(Garment::new(GarmentDesc::new(&flat, &faces)).unwrap_err(), Error::UnusedVertex { vertex: 4 });
    assert_eq!(Garment::new(GarmentDesc::new(&rest, &[])).unwrap_err(), Error::Empty { what: "garment faces" });
    let two = [Material::default(); 2];
    assert!(matches!(
        Garment::new(GarmentDesc::new(&rest, &faces).materials(&two)).unwrap_err(),
        Error::SizeMismatch { what: "materials", expected: 4, got: 2 }
    ));
    let neg = [Material { mu: -1.0, ..Material::default() }];
    assert!(matches!(
        Garment::new(GarmentDesc::new(&rest, &faces).materials(&neg)).unwrap_err(),
        Error::OutOfRange { what: "material", .. }
    ));
    // Well shaped, but out of f32's range: a rest frame (edges of 1e-39 m) or an area (1e30 m)
    // that overflows, a mass that does (1e18 m of cloth at 1e10 kg/m²).
    let scaled = |k: f32| rest.iter().map(|p| p.map(|c| c * k)).collect::<Vec<_>>();
    for k in [1e-39, 1e30] {
        let err = Garment::new(GarmentDesc::new(&scaled(k), &faces)).unwrap_err();
        assert_eq!(err, Error::DegenerateFace { face: 0 }, "scale {k}");
    }
    let dense = [Material { density: 1e10, ..Material::default() }];
    assert!(matches!(
        Garment::new(GarmentDesc::new(&scaled(1e18), &faces).materials(&dense)).unwrap_err(),
        Error::OutOfRange { what: "vertex mass (area times density out of f32's range)", .. }
    ));
}

#[test]
fn garment_repairs_return_what_they_did() {
    let (mut rest, _) = quad();
    rest.push([2.0, 0.0, 0.0]); // 4: on the line through 0 and 1
    rest.push([9.0, 9.0, 9.0]); // 5: unused
    let faces = [[0, 2, 1], [0, 1, 4], [0, 3, 2], [1, 1, 2]];
    let d = repair::drop_degenerate_faces(&rest, &faces);
    assert_eq!(d.dropped, vec![1, 3]);
    let c = repair::drop_unused_vertices(&rest, &d.faces);
    assert_eq!(c.remap.new_to_old, vec![0, 1, 2, 3]);
    assert_eq!(c.remap.old_to_new[4], None);
    assert_eq!(c.remap.old_to_new[5], None);
    let g = Garment::new(GarmentDesc::new(&c.rest, &c.faces)).unwrap();
    assert_eq!(g.n_vertices(), 4);
    // A remap that moves indices.
    let faces = [[1, 3, 2], [1, 4, 3]];
    let c = repair::drop_unused_vertices(&rest, &faces);
    assert_eq!(c.faces, vec![[0, 2, 1], [0, 3, 2]]);
    assert_eq!(c.remap.apply(&[10, 11, 12, 13, 14, 15]), vec![11, 12, 13, 14]);
}

#[test]
fn garment_per_vertex_materials_set_masses() {
    let (rest, faces) = quad();
    let mats: Vec<Material> =
        (0..4).map(|i| Material { density: 0.1 * (i + 1) as f32, ..Material::default() }).collect();
    let g = Garment::new(GarmentDesc::new(&rest, &faces).materials(&mats)).unwrap();
    let area = [1.0 / 3.0, 1.0 / 6.0, 1.0 / 3.0, 1.0 / 6.0];
    for i in 0..4 {
        assert!((g.vertex_mass()[i] - mats[i].density * area[i]).abs() < 1e-7);
    }
}

#[test]
fn garment_subdivision_counts_and_area() {
    let (rest, faces) = grid(5, 4, 1.0, 1.0, 0.0);
    let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    let (r2, f2) = shapes::subdivide(&rest, &faces);
    let g2 = Garment::new(GarmentDesc::new(&r2, &f2)).unwrap();
    assert_eq!(g2.n_vertices(), g.n_vertices() + g.edges().len());
    assert_eq!(f2.len(), 4 * faces.len());
    assert!((g2.total_area() - g.total_area()).abs() < 1e-6);
    let mut n = vec![[0.0; 3]; g2.n_vertices()];
    g2.normals_into(&r2, &mut n).unwrap();
    assert!(n.iter().all(|v| (v[1] - 1.0).abs() < 1e-6), "orientation kept");
}

#[test]
fn garment_beyond_the_vertex_bound_is_refused_before_it_is_read() {
    // Zeroed memory the check refuses without touching it (the allocator maps it lazily).
    let rest = vec![[0.0f32; 3]; crate::limits::MAX_VERTICES + 1];
    let e = Garment::new(GarmentDesc::new(&rest, &[[0, 1, 2]])).unwrap_err();
    let needed = crate::limits::MAX_VERTICES + 1;
    assert_eq!(e, Error::CapacityExceeded { what: "garment vertices", capacity: crate::limits::MAX_VERTICES, needed });
}
