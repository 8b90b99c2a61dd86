//! Parity of every term with the reference implementation's losses and gradients
//! (`../shared/fixtures/hood-parity`, skipped with a message when absent).

use super::tests::rel_err;
use super::*;
use crate::io::safetensors::SafeTensors;
use crate::math::Real;
use crate::mesh::{Garment, GarmentDesc};
use alloc::vec::Vec;
use std::println;

const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/fixtures/hood-parity");

fn open(name: &str) -> Option<SafeTensors> {
    let path = std::format!("{FIXTURES}/{name}");
    if !std::path::Path::new(&path).exists() {
        println!("SKIP: {path} is absent");
        return None;
    }
    Some(SafeTensors::read(&path).expect("fixture reads"))
}

fn rows3(st: &SafeTensors, name: &str) -> Vec<[f32; 3]> {
    st.f32(name).unwrap().rows::<3>().unwrap()
}

fn conv<T: Real>(v: &[[f32; 3]]) -> Vec<[T; 3]> {
    v.iter().map(|p| p.map(T::from_f32)).collect()
}

fn to64<T: Real>(v: &[[T; 3]]) -> Vec<[f64; 3]> {
    v.iter().map(|p| p.map(|c| c.to_f64())).collect()
}

/// Centroids computed in f32 as the reference does, for its nearest-centroid search.
fn centroids32(pos: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<[f32; 3]> {
    faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| pos[i as usize]);
            [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
        })
        .collect()
}

fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs())) / scale
}

struct Frame<T> {
    cent: Vec<[T; 3]>,
    norm: Vec<[T; 3]>,
    query: BruteForceCentroids,
}

fn frame<T: Real>(pos: &[[f32; 3]], faces: &[[u32; 3]]) -> Frame<T> {
    let mut cent = alloc::vec![[T::ZERO; 3]; faces.len()];
    let mut norm = alloc::vec![[T::ZERO; 3]; faces.len()];
    face_frames(pos, faces, &mut cent, &mut norm).unwrap();
    Frame { cent, norm, query: BruteForceCentroids { centroids: centroids32(pos, faces) } }
}

#[test]
fn physics_parity_terms_against_reference() {
    let (Some(scene), Some(losses)) = (open("fixture_scene.safetensors"), open("fixture_losses.safetensors")) else {
        return;
    };
    let rest = rows3(&scene, "cloth_rest_pos");
    let faces: Vec<[u32; 3]> =
        scene.i64("cloth_faces").unwrap().rows::<3>().unwrap().iter().map(|f| f.map(|i| i as u32)).collect();
    let garment = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();

    // Our rest quantities against the reference's.
    let dm_ref = scene.f32("cloth_Dm_inv").unwrap().data;
    let dm_ours: Vec<f32> = garment.dm_inv().iter().flat_map(|d| [d[0][0], d[0][1], d[1][0], d[1][1]]).collect();
    let as64 = |v: &[f32]| -> Vec<f64> { v.iter().map(|&x| x as f64).collect() };
    let e_dm = max_rel(&as64(&dm_ours), &as64(&dm_ref));
    let e_area = max_rel(&as64(garment.face_area()), &as64(&scene.f32("cloth_f_area").unwrap().data));
    let e_mass = max_rel(&as64(garment.vertex_mass()), &as64(&scene.f32("cloth_v_mass").unwrap().data));
    println!(
        "rest quantities, max |err| / max |ref|: Dm_inv {e_dm:.2e}, face area {e_area:.2e}, vertex mass {e_mass:.2e}"
    );
    assert!(e_dm < 1e-5 && e_area < 1e-6 && e_mass < 1e-6);
    assert_eq!(garment.hinges().len(), scene.i64("cloth_f_connectivity").unwrap().shape[0]);

    check_terms::<f64>(&scene, &losses, &garment, 1e-5, 1e-4);
}

#[test]
fn physics_parity_terms_against_reference_f32() {
    // The same code in f32 meets the same bounds.
    let (Some(scene), Some(losses)) = (open("fixture_scene.safetensors"), open("fixture_losses.safetensors")) else {
        return;
    };
    let rest = rows3(&scene, "cloth_rest_pos");
    let faces: Vec<[u32; 3]> =
        scene.i64("cloth_faces").unwrap().rows::<3>().unwrap().iter().map(|f| f.map(|i| i as u32)).collect();
    let garment = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
    check_terms::<f32>(&scene, &losses, &garment, 1e-5, 1e-4);
}

fn check_terms<T: Real>(scene: &SafeTensors, losses: &SafeTensors, garment: &Garment, tol_value: f64, tol_grad: f64) {
    let cloth = Cloth::<T>::new(garment);
    let pos32 = rows3(scene, "cloth_pos");
    let pos = conv::<T>(&pos32);
    let vel = conv::<T>(&rows3(scene, "cloth_velocity"));
    let dt = T::from_f32(scene.f32("timestep").unwrap().data[0]);
    let body_faces: Vec<[u32; 3]> =
        scene.i64("body_faces").unwrap().rows::<3>().unwrap().iter().map(|f| f.map(|i| i as u32)).collect();
    let prev = frame::<T>(&rows3(scene, "body_prev_pos"), &body_faces);
    let cur = frame::<T>(&rows3(scene, "body_pos"), &body_faces);
    let next = frame::<T>(&rows3(scene, "body_target_pos"), &body_faces);
    let n = pos.len();
    let mut near_cur = alloc::vec![0u32; n];
    cur.query.nearest_into(&pos32, &mut near_cur);
    let mut near_prev = alloc::vec![0u32; n];
    prev.query.nearest_into(&pos32, &mut near_prev);

    let reference = FrictionParams::REFERENCE;
    for set in ["pred", "noise5mm", "vel_noise5mm"] {
        let x32 = rows3(losses, &std::format!("{set}.positions"));
        let x = conv::<T>(&x32);
        let mut near_x = alloc::vec![0u32; n];
        cur.query.nearest_into(&x32, &mut near_x);
        type TermFn<'a, T> = &'a dyn Fn(Option<&mut [[T; 3]]>) -> T;
        let terms: [(&str, TermFn<T>); 6] = [
            ("stretching_energy", &|g| stretching(&cloth, &x, g).unwrap()),
            ("bending_energy", &|g| bending(&cloth, &x, g).unwrap()),
            ("inertia", &|g| inertia(&cloth, &pos, &vel, dt, &x, g).unwrap()),
            ("gravitational_energy", &|g| gravity(&cloth, &x, g).unwrap()),
            ("collision_penalty", &|g| {
                let nf = FaceFrame { centroids: &next.cent, normals: &next.norm };
                collision(&x, &near_cur, nf, T::from_f64(2e-3), T::from_f64(5e3), g).unwrap()
            }),
            ("friction_energy", &|g| {
                // The reference's frames: B_a = body prev, B_b = body current.
                let fa = FaceFrame { centroids: &prev.cent, normals: &prev.norm };
                let fb = FaceFrame { centroids: &cur.cent, normals: &cur.norm };
                friction(&cloth, &pos, &x, fa, fb, &near_prev, &near_x, &reference, g).unwrap()
            }),
        ];
        for (name, term) in terms {
            let want = losses.f32(&std::format!("{set}.{name}.loss")).unwrap().data[0] as f64;
            let want_g = to64(&conv::<f64>(&rows3(losses, &std::format!("{set}.{name}.grad"))));
            let mut g = alloc::vec![[T::ZERO; 3]; n];
            let got = term(Some(&mut g)).to_f64();
            let g = to64(&g);
            let ev = (got - want).abs() / want.abs();
            let eg = rel_err(&g, &want_g);
            println!(
                "{} {set:>12} {name:<21} ours {got:.7e} ref {want:.7e} value rel err {ev:.2e} grad rel err {eg:.2e}",
                core::any::type_name::<T>()
            );
            assert!(ev < tol_value, "{set} {name}: value rel err {ev:e}");
            assert!(eg < tol_grad, "{set} {name}: gradient rel err {eg:e}");
        }
    }
}
