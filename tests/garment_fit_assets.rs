//! MakeHuman garments fitted to the MakeHuman body (skipped with a message when
//! ../shared/assets is absent).
#![cfg(feature = "tools")]

mod common;

use glam::Vec3;
use hood::io::makehuman::{MakeHuman, METRES_PER_UNIT};
use hood::io::obj::{split_components, Obj};
use hood::mesh::{Garment, GarmentDesc};
use hood::rig::fit::{boundary_loop_pins, diffused_weights, LoopChoice, MhcloBinding, DIFFUSION_SAMPLES};
use std::path::PathBuf;
use std::time::Instant;

fn assets() -> Option<PathBuf> {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/assets"));
    if p.join("body/base.obj").exists() && p.join("garments/female_casualsuit01.mhclo").exists() {
        Some(p)
    } else {
        common::skip("garment_fit_assets", &p);
        None
    }
}

/// Generalised winding number of the mesh around `p` (about 1 inside, 0 outside).
fn winding_number(p: Vec3, pos: &[[f32; 3]], faces: &[[u32; 3]]) -> f64 {
    let p = p.as_dvec3();
    let mut total = 0.0;
    for f in faces {
        let [a, b, c] = f.map(|i| Vec3::from(pos[i as usize]).as_dvec3() - p);
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let det = a.dot(b.cross(c));
        let div = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
        total += 2.0 * det.atan2(div);
    }
    total / (4.0 * std::f64::consts::PI)
}

/// The garment's OBJ and binding, fitted to the rest body (metres, MakeHuman's floor shift),
/// with MakeHuman's formula (`exact`) or without the offsets' inward part.
fn fitted(dir: &std::path::Path, mh: &MakeHuman, name: &str, exact: bool) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let text = std::fs::read_to_string(dir.join(format!("garments/{name}.mhclo"))).unwrap();
    let binding = MhcloBinding::parse(&text, METRES_PER_UNIT).unwrap();
    let obj = Obj::read(dir.join("garments").join(&binding.obj_file)).unwrap();
    assert_eq!(obj.positions.len(), binding.vertices.len(), "{name}");
    let mut out = vec![[0.0; 3]; binding.vertices.len()];
    if exact {
        binding.fit(&mh.obj.positions, &mh.obj.positions, &mut out).unwrap();
    } else {
        let mut normals = vec![[0.0; 3]; mh.obj.positions.len()];
        hood::mesh::vertex_normals(&mh.obj.triangles, &mh.obj.positions, &mut normals);
        binding.fit_outside(&mh.obj.positions, &normals, &mh.obj.positions, &mut out).unwrap();
    }
    // The OBJ itself was modelled on a MakeHuman character with default morphs, not on base.obj:
    // the binding (not the OBJ) is what places the garment on this body.
    let mut dev: Vec<f32> = out
        .iter()
        .zip(&obj.positions)
        .map(|(a, b)| {
            (Vec3::from(*a) - Vec3::new(b[0], b[1] + mh.floor_shift / METRES_PER_UNIT, b[2]) * METRES_PER_UNIT).length()
        })
        .collect();
    dev.sort_by(f32::total_cmp);
    println!("{name}: fitted vs its own OBJ: median {:.3} m (different body shape)", dev[dev.len() / 2]);
    (out, obj.triangles)
}

#[test]
fn garment_fit_makehuman_garments_are_outside_the_body() {
    let Some(dir) = assets() else { return };
    let mh = MakeHuman::load(dir.join("body")).unwrap();
    for name in ["female_casualsuit01", "female_sportsuit01", "male_casualsuit04"] {
        let count_inside = |pos: &[[f32; 3]]| {
            pos.iter().filter(|p| winding_number(Vec3::from(**p), &mh.body.rest, &mh.body.faces) > 0.5).count()
        };
        let (exact, _) = fitted(&dir, &mh, name, true);
        let (pos, tris) = fitted(&dir, &mh, name, false);
        let pieces = split_components(&pos, &tris).unwrap();
        let inside = count_inside(&pos);
        let sizes: Vec<usize> = pieces.iter().map(|p| p.rest.len()).collect();
        println!(
            "{name}: pieces {sizes:?}, {inside} of {} vertices inside the body ({} with MakeHuman's exact offsets)",
            pos.len(),
            count_inside(&exact)
        );
        assert_eq!(pieces.len(), 2, "{name}");
        assert!((inside as f64) < 0.01 * pos.len() as f64, "{name}: {inside} inside");
    }
}

#[test]
fn garment_fit_tshirt_diffused_weights_and_waist() {
    let Some(dir) = assets() else { return };
    let mh = MakeHuman::load(dir.join("body")).unwrap();
    let (pos, tris) = fitted(&dir, &mh, "female_casualsuit01", false);
    let pieces = split_components(&pos, &tris).unwrap();
    let mean_y =
        |p: &hood::mesh::repair::CompactedMesh| p.rest.iter().map(|v| v[1] as f64).sum::<f64>() / p.rest.len() as f64;
    let (shirt, jeans) =
        if mean_y(&pieces[0]) > mean_y(&pieces[1]) { (&pieces[0], &pieces[1]) } else { (&pieces[1], &pieces[0]) };
    assert_eq!(shirt.rest.len(), 1311);
    assert_eq!(jeans.rest.len(), 886);
    let t = Instant::now();
    let w = diffused_weights(&shirt.rest, &mh.body.rest, &mh.body_weights, DIFFUSION_SAMPLES, 0.01, 1).unwrap();
    let took = t.elapsed();
    println!("diffused weights, t-shirt {} vertices, M = {DIFFUSION_SAMPLES}: {took:?}", shirt.rest.len());
    // The shirt's hem moves with the spine/hips, its sleeves with the arms.
    let name = |v: usize| mh.skeleton.bones()[w.dominant_bone(v)].name.clone();
    let left_most = (0..shirt.rest.len()).max_by(|&a, &b| shirt.rest[a][0].total_cmp(&shirt.rest[b][0])).unwrap();
    assert!(name(left_most).starts_with("Left"), "{}", name(left_most));
    // The jeans' waist is their highest boundary loop.
    let g = Garment::new(GarmentDesc::new(&jeans.rest, &jeans.faces)).unwrap();
    let waist = boundary_loop_pins(&g, LoopChoice::Highest).unwrap();
    let wy: f32 = waist.iter().map(|&v| jeans.rest[v as usize][1]).sum::<f32>() / waist.len() as f32;
    println!("jeans: {} boundary loops, waist {} vertices at mean y {wy:.3} m", g.boundary_loops().len(), waist.len());
    assert!(wy > 0.9 && wy < 1.2, "waist height {wy}");
}
