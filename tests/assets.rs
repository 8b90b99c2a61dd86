//! Tests on the real CC0 assets in `../shared/assets` (MakeHuman body and garments). Each test
//! prints a message and passes when the folder is absent, so a fresh clone still tests clean.
#![cfg(feature = "tools")]

mod common;

use hood::body::{BodyFrame, BodyMesh, Nearest};
use hood::io::obj::{split_components, Obj};
use hood::mesh::repair::{drop_degenerate_faces, drop_unused_vertices};
use hood::mesh::{Garment, GarmentDesc};
use std::path::PathBuf;

const ASSETS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/assets");
/// MakeHuman files are in decimetres.
const DM_TO_M: f32 = 0.1;

fn asset(rel: &str) -> Option<PathBuf> {
    let p = PathBuf::from(ASSETS).join(rel);
    if p.exists() {
        Some(p)
    } else {
        common::skip("assets", &p);
        None
    }
}

/// The garments and the vertex counts of their pieces (assets README).
const GARMENTS: &[(&str, &[usize])] =
    &[("female_casualsuit01", &[1311, 886]), ("female_sportsuit01", &[911, 886]), ("male_casualsuit04", &[810, 886])];

/// Positions (metres) and triangles.
type Mesh = (Vec<[f32; 3]>, Vec<[u32; 3]>);

fn body() -> Option<Mesh> {
    let path = asset("body/base.obj")?;
    let mut obj = Obj::read(&path).unwrap();
    assert_eq!(obj.positions.len(), 19_158);
    obj.scale(DM_TO_M);
    let body = obj.extract_groups(&["body"]).unwrap();
    Some((body.rest, body.faces))
}

fn garment_points(name: &str) -> Option<Vec<[f32; 3]>> {
    let mut obj = Obj::read(asset(&format!("garments/{name}.obj"))?).unwrap();
    obj.scale(DM_TO_M);
    Some(obj.positions)
}

#[test]
fn garment_base_obj_groups() {
    let Some(path) = asset("body/base.obj") else { return };
    let obj = Obj::read(&path).unwrap();
    assert_eq!(obj.positions.len(), 19_158);
    let body = obj.extract_groups(&["body"]).unwrap();
    assert_eq!(body.rest.len(), 13_380);
    // The fixture's body: 13,380 vertices, 26,756 triangles (quads split).
    assert_eq!(body.faces.len(), 26_756);
    let skirt = obj.extract_groups(&["helper-skirt"]).unwrap();
    assert_eq!(skirt.rest.len(), 720);
    let joints: Vec<&str> = obj.groups.iter().filter(|g| g.starts_with("joint-")).map(|g| g.as_str()).collect();
    println!(
        "base.obj: {} groups ({} joint-*), {} polygons, {} triangles",
        obj.groups.len(),
        joints.len(),
        obj.n_polygons,
        obj.triangles.len()
    );
    assert!(!joints.is_empty());
    // Body in metres: about 1.7 m tall.
    let ys = body.rest.iter().map(|p| p[1] * DM_TO_M);
    let (lo, hi) = ys.fold((f32::MAX, f32::MIN), |(l, h), y| (l.min(y), h.max(y)));
    println!("body height {:.3} m", hi - lo);
    assert!((1.4..2.1).contains(&(hi - lo)), "height {} m", hi - lo);
}

#[test]
fn garment_assets_split_into_pieces() {
    for (name, want) in GARMENTS {
        let Some(path) = asset(&format!("garments/{name}.obj")) else { return };
        let mut obj = Obj::read(&path).unwrap();
        obj.scale(DM_TO_M);
        let parts = split_components(&obj.positions, &obj.triangles).unwrap();
        let mut counts: Vec<usize> = parts.iter().map(|p| p.rest.len()).collect();
        counts.sort_unstable_by(|a, b| b.cmp(a));
        let mut want_sorted = want.to_vec();
        want_sorted.sort_unstable_by(|a, b| b.cmp(a));
        assert_eq!(counts, want_sorted, "{name}: component vertex counts");
        for (k, part) in parts.iter().enumerate() {
            let repaired = drop_degenerate_faces(&part.rest, &part.faces);
            let (rest, faces) = if repaired.dropped.is_empty() {
                (part.rest.clone(), part.faces.clone())
            } else {
                println!(
                    "{name} piece {k}: dropped {} degenerate faces {:?}",
                    repaired.dropped.len(),
                    repaired.dropped
                );
                let c = drop_unused_vertices(&part.rest, &repaired.faces);
                if c.rest.len() != part.rest.len() {
                    println!("{name} piece {k}: dropped {} unused vertices", part.rest.len() - c.rest.len());
                }
                (c.rest, c.faces)
            };
            let g = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap_or_else(|e| panic!("{name} piece {k}: {e}"));
            println!(
                "{name} piece {k}: {} vertices, {} triangles, {} edges, {} hinges, {} boundary loops, {} component(s), {:.3} m^2",
                g.n_vertices(),
                g.faces().len(),
                g.edges().len(),
                g.hinges().len(),
                g.boundary_loops().len(),
                g.n_components(),
                g.total_area()
            );
            assert_eq!(g.n_components(), 1);
            // The coarse levels of each piece (MODEL.md section 2): nested node sets, about half
            // as many nodes per level.
            let h = hood::hierarchy::Hierarchy::build(&g, &hood::hierarchy::HierarchyConfig::default()).unwrap();
            let mut prev = g.n_vertices();
            let mut line = format!("{name} piece {k} levels:");
            for (l, level) in h.levels().iter().enumerate() {
                let nodes = level.nodes.len();
                line += &format!(" c{l} {nodes} nodes / {} edges;", level.edges.len());
                assert!(nodes < prev && nodes * 4 > prev, "{name} piece {k} level {l}: {nodes} nodes after {prev}");
                prev = nodes;
            }
            println!("{line}");
        }
    }
}

#[test]
fn body_query_real_body_against_brute_force() {
    let Some((body_v, body_f)) = body() else { return };
    let mesh = BodyMesh::new(body_v.len(), &body_f).unwrap();
    let mut frame = BodyFrame::new(&mesh).unwrap();
    frame.update(&mesh, &body_v).unwrap();
    for (name, _) in GARMENTS {
        let Some(garment) = garment_points(name) else { return };
        let mut edges = vec![None; garment.len()];
        let n_edges = frame.body_edges(&mesh, &garment, 0.03, &mut edges).unwrap();
        let mut faces = vec![Nearest { index: 0, distance: 0.0 }; garment.len()];
        frame.nearest_faces(&garment, &mut faces).unwrap();
        for (k, g) in garment.iter().enumerate() {
            let (mut bv, mut bf) = ((u32::MAX, f32::INFINITY), (u32::MAX, f32::INFINITY));
            for (i, p) in body_v.iter().enumerate() {
                let d = dist2(*p, *g);
                if d < bv.1 {
                    bv = (i as u32, d);
                }
            }
            for (i, p) in frame.centroids().iter().enumerate() {
                let d = dist2(*p, *g);
                if d < bf.1 {
                    bf = (i as u32, d);
                }
            }
            let want_edge = (bv.1 <= 0.03f32 * 0.03).then_some(bv.0);
            assert_eq!(edges[k].map(|n| n.index), want_edge, "{name} vertex {k}");
            assert_eq!(faces[k].index, bf.0, "{name} vertex {k}");
        }
        let mean_face = faces.iter().map(|f| f.distance as f64).sum::<f64>() / faces.len() as f64;
        println!(
            "{name}: {} garment vertices, {n_edges} body edges within 3 cm, mean nearest-centroid distance {:.4} m",
            garment.len(),
            mean_face
        );
        assert!(n_edges > garment.len() / 4, "a fitted garment lies close to the body");
    }
}

fn dist2(p: [f32; 3], q: [f32; 3]) -> f32 {
    let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
    dx * dx + dy * dy + dz * dz
}
