use super::shapes::ellipsoid;
use super::*;
use crate::mesh::vertex_normals;

/// splitmix64: a tiny seeded generator.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.unit()
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn dir(&mut self) -> [f32; 3] {
        loop {
            let v = [self.range(-1.0, 1.0), self.range(-1.0, 1.0), self.range(-1.0, 1.0)];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 0.1 && l <= 1.0 {
                return v.map(|c| c / l);
            }
        }
    }
}

fn d2(p: [f32; 3], q: [f32; 3]) -> f32 {
    let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
    dx * dx + dy * dy + dz * dz
}

/// Brute force with the documented rule: squared f32 distance `<= limit2`, lowest index on ties.
fn brute(points: &[[f32; 3]], q: [f32; 3], limit2: f32) -> Option<Nearest> {
    let mut best: Option<(u32, f32)> = None;
    for (i, p) in points.iter().enumerate() {
        let d = d2(*p, q);
        if d <= limit2 && best.is_none_or(|(_, b)| d < b) {
            best = Some((i as u32, d));
        }
    }
    best.map(|(index, d)| Nearest { index, distance: d.sqrt() })
}

/// Random point sets of different shapes, around a random offset.
fn random_cloud(rng: &mut Rng, kind: usize, n: usize) -> Vec<[f32; 3]> {
    let off = [rng.range(-5.0, 5.0), rng.range(-5.0, 5.0), rng.range(-5.0, 5.0)];
    let mut pts = Vec::with_capacity(n);
    for _ in 0..n {
        let p = match kind {
            // Filled box.
            0 => [rng.range(0.0, 0.6), rng.range(0.0, 1.7), rng.range(0.0, 0.3)],
            // Sphere surface (a body-like 2-manifold).
            1 => rng.dir().map(|c| 0.4 * c),
            // Flat: all in one plane.
            2 => [rng.range(-1.0, 1.0), 0.25, rng.range(-0.5, 0.5)],
            // A line.
            3 => [rng.range(-1.0, 1.0), 0.0, 0.0],
            // A few tight clusters far apart, with exact duplicates.
            _ => {
                let c = [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, -2.0, 1.0]][rng.below(3)];
                let q = [(rng.below(5) as f32) * 0.01, (rng.below(5) as f32) * 0.01, 0.0];
                [c[0] + q[0], c[1] + q[1], c[2] + q[2]]
            }
        };
        pts.push([p[0] + off[0], p[1] + off[1], p[2] + off[2]]);
    }
    pts
}

/// Queries inside the bounds, near them and far outside.
fn random_queries(rng: &mut Rng, points: &[[f32; 3]], n: usize) -> Vec<[f32; 3]> {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let mut qs = Vec::with_capacity(n);
    for i in 0..n {
        let q = match i % 4 {
            0 => [0, 1, 2].map(|a| rng.range(lo[a], hi[a])),
            1 => {
                let p = points[rng.below(points.len())];
                let d = rng.dir();
                let r = rng.range(0.0, 0.05);
                [0, 1, 2].map(|a| p[a] + r * d[a])
            }
            2 => [0, 1, 2].map(|a| rng.range(lo[a] - 0.5, hi[a] + 0.5)),
            _ => {
                let d = rng.dir();
                let r = [3.0, 30.0, 1000.0][rng.below(3)];
                [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]) + r * d[a])
            }
        };
        qs.push(q);
    }
    qs
}

#[test]
fn body_query_nearest_matches_brute_force() {
    let mut rng = Rng(1);
    let mut grid = PointGrid::new(3000, 20_000).unwrap();
    for round in 0..40 {
        let kind = round % 5;
        let n = [1, 2, 7, 300, 3000][rng.below(5)];
        let pts = random_cloud(&mut rng, kind, n);
        grid.set_cells_per_point([0.05, 0.5, 2.0, 8.0][round % 4]).unwrap();
        grid.rebuild(&pts).unwrap();
        let qs = random_queries(&mut rng, &pts, 400);
        let mut out = vec![Nearest { index: 0, distance: 0.0 }; qs.len()];
        grid.nearest(&qs, &mut out).unwrap();
        for (q, got) in qs.iter().zip(&out) {
            let want = brute(&pts, *q, f32::INFINITY).unwrap();
            assert_eq!(got.index, want.index, "round {round} kind {kind} n {n} query {q:?}: {got:?} vs {want:?}");
            assert_eq!(got.distance, want.distance);
        }
        // Any hint (right, wrong, far, invalid) gives the same answer.
        let hints: Vec<u32> = (0..qs.len())
            .map(|k| match k % 4 {
                0 => out[k].index,
                1 => rng.below(n) as u32,
                2 => u32::MAX,
                _ => n as u32 + 3,
            })
            .collect();
        let mut hinted = vec![Nearest { index: 0, distance: 0.0 }; qs.len()];
        grid.nearest_hinted(&qs, &hints, &mut hinted).unwrap();
        assert_eq!(hinted, out, "round {round}: hints changed the result");
        let mut within = vec![None; qs.len()];
        let mut within_hinted = vec![None; qs.len()];
        grid.nearest_within(&qs, 0.05, &mut within).unwrap();
        grid.nearest_within_hinted(&qs, 0.05, &hints, &mut within_hinted).unwrap();
        assert_eq!(within, within_hinted, "round {round}: hints changed the radius result");
        assert!(matches!(grid.nearest_hinted(&qs, &hints[1..], &mut hinted), Err(Error::SizeMismatch { .. })));
    }
}

#[test]
fn body_query_within_radius_matches_brute_force() {
    let mut rng = Rng(2);
    let mut grid = PointGrid::new(3000, 20_000).unwrap();
    for round in 0..40 {
        let kind = round % 5;
        let n = [1, 5, 300, 3000][rng.below(4)];
        let pts = random_cloud(&mut rng, kind, n);
        grid.set_cells_per_point([0.05, 0.5, 2.0, 8.0][round % 4]).unwrap();
        grid.rebuild(&pts).unwrap();
        let qs = random_queries(&mut rng, &pts, 400);
        let mut out = vec![None; qs.len()];
        for r in [0.0, 0.01, 0.03, 0.2, 2.0] {
            grid.nearest_within(&qs, r, &mut out).unwrap();
            let mut found = 0;
            for (q, got) in qs.iter().zip(&out) {
                let want = brute(&pts, *q, r * r);
                assert_eq!(*got, want, "round {round} kind {kind} n {n} r {r} query {q:?}");
                found += got.is_some() as usize;
            }
            if r >= 0.03 && kind != 4 {
                assert!(found > 0, "round {round}: no query found a point within {r}");
            }
        }
    }
}

#[test]
fn body_query_radius_is_inclusive() {
    let r = 0.03f32;
    // Points exactly r away along each axis, and one a hair farther.
    let q = [1.0f32, 2.0, 3.0];
    let far = f32::from_bits((q[0] + r).to_bits() + 1);
    let pts = vec![[far, q[1], q[2]], [q[0], q[1] + r, q[2]], [q[0], q[1], q[2] - r], [q[0] - 0.5, q[1], q[2]]];
    let mut grid = PointGrid::new(8, 64).unwrap();
    grid.rebuild(&pts).unwrap();
    let mut out = [None];
    // Both 1 and 2 are at distance r exactly (in f32); the lower index wins.
    let exact = d2(pts[1], q);
    assert_eq!(exact, d2(pts[2], q));
    assert!(d2(pts[0], q) > exact);
    grid.nearest_within(&[q], crate::math::sqrt_f32(exact), &mut out).unwrap();
    assert_eq!(out[0].map(|n| n.index), Some(1));
    // Just below: nothing.
    grid.nearest_within(&[q], f32::from_bits(crate::math::sqrt_f32(exact).to_bits() - 1), &mut out).unwrap();
    assert_eq!(out[0], None, "a radius below the distance must find nothing");
    // Without point 1, the equally distant point 2 is found, never the farther point 0.
    grid.rebuild(&[pts[0], pts[3], pts[2]]).unwrap();
    grid.nearest_within(&[q], r, &mut out).unwrap();
    assert_eq!(out[0].map(|n| n.index), (d2(pts[2], q) <= r * r).then_some(2));
}

#[test]
fn body_query_ties_take_lowest_index() {
    // Duplicates and a symmetric configuration; the order of the points is shuffled so that the
    // winner is not simply the first point sorted into the cell.
    let mut grid = PointGrid::new(16, 4096).unwrap();
    let pts = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 5.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]];
    grid.rebuild(&pts).unwrap();
    assert_eq!(grid.nearest_one([0.0, 0.0, 0.0]).unwrap().index, 0);
    assert_eq!(grid.nearest_one([-1.0, 0.0, 0.0]).unwrap().index, 1);
    assert_eq!(grid.nearest_within_one([0.0, 0.0, 0.0], 1.0).unwrap().index, 0);
    let rev: Vec<_> = pts.iter().rev().copied().collect();
    grid.rebuild(&rev).unwrap();
    assert_eq!(grid.nearest_one([0.0, 0.0, 0.0]).unwrap().index, 0); // (-1,0,0) is index 0 now
    assert_eq!(grid.nearest_one([1.0, 0.0, 0.0]).unwrap().index, 1);
    assert_eq!(grid.nearest_one([0.0, 1e6, 0.0]).unwrap().index, 2);
}

#[test]
fn body_query_empty_and_errors() {
    let mut grid = PointGrid::new(4, 64).unwrap();
    assert!(grid.is_empty());
    let mut near = [Nearest { index: 0, distance: 0.0 }];
    assert_eq!(grid.nearest(&[[0.0; 3]], &mut near), Err(Error::Empty { what: "point grid" }));
    let mut within = [Some(Nearest { index: 0, distance: 0.0 })];
    grid.nearest_within(&[[0.0; 3]], 1.0, &mut within).unwrap();
    assert_eq!(within[0], None);
    // Empty rebuild after a non-empty one empties the grid.
    grid.rebuild(&[[0.0; 3]]).unwrap();
    assert_eq!(grid.nearest_one([1.0, 0.0, 0.0]).map(|n| n.distance), Some(1.0));
    grid.rebuild(&[]).unwrap();
    assert_eq!(grid.nearest_one([1.0, 0.0, 0.0]), None);
    // Far beyond the radius: none; everything at one spot: found.
    grid.rebuild(&[[0.0; 3], [0.0; 3], [0.0; 3]]).unwrap();
    assert_eq!(grid.nearest_within_one([0.0, 0.0, 0.031], 0.03), None);
    assert_eq!(grid.nearest_within_one([0.0, 0.0, 0.02], 0.03).map(|n| n.index), Some(0));

    assert_eq!(
        grid.rebuild(&[[0.0; 3]; 5]),
        Err(Error::CapacityExceeded { what: "grid points", capacity: 4, needed: 5 })
    );
    assert!(grid.is_empty(), "a failed rebuild leaves the grid empty");
    assert_eq!(grid.rebuild(&[[0.0; 3], [f32::NAN, 0.0, 0.0]]), Err(Error::NonFinite { what: "grid point", index: 1 }));
    // The bounds are taken eight points at a time: a bad coordinate in a full group, in the
    // remainder, on every axis, is found and named; the good points' bounds are exact.
    let mut big = PointGrid::new(100, 6400).unwrap();
    let mut rng = Rng(5);
    for n in [1, 8, 9, 24, 61] {
        let pts = random_cloud(&mut rng, 0, n);
        big.rebuild(&pts).unwrap();
        for a in 0..3 {
            let want = (
                pts.iter().map(|p| p[a]).fold(f32::INFINITY, f32::min),
                pts.iter().map(|p| p[a]).fold(f32::NEG_INFINITY, f32::max),
            );
            assert_eq!((big.bounds().0[a], big.bounds().1[a]), want, "n {n} axis {a}");
        }
        for k in [0, n / 2, n - 1] {
            for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
                for a in 0..3 {
                    let mut p = pts.clone();
                    p[k][a] = bad;
                    assert_eq!(
                        big.rebuild(&p),
                        Err(Error::NonFinite { what: "grid point", index: k }),
                        "n {n} at {k} axis {a} {bad}"
                    );
                }
            }
        }
    }
    grid.rebuild(&[[0.0; 3]]).unwrap();
    let qs = [[0.0; 3], [0.0, f32::INFINITY, 0.0]];
    let mut out2 = [None; 2];
    assert_eq!(grid.nearest_within(&qs, 1.0, &mut out2), Err(Error::NonFinite { what: "query point", index: 1 }));
    assert_eq!(
        grid.nearest_within(&qs[..1], -1.0, &mut out2[..1]),
        Err(Error::OutOfRange { what: "query radius", index: 0 })
    );
    assert!(matches!(
        grid.nearest_within(&qs, 1.0, &mut out2[..1]),
        Err(Error::SizeMismatch { expected: 2, got: 1, .. })
    ));
    assert!(matches!(PointGrid::new(4, 63), Err(Error::OutOfRange { .. })));
}

#[test]
fn body_query_grid_respects_max_cells_and_follows_points() {
    let mut rng = Rng(3);
    let mut grid = PointGrid::new(5000, 1000).unwrap();
    let mut pts = random_cloud(&mut rng, 0, 5000);
    grid.rebuild(&pts).unwrap();
    let c = grid.cells();
    assert!(c[0] * c[1] * c[2] <= 1000, "{c:?}");
    let (lo0, hi0) = grid.bounds();
    // Move the whole set far away: the bounds follow.
    for p in &mut pts {
        p[0] += 100.0;
    }
    grid.rebuild(&pts).unwrap();
    let (lo, hi) = grid.bounds();
    assert!((lo[0] - lo0[0] - 100.0).abs() < 1e-4 && (hi[0] - hi0[0] - 100.0).abs() < 1e-4, "{lo:?} {hi:?}");
    assert_eq!((lo[1], hi[2]), (lo0[1], hi0[2]));
    let q = [lo[0] - 50.0, 0.0, 0.0];
    assert_eq!(grid.nearest_one(q), brute(&pts, q, f32::INFINITY));
}

#[test]
fn body_query_mesh_validation_names_the_index() {
    let f = [[0, 1, 2], [0, 2, 3]];
    assert!(BodyMesh::new(4, &f).is_ok());
    assert_eq!(BodyMesh::new(0, &f), Err(Error::Empty { what: "body vertices" }));
    assert_eq!(BodyMesh::new(4, &[]), Err(Error::Empty { what: "body faces" }));
    assert_eq!(BodyMesh::new(3, &f), Err(Error::IndexOutOfRange { what: "body face", at: 1, index: 3, len: 3 }));
    assert_eq!(BodyMesh::new(4, &[[0, 1, 2], [2, 3, 2]]), Err(Error::RepeatedVertex { face: 1, vertex: 2 }));
    assert_eq!(BodyMesh::new(4, &[[1, 1, 2]]), Err(Error::RepeatedVertex { face: 0, vertex: 1 }));
    let m = BodyMesh::new(4, &f).unwrap();
    assert!(matches!(m.clone().with_omitted(&[false; 3]), Err(Error::SizeMismatch { expected: 4, got: 3, .. })));
    assert_eq!(m.check_positions(&[[0.0; 3]; 3]).unwrap_err().code(), 7);
    assert_eq!(
        m.check_positions(&[[0.0; 3], [0.0; 3], [0.0, 0.0, f32::NAN], [0.0; 3]]),
        Err(Error::NonFinite { what: "body vertex", index: 2 })
    );
}

#[test]
fn body_query_geometry_of_an_ellipsoid() {
    let c = [0.1, 1.0, -0.2];
    let (v, f) = ellipsoid(12, 20, [0.3, 0.5, 0.2], c);
    assert_eq!(v.len(), 2 + 12 * 20);
    assert_eq!(f.len(), 2 * 12 * 20);
    let mesh = BodyMesh::new(v.len(), &f).unwrap();
    let mut cen = vec![[0.0; 3]; f.len()];
    let mut fnrm = vec![[0.0; 3]; f.len()];
    let mut vn = vec![[0.0; 3]; v.len()];
    mesh.face_centroids(&v, &mut cen).unwrap();
    mesh.face_normals(&v, &mut fnrm).unwrap();
    mesh.vertex_normals(&v, &mut vn).unwrap();
    let mut vol = 0.0f64;
    for (i, tri) in f.iter().enumerate() {
        let [a, b, cc] = tri.map(|k| v[k as usize]);
        for ax in 0..3 {
            // Bit for bit the documented formula (the divisions run as a separate pass).
            assert_eq!(cen[i][ax], (a[ax] + b[ax] + cc[ax]) / 3.0);
        }
        let n = fnrm[i];
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-5);
        let out = [cen[i][0] - c[0], cen[i][1] - c[1], cen[i][2] - c[2]];
        assert!(n[0] * out[0] + n[1] * out[1] + n[2] * out[2] > 0.0, "face {i} normal points inwards");
        // Signed volume (closed, outward faces: positive).
        let det = a[0] as f64 * (b[1] as f64 * cc[2] as f64 - b[2] as f64 * cc[1] as f64)
            - a[1] as f64 * (b[0] as f64 * cc[2] as f64 - b[2] as f64 * cc[0] as f64)
            + a[2] as f64 * (b[0] as f64 * cc[1] as f64 - b[1] as f64 * cc[0] as f64);
        vol += det / 6.0;
    }
    let exact = 4.0 / 3.0 * core::f64::consts::PI * 0.3 * 0.5 * 0.2;
    assert!(vol > 0.9 * exact && vol < exact, "volume {vol} vs {exact}");
    let mut want = vec![[0.0; 3]; v.len()];
    vertex_normals(&f, &v, &mut want);
    assert_eq!(vn, want);
    // A degenerate face gets a zero normal, not NaN.
    let flat = [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
    let m = BodyMesh::new(3, &[[0, 1, 2]]).unwrap();
    let mut n1 = [[9.0; 3]];
    m.face_normals(&flat, &mut n1).unwrap();
    assert_eq!(n1, [[0.0; 3]]);
    assert!(matches!(m.face_normals(&flat, &mut []), Err(Error::SizeMismatch { .. })));
    assert!(matches!(m.face_centroids(&flat[..2], &mut n1), Err(Error::SizeMismatch { .. })));
}

#[test]
fn body_query_frame_matches_brute_force_with_omitted_vertices() {
    let mut rng = Rng(4);
    let (v, f) = ellipsoid(40, 60, [0.25, 0.8, 0.15], [0.0, 1.0, 0.0]);
    // Omit the lower third (a stand-in for the hands).
    let omitted: Vec<bool> = v.iter().map(|p| p[1] < 0.6).collect();
    let mesh = BodyMesh::new(v.len(), &f).unwrap().with_omitted(&omitted).unwrap();
    let mut frame = BodyFrame::new(&mesh).unwrap();
    let mut positions = v.clone();
    let n_garment = 2000;
    let mut edges = vec![None; n_garment];
    let mut faces = vec![Nearest { index: 0, distance: 0.0 }; n_garment];
    for step in 0..3 {
        // Move the body: translate and wobble.
        for p in positions.iter_mut() {
            p[0] += 0.3;
            p[2] += 0.02 * (p[1] * 7.0 + step as f32).sin();
        }
        frame.update(&mesh, &positions).unwrap();
        let garment = random_queries(&mut rng, &positions, n_garment);
        let r = 0.03;
        let kept = frame.body_edges(&mesh, &garment, r, &mut edges).unwrap();
        let (mut n_raw, mut n_omitted) = (0, 0);
        for (g, got) in garment.iter().zip(&edges) {
            let raw = brute(&positions, *g, r * r);
            n_raw += raw.is_some() as usize;
            // MODEL.md: the nearest vertex overall decides; no fallback to the second nearest.
            let want = raw.filter(|n| !omitted[n.index as usize]);
            n_omitted += (raw.is_some() && want.is_none()) as usize;
            assert_eq!(*got, want, "step {step} garment point {g:?}");
        }
        assert_eq!(kept, edges.iter().filter(|e| e.is_some()).count());
        assert!(
            kept > 0 && n_omitted > 0,
            "the test must see both kept and omitted edges ({kept}, {n_omitted}, {n_raw})"
        );
        // Last frame's answers as hints (the first frame: none).
        let hints: Vec<u32> = if step == 0 { vec![] } else { faces.iter().map(|f| f.index).collect() };
        let edge_hints: Vec<u32> = edges.iter().map(|e| e.map_or(u32::MAX, |e| e.index)).collect();
        frame.nearest_faces_hinted(&garment, &hints, &mut faces).unwrap();
        for (g, got) in garment.iter().zip(&faces) {
            assert_eq!(Some(*got), brute(frame.centroids(), *g, f32::INFINITY));
        }
        let mut edges2 = vec![None; n_garment];
        assert_eq!(frame.body_edges_hinted(&mesh, &garment, r, &edge_hints, &mut edges2).unwrap(), kept);
        assert_eq!(edges2, edges);
    }
    assert_eq!(
        frame.update(&mesh, &positions[1..]),
        Err(Error::SizeMismatch { what: "body positions", expected: v.len(), got: v.len() - 1 })
    );
    positions[7][1] = f32::NAN;
    assert_eq!(frame.update(&mesh, &positions), Err(Error::NonFinite { what: "body vertex", index: 7 }));
}

#[test]
fn body_query_omitted_nearest_has_no_fallback() {
    // Vertex 0 is nearest and omitted; vertex 1 is also within the radius but must not be used.
    let v = [[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let mesh = BodyMesh::new(3, &[[0, 1, 2]]).unwrap().with_omitted(&[true, false, false]).unwrap();
    let mut frame = BodyFrame::new(&mesh).unwrap();
    frame.update(&mesh, &v).unwrap();
    let g = [[0.001, 0.0, 0.0], [0.019, 0.0, 0.0], [0.5, 0.5, 0.0]];
    let mut raw = [None; 3];
    frame.vertex_grid().nearest_within(&g, 0.03, &mut raw).unwrap();
    assert_eq!(raw.map(|n| n.map(|n| n.index)), [Some(0), Some(1), None]);
    let mut out = [None; 3];
    assert_eq!(frame.body_edges(&mesh, &g, 0.03, &mut out).unwrap(), 1);
    assert_eq!(out.map(|n| n.map(|n| n.index)), [None, Some(1), None]);
}

#[test]
fn body_query_avx2_scan_matches_portable_twin() {
    // The 8-wide AVX2 scans (where the CPU has them) against the portable lanes on fresh random
    // inputs; both against brute force. Without AVX2 both grids run the portable code.
    let mut rng = Rng(5);
    let mut fast = PointGrid::new(4000, 40_000).unwrap();
    let mut portable = PointGrid::new(4000, 40_000).unwrap();
    portable.force_portable();
    for round in 0..30 {
        let kind = round % 5;
        let n = [3, 9, 17, 500, 4000][rng.below(5)];
        let pts = random_cloud(&mut rng, kind, n);
        let cpp = [0.1, 1.0, 4.0][round % 3];
        fast.set_cells_per_point(cpp).unwrap();
        portable.set_cells_per_point(cpp).unwrap();
        fast.rebuild(&pts).unwrap();
        portable.rebuild(&pts).unwrap();
        let qs = random_queries(&mut rng, &pts, 300);
        let hints: Vec<u32> = (0..qs.len()).map(|_| rng.below(n + 2) as u32).collect();
        let mut a = vec![Nearest { index: 0, distance: 0.0 }; qs.len()];
        let mut b = a.clone();
        fast.nearest_hinted(&qs, &hints, &mut a).unwrap();
        portable.nearest_hinted(&qs, &hints, &mut b).unwrap();
        assert_eq!(a, b, "round {round}: nearest differs between AVX2 and portable scans");
        for (q, got) in qs.iter().zip(&a) {
            assert_eq!(Some(*got), brute(&pts, *q, f32::INFINITY), "round {round} query {q:?}");
        }
        for r in [0.02, 0.3] {
            let mut wa = vec![None; qs.len()];
            let mut wb = wa.clone();
            fast.nearest_within(&qs, r, &mut wa).unwrap();
            portable.nearest_within_hinted(&qs, r, &hints, &mut wb).unwrap();
            assert_eq!(wa, wb, "round {round} r {r}: radius query differs");
            for (q, got) in qs.iter().zip(&wa) {
                assert_eq!(*got, brute(&pts, *q, r * r), "round {round} r {r} query {q:?}");
            }
        }
    }
}

#[test]
fn body_query_vectorized_cell_slots_match_cell_of() {
    // The rebuild's slot pass (eight points per step; AVX2 where the CPU has it) against the
    // scalar cell assignment, point by point: random grids, points inside, outside on every side
    // (clamped), non-finite coordinates, and counts that leave every tail length.
    use grid::{cell_of, SlotsOf, BLOCK};
    let mut rng = Rng(11);
    for round in 0..300 {
        let blocks = [1 + rng.below(40), 1 + rng.below(40), 1 + rng.below(12)];
        let lo = [rng.range(-3.0, 3.0), rng.range(-3.0, 3.0), rng.range(-3.0, 3.0)];
        let inv_edge = [rng.range(0.5, 60.0), rng.range(0.5, 60.0), rng.range(0.5, 60.0)];
        let ext: [f32; 3] = core::array::from_fn(|a| (blocks[a] * BLOCK) as f32 / inv_edge[a]);
        let n = [0, 1, 7, 8, 9, 15, 23, 24, 25, 1000][round % 10];
        let pts: Vec<[f32; 3]> = (0..n)
            .map(|_| {
                core::array::from_fn(|a| match rng.below(40) {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => f32::NEG_INFINITY,
                    _ => lo[a] + ext[a] * rng.range(-0.3, 1.3),
                })
            })
            .collect();
        let dims = blocks.map(|b| b * BLOCK);
        let want: Vec<u32> = pts
            .iter()
            .map(|p| {
                let c = cell_of(*p, lo, inv_edge, blocks);
                (c[0] + dims[0] * (c[1] + dims[1] * c[2])) as u32
            })
            .collect();
        let slots = SlotsOf { lo, inv_edge, blocks };
        let mut got = vec![u32::MAX; n];
        slots.write(&pts, &mut got);
        assert_eq!(got, want, "round {round}: portable slots");
        #[cfg(target_arch = "x86_64")]
        if grid::has_avx2() {
            got.fill(u32::MAX);
            // SAFETY: the CPU has AVX2.
            unsafe { slots.write_avx2(&pts, &mut got) };
            assert_eq!(got, want, "round {round}: AVX2 slots");
        }
    }
}

#[test]
fn body_query_scans_past_a_range_read_only_real_points() {
    // A scan reads whole groups of eight, past the end of its cells: after a large rebuild and a
    // small one, the stale points of the large one (indices beyond the small set) must never be
    // answered; duplicates spread over many lanes still give the lowest index.
    let mut rng = Rng(6);
    for portable in [false, true] {
        let mut grid = PointGrid::new(2000, 20_000).unwrap();
        if portable {
            grid.force_portable();
        }
        let big = random_cloud(&mut rng, 0, 2000);
        grid.rebuild(&big).unwrap();
        let small: Vec<[f32; 3]> = big[..5].to_vec();
        grid.rebuild(&small).unwrap();
        for q in random_queries(&mut rng, &big, 200) {
            let got = grid.nearest_one(q);
            assert_eq!(got, brute(&small, q, f32::INFINITY));
            assert!(got.unwrap().index < 5);
            assert_eq!(grid.nearest_within_one(q, 0.5), brute(&small, q, 0.25));
        }
        // 40 copies of one point among 60 others, at scattered indices.
        let mut pts = random_cloud(&mut rng, 1, 100);
        let dup = [0.123, 0.456, 0.789];
        let copies: Vec<usize> = (0..100).filter(|k| k % 5 < 2).collect();
        for &k in &copies {
            pts[k] = dup;
        }
        grid.rebuild(&pts).unwrap();
        let q = [dup[0] + 0.001, dup[1], dup[2]];
        assert_eq!(grid.nearest_one(q).map(|n| n.index), Some(copies[0] as u32));
        assert_eq!(grid.nearest_within_one(q, 0.01).map(|n| n.index), Some(copies[0] as u32));
        assert_eq!(grid.nearest_one_hinted(q, copies[7] as u32).map(|n| n.index), Some(copies[0] as u32));
    }
}

/// The batch queries split over a thread pool (and the two grids rebuilt as two tasks) give the
/// serial answers exactly, with and without hints; bad input is refused before any search.
#[cfg(feature = "std")]
#[test]
fn body_query_on_a_thread_pool_matches_serial() {
    use crate::exec::{Executor, Serial, ThreadPool};
    let mut rng = Rng(11);
    let (v, f) = ellipsoid(50, 70, [0.25, 0.8, 0.15], [0.0, 1.0, 0.0]);
    let mesh = BodyMesh::new(v.len(), &f).unwrap();
    let (mut serial, mut pooled) = (BodyFrame::new(&mesh).unwrap(), BodyFrame::new(&mesh).unwrap());
    let pool = ThreadPool::new(2);
    for (step, exec) in [&pool as &dyn Executor, &Serial, &pool].into_iter().enumerate() {
        let positions: Vec<[f32; 3]> = v
            .iter()
            .map(|p| [p[0] + 0.1 * step as f32, p[1], p[2] + 0.03 * (p[1] * 5.0 + step as f32).sin()])
            .collect();
        serial.update_grids(&mesh, &positions).unwrap();
        pooled.update_grids_on(exec, &mesh, &positions).unwrap();
        assert_eq!(serial.centroids(), pooled.centroids());
        // Enough queries for several chunks per thread.
        let garment = random_queries(&mut rng, &positions, 3000);
        let n = garment.len();
        let hints: Vec<u32> = (0..n).map(|_| rng.below(v.len() + 5) as u32).collect();
        let face_hints: Vec<u32> = (0..n).map(|_| rng.below(f.len()) as u32).collect();
        let (mut e1, mut e2) = (vec![None; n], vec![None; n]);
        let kept = serial.body_edges(&mesh, &garment, 0.04, &mut e1).unwrap();
        assert_eq!(pooled.body_edges_on(exec, &mesh, &garment, 0.04, &[], &mut e2).unwrap(), kept);
        assert_eq!(e1, e2, "step {step}");
        e2.fill(None);
        assert_eq!(pooled.body_edges_on(exec, &mesh, &garment, 0.04, &hints, &mut e2).unwrap(), kept);
        assert_eq!(e1, e2, "step {step}, hinted");
        assert!(kept > 100 && kept < n, "the queries must see both edges and misses ({kept})");
        let zero = Nearest { index: 0, distance: 0.0 };
        let (mut f1, mut f2) = (vec![zero; n], vec![zero; n]);
        serial.nearest_faces(&garment, &mut f1).unwrap();
        pooled.nearest_faces_on(exec, &garment, &[], &mut f2).unwrap();
        assert_eq!(f1, f2, "step {step}");
        f2.fill(zero);
        pooled.nearest_faces_on(exec, &garment, &face_hints, &mut f2).unwrap();
        assert_eq!(f1, f2, "step {step}, hinted");

        // A bad query late in the batch: refused, naming it, before anything is written.
        let mut bad = garment.clone();
        bad[n - 3][2] = f32::INFINITY;
        let before = f2.clone();
        assert_eq!(
            pooled.nearest_faces_on(exec, &bad, &[], &mut f2),
            Err(Error::NonFinite { what: "query point", index: n - 3 })
        );
        assert_eq!(f2, before);
        assert_eq!(
            pooled.body_edges_on(exec, &mesh, &bad, 0.04, &hints[1..], &mut e2),
            Err(Error::SizeMismatch { what: "query hints", expected: n, got: n - 1 })
        );
    }
    let mut bad = v.clone();
    bad[5][0] = f32::NAN;
    assert_eq!(pooled.update_grids_on(&pool, &mesh, &bad), Err(Error::NonFinite { what: "body vertex", index: 5 }));
}

/// Runs the tasks in reverse order, on the calling thread or split between two threads: a query
/// task then comes before the rebuild of its grid and must build it itself (or wait for it).
#[cfg(feature = "std")]
struct Reversed(usize);

#[cfg(feature = "std")]
// SAFETY: every index once (reversed, possibly split over two threads joined before return).
unsafe impl crate::sim::Executor for Reversed {
    fn parallelism(&self) -> usize {
        self.0
    }
    fn run(&self, n: usize, task: &(dyn Fn(usize) + Sync)) {
        if self.0 == 1 {
            (0..n).rev().for_each(task);
        } else {
            // Odd tasks on a second thread, each side from the end.
            std::thread::scope(|s| {
                s.spawn(|| (0..n).rev().filter(|t| t % 2 == 1).for_each(task));
                (0..n).rev().filter(|t| t % 2 == 0).for_each(task);
            });
        }
    }
}

/// The whole query in one job (both rebuilds, then body edges and nearest faces as their grids
/// become ready) gives the separate serial calls' answers exactly on any executor, including ones
/// that run a query before the rebuild it needs; bad input changes nothing.
#[cfg(feature = "std")]
#[test]
fn body_query_whole_in_one_job_matches_separate_calls() {
    use crate::exec::{Executor, Serial, ThreadPool};
    let mut rng = Rng(12);
    let (v, f) = two_ellipsoids();
    let mut omitted = vec![false; v.len()];
    for k in (0..v.len()).step_by(7) {
        omitted[k] = true;
    }
    let mesh = BodyMesh::new(v.len(), &f).unwrap().with_omitted(&omitted).unwrap();
    let (pool2, pool3) = (ThreadPool::new(2), ThreadPool::new(3));
    let executors: [&dyn Executor; 6] = [&Serial, &pool2, &pool3, &Reversed(1), &Reversed(2), &Reversed(8)];
    let mut serial = BodyFrame::new(&mesh).unwrap();
    let mut fused: Vec<BodyFrame> = executors.iter().map(|_| BodyFrame::new(&mesh).unwrap()).collect();
    let zero = Nearest { index: 0, distance: 0.0 };
    for step in 0..3 {
        let positions: Vec<[f32; 3]> = v
            .iter()
            .map(|p| [p[0] + 0.05 * step as f32, p[1], p[2] + 0.02 * (p[1] * 7.0 + step as f32).sin()])
            .collect();
        serial.update_grids(&mesh, &positions).unwrap();
        let garment = random_queries(&mut rng, &positions, 2500 + 300 * step);
        let n = garment.len();
        let vertex_hints: Vec<u32> = (0..n).map(|_| rng.below(v.len() + 5) as u32).collect();
        let face_hints: Vec<u32> = (0..n).map(|_| rng.below(f.len()) as u32).collect();
        let mut want_edges = vec![None; n];
        let want_kept = serial.body_edges(&mesh, &garment, 0.03, &mut want_edges).unwrap();
        let mut want_faces = vec![zero; n];
        serial.nearest_faces(&garment, &mut want_faces).unwrap();
        assert!(want_kept > 100 && want_kept < n, "the queries must see both edges and misses ({want_kept})");
        for (k, (exec, frame)) in executors.iter().zip(fused.iter_mut()).enumerate() {
            for hinted in [false, true] {
                let query = GarmentQuery {
                    points: &garment,
                    radius: 0.03,
                    vertex_hints: if hinted { &vertex_hints } else { &[] },
                    face_hints: if hinted { &face_hints } else { &[] },
                };
                let (mut edges, mut faces) = (vec![None; n], vec![zero; n]);
                let kept = frame.update_and_query_on(*exec, &mesh, &positions, query, &mut edges, &mut faces).unwrap();
                assert_eq!(
                    (kept, &edges, &faces),
                    (want_kept, &want_edges, &want_faces),
                    "step {step} executor {k} hinted {hinted}"
                );
                assert_eq!(frame.centroids(), serial.centroids());

                // Bad input anywhere: refused, naming it, with the frame and outputs unchanged.
                let mut bad_body = positions.clone();
                bad_body[9][1] = f32::NAN;
                let mut bad_garment = garment.clone();
                bad_garment[n - 2][0] = f32::NEG_INFINITY;
                let before = (edges.clone(), faces.clone());
                let moved: Vec<[f32; 3]> = positions.iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect();
                assert_eq!(
                    frame.update_and_query_on(*exec, &mesh, &bad_body, query, &mut edges, &mut faces),
                    Err(Error::NonFinite { what: "body vertex", index: 9 })
                );
                let bad_query = GarmentQuery { points: &bad_garment, ..query };
                assert_eq!(
                    frame.update_and_query_on(*exec, &mesh, &moved, bad_query, &mut edges, &mut faces),
                    Err(Error::NonFinite { what: "query point", index: n - 2 })
                );
                assert_eq!(
                    frame.update_and_query_on(*exec, &mesh, &moved, query, &mut edges[1..], &mut faces),
                    Err(Error::SizeMismatch { what: "query output", expected: n, got: n - 1 })
                );
                assert_eq!((&edges, &faces), (&before.0, &before.1));
                assert_eq!(frame.centroids(), serial.centroids(), "a refused call must not rebuild");
                let mut again = vec![zero; n];
                frame.nearest_faces(&garment, &mut again).unwrap();
                assert_eq!(again, want_faces);
            }
        }
    }
}

/// A body-like closed mesh: an ellipsoid with a smaller one (an "arm") beside it, close enough
/// that clusters near the gap are taken exactly.
fn two_ellipsoids() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (mut v, mut f) = ellipsoid(30, 48, [0.18, 0.45, 0.12], [0.0, 1.0, 0.0]);
    let (v2, f2) = ellipsoid(16, 24, [0.04, 0.3, 0.04], [0.24, 1.0, 0.0]);
    let off = v.len() as u32;
    v.extend(v2);
    f.extend(f2.iter().map(|t| t.map(|i| i + off)));
    (v, f)
}

#[test]
fn winding_number_matches_exact_and_classifies_inside() {
    let (rest, faces) = two_ellipsoids();
    let mesh = BodyMesh::new(rest.len(), &faces).unwrap();
    let mut w = Winding::new(&mesh, &rest).unwrap();
    // Moved, turned and squashed after clustering: clusters must follow the refit.
    let (s, c) = (libm::sinf(0.7), libm::cosf(0.7));
    let moved: Vec<[f32; 3]> =
        rest.iter().map(|p| [c * p[0] + s * p[2] + 0.3, 0.9 * p[1] - 0.2, -s * p[0] + c * p[2]]).collect();
    w.refit(&mesh, &moved).unwrap();
    let mut rng = Rng(11);
    let (mut inside, mut checked) = (0, 0);
    for k in 0..600 {
        // Near the surface (vertex ± up to 2 cm) or anywhere in a box around the body.
        let p = if k % 2 == 0 {
            let v = moved[rng.below(moved.len())];
            let d = rng.dir();
            [0, 1, 2].map(|a| v[a] + rng.range(0.0, 0.02) * d[a])
        } else {
            [rng.range(-0.6, 1.2), rng.range(0.0, 1.6), rng.range(-0.6, 0.6)]
        };
        let exact = winding_number_exact(&faces, &moved, p.map(|x| x as f64));
        let fast = w.number(p) as f64;
        assert!((fast - exact).abs() < 2e-2, "point {p:?}: fast {fast}, exact {exact}");
        if (exact - 0.5).abs() > 0.05 {
            checked += 1;
            assert_eq!(w.inside(p), exact > 0.5, "point {p:?}: fast {fast}, exact {exact}");
            inside += usize::from(exact > 0.5);
        }
    }
    assert!(inside > 100 && checked - inside > 100, "both sides sampled: {inside} inside of {checked}");
    let centre = [0.3, 1.0 * 0.9 - 0.2, 0.0];
    assert!((w.number(centre) - 1.0).abs() < 1e-2, "{}", w.number(centre));
    assert!(w.number([5.0, 0.0, 0.0]).abs() < 1e-3);
    let pts = [centre, [5.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0]];
    assert_eq!(w.count_inside(&pts), 1);
    assert!(w.number([0.0, f32::INFINITY, 0.0]).is_nan());
}

#[test]
fn winding_refit_refuses_bad_positions_and_another_mesh() {
    let (rest, faces) = ellipsoid(6, 8, [0.2, 0.4, 0.1], [0.0; 3]);
    let mesh = BodyMesh::new(rest.len(), &faces).unwrap();
    let mut w = Winding::new(&mesh, &rest).unwrap();
    let mut bad = rest.clone();
    bad[3][1] = f32::NAN;
    assert!(matches!(w.refit(&mesh, &bad), Err(Error::NonFinite { index: 3, .. })));
    assert!(matches!(w.refit(&mesh, &rest[1..]), Err(Error::SizeMismatch { .. })));
    let other = BodyMesh::new(rest.len(), &faces[1..]).unwrap();
    assert!(matches!(w.refit(&other, &rest), Err(Error::SizeMismatch { .. })));
    assert!(matches!(Winding::new(&mesh, &bad), Err(Error::NonFinite { .. })));
}

/// Queries along random walks near the points (neighbouring queries close together, as a
/// garment's vertices are), with occasional jumps and a few far away.
fn coherent_queries(rng: &mut Rng, points: &[[f32; 3]], n: usize, step: f32) -> Vec<[f32; 3]> {
    let mut q = points[0];
    (0..n)
        .map(|k| {
            if k % 37 == 0 {
                q = points[rng.below(points.len())];
            }
            if k % 97 == 50 {
                return [q[0] + 20.0, q[1], q[2]];
            }
            let d = rng.dir();
            q = [0, 1, 2].map(|a| q[a] + step * rng.unit() * d[a]);
            q
        })
        .collect()
}

#[test]
fn body_query_tiles_match_single_searches() {
    // Eight neighbouring queries searched as one box (AVX2 and portable) against the same
    // queries searched one by one, and against brute force: radius queries with and without
    // hints, hinted nearest queries, tiles of every length (the last one partial).
    let mut rng = Rng(8);
    for round in 0..24 {
        let kind = round % 5;
        let n = [5, 60, 3000][round % 3];
        let pts = random_cloud(&mut rng, kind, n);
        let cpp = [0.1, 2.0, 8.0][(round / 3) % 3];
        let step = [0.005, 0.02, 0.1][round % 3];
        let n_queries = [203, 8, 1, 17][round % 4];
        let qs = coherent_queries(&mut rng, &pts, n_queries, step);
        // Hints: a nearby point's answer (close), none, an arbitrary point, an invalid index.
        let hints: Vec<u32> = (0..qs.len())
            .map(|k| match k % 5 {
                0..=2 => brute(&pts, [qs[k][0] + 0.003, qs[k][1], qs[k][2]], f32::INFINITY).unwrap().index,
                3 => rng.below(n) as u32,
                _ => u32::MAX,
            })
            .collect();
        let all_hinted: Vec<u32> = hints.iter().map(|&h| if h == u32::MAX { 0 } else { h }).collect();
        let mut grids = Vec::new();
        for (portable, tiles) in
            [(false, None), (false, Some(true)), (false, Some(false)), (true, Some(true)), (true, Some(false))]
        {
            let mut g = PointGrid::new(3000, 40_000).unwrap();
            g.set_cells_per_point(cpp).unwrap();
            if portable {
                g.force_portable();
            }
            if let Some(always) = tiles {
                g.force_tiles(always);
            }
            g.rebuild(&pts).unwrap();
            grids.push(g);
        }
        for r in [0.0, 0.02, 0.1, 1.0] {
            let want: Vec<_> = qs.iter().map(|q| brute(&pts, *q, r * r)).collect();
            for (v, g) in grids.iter().enumerate() {
                for h in [&hints[..], &[]] {
                    let mut got = vec![None; qs.len()];
                    g.nearest_within_hinted(&qs, r, h, &mut got).unwrap();
                    assert_eq!(got, want, "round {round} grid {v} r {r} hinted {}", !h.is_empty());
                }
            }
        }
        let want: Vec<_> = qs.iter().map(|q| brute(&pts, *q, f32::INFINITY).unwrap()).collect();
        for (v, g) in grids.iter().enumerate() {
            for h in [&hints, &all_hinted] {
                let mut got = vec![Nearest { index: 0, distance: 0.0 }; qs.len()];
                g.nearest_hinted(&qs, h, &mut got).unwrap();
                assert_eq!(got, want, "round {round} grid {v}: nearest");
            }
        }
    }
}

#[test]
fn body_query_tiles_refuse_a_non_finite_query_by_its_index() {
    let mut rng = Rng(9);
    let pts = random_cloud(&mut rng, 1, 500);
    let mut grid = PointGrid::new(500, 5000).unwrap();
    grid.rebuild(&pts).unwrap();
    let mut qs = coherent_queries(&mut rng, &pts, 40, 0.01);
    qs[19][1] = f32::NAN;
    let mut within = vec![None; qs.len()];
    let err = grid.nearest_within(&qs, 0.05, &mut within).unwrap_err();
    assert_eq!(err, crate::Error::NonFinite { what: "query point", index: 19 });
    let mut nearest = vec![Nearest { index: 0, distance: 0.0 }; qs.len()];
    let hints = vec![0u32; qs.len()];
    let err = grid.nearest_hinted(&qs, &hints, &mut nearest).unwrap_err();
    assert_eq!(err, crate::Error::NonFinite { what: "query point", index: 19 });
}

/// The grid's scans follow the kernels' tier (one setting for every SIMD path): capped at
/// scalar or portable, a new grid scans portably; uncapped, it uses AVX2 exactly when the tier has it.
#[test]
fn body_grid_scans_follow_the_kernel_tier() {
    use crate::kernels::{force_tier, Kernels, Tier};
    let _guard = crate::kernels::CAP_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let before = crate::kernels::tier_cap();
    for cap in [Tier::Scalar, Tier::Portable] {
        force_tier(Some(cap));
        let capped = PointGrid::new(10, 100).unwrap().uses_avx2();
        force_tier(before);
        assert!(!capped, "a grid made under the {} cap scans with AVX2", cap.name());
    }
    let now = PointGrid::new(10, 100).unwrap().uses_avx2();
    assert_eq!(now, Kernels::best().tier() >= Tier::Avx2Fma);
}
