//! The whole step against the reference implementation's outputs on the fixture scene and
//! weights (`../shared/fixtures/hood-parity`): encoder outputs, every block, decoder,
//! accelerations and positions. `cargo test runtime_parity` selects these.
#![cfg(feature = "tools")]

mod common;
use common::*;
use hood::body::BodyMesh;
use hood::kernels::Tier;
use hood::mesh::{Garment, GarmentDesc};
use hood::model::{reference, write_model, ModelBytes, ModelSpec};
use hood::sim::{BodyDesc, Graph, Precision, Probe, Sim, SimConfig, SimState, Stage};

struct Run {
    encoded: (Vec<f32>, Vec<f32>),
    blocks: Vec<(Vec<f32>, Vec<f32>)>,
    decoded: Vec<f32>,
    pos: Vec<f32>,
    vel: Vec<f32>,
}

fn run(f: &Fixture, bytes: &ModelBytes, precision: Precision, tier: Option<Tier>) -> Run {
    let model = bytes.model().unwrap();
    let rest = rows3(&f.scene, "cloth_rest_pos");
    let tris = faces(&f.scene, "cloth_faces");
    let garment = Garment::new(GarmentDesc::new(&rest, &tris)).unwrap();
    // The reference's coarse edges (its coarsening depends on networkx's neighbour order).
    let coarse: Vec<Vec<[u32; 2]>> = (0..3)
        .map(|l| {
            let e = edge_pairs(&f.scene, &format!("coarse_edge_index{l}"));
            e[..e.len() / 2].to_vec()
        })
        .collect();
    let level: Vec<u8> = f.scene.i64("cloth_vertex_level").unwrap().data.iter().map(|&l| l as u8).collect();
    let graph = Graph::from_parts(&garment, &coarse, &level).unwrap();
    let body_faces = faces(&f.scene, "body_faces");
    let bpos = rows3(&f.scene, "body_pos");
    let mesh = BodyMesh::new(bpos.len(), &body_faces).unwrap();
    let cfg = SimConfig::network().with_startup(false).with_precision(precision).with_tier(tier);
    let body = BodyDesc { mesh: &mesh, positions: &bpos };
    let mut sim = Sim::with_graph(&model, &garment, graph, Some(body), cfg).unwrap();
    let state = SimState {
        pos: rows3(&f.scene, "cloth_pos"),
        velocity: rows3(&f.scene, "cloth_velocity"),
        body_prev: rows3(&f.scene, "body_prev_pos"),
        body_pos: bpos.clone(),
        started: true,
    };
    sim.set_state(&state).unwrap();
    let mut r = Run { encoded: (vec![], vec![]), blocks: vec![], decoded: vec![], pos: vec![], vel: vec![] };
    let next = rows3(&f.scene, "body_target_pos");
    let mut obs = |p: Probe<'_>| match p.stage {
        Stage::Encoded => r.encoded = (p.garment.to_vec(), p.body.to_vec()),
        Stage::Block(_) => r.blocks.push((p.garment.to_vec(), p.body.to_vec())),
        Stage::Decoded => r.decoded = p.garment.to_vec(),
    };
    sim.step_observed(&next, &mut obs).unwrap();
    r.pos = sim.positions().as_flattened().to_vec();
    r.vel = sim.state().velocity.as_flattened().to_vec();
    r
}

fn fixture_model(f: &Fixture) -> ModelBytes {
    let spec = ModelSpec::hood(reference::latent_width(&f.weights).unwrap());
    let params = reference::params_from_state_dict(&f.weights, &spec).unwrap();
    ModelBytes::new(&write_model(&params, true, &[("source", "hood-parity fixture")]).unwrap())
}

fn check(what: &str, ours: &[f32], theirs: &[f32], tol: f64) -> f64 {
    let r = rel_err(ours, theirs);
    println!("{what}: rel {r:.2e}, max abs {:.2e}", max_abs(ours, theirs));
    assert!(r < tol, "{what}: relative error {r:.3e} >= {tol:.0e}");
    r
}

#[test]
fn runtime_parity_f32() {
    let Some(f) = fixture("runtime_parity_f32") else { return };
    let bytes = fixture_model(&f);
    let r = run(&f, &bytes, Precision::F32, None);
    let t = |n: &str| f.io.f32(n).unwrap().data;
    assert_eq!(r.encoded.1.len() / 128, 1010, "active body nodes");
    check("encoded garment", &r.encoded.0, &t("lat_enc_cloth"), 1e-4);
    check("encoded body", &r.encoded.1, &t("lat_enc_body_active"), 1e-4);
    for (i, (g, b)) in r.blocks.iter().enumerate() {
        check(&format!("block {:2} garment", i + 1), g, &t(&format!("lat_block{:02}_cloth", i + 1)), 1e-4);
        check(&format!("block {:2} body", i + 1), b, &t(&format!("lat_block{:02}_body_active", i + 1)), 1e-4);
    }
    check("decoder output", &r.decoded, &t("decoder_output"), 1e-4);
    let v0 = f.scene.f32("cloth_velocity").unwrap().data;
    let acc: Vec<f32> = r.vel.iter().zip(&v0).map(|(a, b)| a - b).collect();
    check("acceleration", &acc, &t("pred_acceleration"), 1e-4);
    check("predicted positions", &r.pos, &t("pred_pos"), 1e-4);
    println!("pred_pos max abs error: {:.2e} m", max_abs(&r.pos, &t("pred_pos")));
}

#[test]
fn runtime_parity_bf16_and_every_tier() {
    let Some(f) = fixture("runtime_parity_bf16_and_every_tier") else { return };
    let bytes = fixture_model(&f);
    let t = |n: &str| f.io.f32(n).unwrap().data;
    let v0 = f.scene.f32("cloth_velocity").unwrap().data;
    let best = hood::kernels::Kernels::best().tier();
    for tier in Tier::ALL {
        if tier > best {
            println!("tier {}: skipped, this CPU lacks it", tier.name());
            continue;
        }
        for precision in [Precision::F32, Precision::Bf16] {
            let r = run(&f, &bytes, precision, Some(tier));
            let acc: Vec<f32> = r.vel.iter().zip(&v0).map(|(a, b)| a - b).collect();
            let tol = if precision == Precision::Bf16 { 3e-2 } else { 1e-4 };
            check(&format!("{} {precision:?} acceleration", tier.name()), &acc, &t("pred_acceleration"), tol);
            check(&format!("{} {precision:?} positions", tier.name()), &r.pos, &t("pred_pos"), tol);
        }
    }
}

/// The scene `hood bench --reference` hands the reference forward is the fixture's own on `tee`:
/// positions, faces, body frames, the directed mesh and coarse edges (as sets: the order may
/// differ) and vertex levels; the subdivided `tee-sub` has the same keys at its own size.
#[test]
fn runtime_parity_reference_scene_is_the_fixture_scene() {
    use hood::io::safetensors::SafeTensors;
    use std::collections::BTreeSet;
    let Some(f) = fixture("runtime_parity_reference_scene_is_the_fixture_scene") else { return };
    let assets = shared_dir().join("assets");
    let tee = hood::workloads::workload("tee", &assets).unwrap();
    let ours = SafeTensors::from_bytes(hood::workloads::reference_scene(&tee).unwrap()).unwrap();
    let close = |name: &str, tol: f32| {
        let (a, b) = (ours.f32(name).unwrap(), f.scene.f32(name).unwrap());
        assert_eq!(a.shape, b.shape, "{name}");
        assert!(max_abs(&a.data, &b.data) <= tol as f64, "{name}: {}", max_abs(&a.data, &b.data));
    };
    for name in ["cloth_rest_pos", "cloth_pos", "body_pos", "body_prev_pos", "body_target_pos"] {
        close(name, 0.0);
    }
    // The previous positions come back as pos - (pos - prev): within rounding.
    close("cloth_prev_pos", 1e-7);
    assert_eq!(faces(&ours, "cloth_faces"), faces(&f.scene, "cloth_faces"));
    assert_eq!(faces(&ours, "body_faces"), faces(&f.scene, "body_faces"));
    assert_eq!(ours.i64("cloth_vertex_level").unwrap().data, f.scene.i64("cloth_vertex_level").unwrap().data);
    let set = |st: &SafeTensors, name: &str| edge_pairs(st, name).into_iter().collect::<BTreeSet<_>>();
    for name in ["mesh_edge_index", "coarse_edge_index0", "coarse_edge_index1", "coarse_edge_index2"] {
        assert_eq!(set(&ours, name), set(&f.scene, name), "{name}");
        assert_eq!(edge_pairs(&ours, name).len(), edge_pairs(&f.scene, name).len(), "{name}: no duplicates");
    }
    let sub = hood::workloads::workload("tee-sub", &assets).unwrap();
    let sub = SafeTensors::from_bytes(hood::workloads::reference_scene(&sub).unwrap()).unwrap();
    let names = |st: &SafeTensors| st.tensors().iter().map(|(n, _)| n.clone()).collect::<BTreeSet<_>>();
    assert_eq!(names(&sub), names(&ours));
    assert_eq!(sub.f32("cloth_pos").unwrap().shape, vec![5148, 3]);
    // A procedural workload has no fixed state to hand over.
    let walk = hood::workloads::workload("grid-1k", &assets).unwrap();
    assert!(hood::workloads::reference_scene(&walk).is_err());
}
