//! Feature assembly and garment rest quantities against the reference implementation's fixture
//! (`../shared/fixtures/hood-parity`). `cargo test features` selects these.

// The fixture is read with the tools' safetensors reader: every test on it needs `tools`.
#[cfg(feature = "tools")]
mod common;
#[cfg(feature = "tools")]
use common::*;
use hood::features::*;
#[cfg(feature = "tools")]
use hood::mesh::{vertex_normals, Garment, GarmentDesc, Material};
#[cfg(feature = "tools")]
use hood::normaliser::{normalise_rows, Normaliser};

#[cfg(feature = "tools")]
fn stats(f: &Fixture, name: &str) -> hood::normaliser::NormStats {
    let p = format!("model._{name}_normalizer.");
    let sum = f.weights.f64(&(p.clone() + "_acc_sum")).unwrap().data;
    let sq = f.weights.f64(&(p.clone() + "_acc_sum_squared")).unwrap().data;
    let count = f.weights.f64(&(p + "_acc_count")).unwrap().data[0];
    let s = Normaliser::from_accumulators(&sum, &sq, count).stats();
    // The derived statistics the fixture stores must agree with ours.
    let want_mean = f.io.f32(&format!("_{name}_normalizer.mean")).unwrap().data;
    let want_std = f.io.f32(&format!("_{name}_normalizer.std")).unwrap().data;
    assert!(rel_err(&s.mean, &want_mean) < 1e-5, "{name} mean");
    assert!(rel_err(&s.std, &want_std) < 1e-5, "{name} std");
    s
}

#[cfg(feature = "tools")]
fn check(what: &str, ours: &[f32], theirs: &[f32], tol: f64) {
    let (r, a) = (rel_err(ours, theirs), max_abs(ours, theirs));
    println!("{what}: rel {r:.2e}, max abs {a:.2e}");
    assert!(r < tol, "{what}: relative error {r:.3e} >= {tol:.0e}");
}

#[cfg(feature = "tools")]
#[test]
fn features_garment_rest_quantities_match_reference() {
    let Some(f) = fixture("features_garment_rest_quantities_match_reference") else { return };
    let rest = rows3(&f.scene, "cloth_rest_pos");
    let tris = faces(&f.scene, "cloth_faces");
    let g = Garment::new(GarmentDesc::new(&rest, &tris)).unwrap();
    assert_eq!(g.n_vertices(), 1311);
    assert_eq!(g.edges().len(), 3837);
    assert_eq!(g.edges().len() - g.hinges().len(), 102, "boundary edges");
    assert_eq!(g.hinges().len(), f.scene.i64("cloth_f_connectivity").unwrap().shape[0]);
    check("vertex mass", g.vertex_mass(), &f.scene.f32("cloth_v_mass").unwrap().data, 1e-6);
    check("face area", g.face_area(), &f.scene.f32("cloth_f_area").unwrap().data, 1e-6);
    let dm: Vec<f32> = g.dm_inv().iter().flat_map(|m| [m[0][0], m[0][1], m[1][0], m[1][1]]).collect();
    check("Dm^-1", &dm, &f.scene.f32("cloth_Dm_inv").unwrap().data, 1e-5);
    let m = f.scene.f32("material_inputs_bending_mu_lambda").unwrap().data;
    check("material inputs", &Material::default().network_inputs(), &m, 1e-6);
}

#[cfg(feature = "tools")]
#[test]
fn features_match_reference() {
    let Some(f) = fixture("features_match_reference") else { return };
    let rest = rows3(&f.scene, "cloth_rest_pos");
    let tris = faces(&f.scene, "cloth_faces");
    let pos = rows3(&f.scene, "cloth_pos");
    let vel = rows3(&f.scene, "cloth_velocity");
    let mass = f.scene.f32("cloth_v_mass").unwrap().data;
    let level: Vec<u8> = f.scene.i64("cloth_vertex_level").unwrap().data.iter().map(|&l| l as u8).collect();
    let body_faces = faces(&f.scene, "body_faces");
    let (bpos, bprev, bnext) =
        (rows3(&f.scene, "body_pos"), rows3(&f.scene, "body_prev_pos"), rows3(&f.scene, "body_target_pos"));
    let active: Vec<u32> = f.scene.i64("body_active_idx").unwrap().data.iter().map(|&v| v as u32).collect();
    let dt = f.scene.f32("timestep").unwrap().data[0];
    let n = pos.len();
    let m_in = f.scene.f32("material_inputs_bending_mu_lambda").unwrap().data;
    let material = vec![[m_in[0], m_in[1], m_in[2]]; n];
    let type_table = f.weights.f32("model.nodetype_embedding.weight").unwrap().data;
    let level_table = f.weights.f32("model.vertexlevel_embedding.weight").unwrap().data;
    let emb = Embeddings { node_type: &type_table, level: &level_table };

    // Normals.
    let mut normals = vec![[0.0; 3]; n];
    vertex_normals(&tris, &pos, &mut normals);
    check("garment normals", normals.as_flattened(), &f.io.f32("cloth_normals").unwrap().data, 1e-5);
    let mut bnormals = vec![[0.0; 3]; bpos.len()];
    vertex_normals(&body_faces, &bpos, &mut bnormals);
    check("body normals", bnormals.as_flattened(), &f.io.f32("body_normals").unwrap().data, 1e-5);

    // Node features, raw then normalised.
    let pinned = vec![false; n];
    let gn = GarmentNodes {
        velocity: &vel,
        normals: &normals,
        mass: &mass,
        pinned: &pinned,
        level: &level,
        material: &material,
        dt,
    };
    let mut nodes = vec![0.0; (n + active.len()) * NODE_WIDTH];
    let (gpart, bpart) = nodes.split_at_mut(n * NODE_WIDTH);
    garment_node_features(&gn, &emb, gpart).unwrap();
    let bn = BodyNodes { pos: &bpos, prev: &bprev, normals: &bnormals, omitted: &[], dt };
    body_node_features(&bn, &active, &emb, bpart).unwrap();
    let raw: Vec<f32> = nodes.chunks_exact(NODE_WIDTH).flat_map(|r| r[..NODE_NORMALISED].to_vec()).collect();
    check("raw node features", &raw, &f.io.f32("raw_node_features_norm_part").unwrap().data, 1e-5);
    let s = stats(&f, "node");
    normalise_rows(&mut nodes, NODE_WIDTH, &s.mean, &s.std);
    check("garment node input", &nodes[..n * NODE_WIDTH], &f.io.f32("in_node_cloth").unwrap().data, 1e-5);
    check("body node input", &nodes[n * NODE_WIDTH..], &f.io.f32("in_node_body_active").unwrap().data, 1e-5);

    // Mesh and coarse edges share one normaliser.
    let s = stats(&f, "mesh_edge");
    for (edges, raw_name, in_name) in [
        ("mesh_edge_index", "raw_edge_features_mesh", "in_edge_mesh"),
        ("coarse_edge_index0", "raw_edge_features_coarse0", "in_edge_coarse0"),
        ("coarse_edge_index1", "raw_edge_features_coarse1", "in_edge_coarse1"),
        ("coarse_edge_index2", "raw_edge_features_coarse2", "in_edge_coarse2"),
    ] {
        let e = edge_pairs(&f.scene, edges);
        let mut out = vec![0.0; e.len() * EDGE_WIDTH];
        edge_features(&e, &pos, &rest, &material, dt, &mut out).unwrap();
        let raw: Vec<f32> = out.chunks_exact(EDGE_WIDTH).flat_map(|r| r[..EDGE_NORMALISED].to_vec()).collect();
        check(raw_name, &raw, &f.io.f32(raw_name).unwrap().data, 1e-5);
        normalise_rows(&mut out, EDGE_WIDTH, &s.mean, &s.std);
        check(in_name, &out, &f.io.f32(in_name).unwrap().data, 1e-5);
    }

    // Body edges: both directions, one normaliser.
    let pairs = edge_pairs(&f.scene, "world_edge_index");
    let (mut g2b, mut b2g) = (vec![0.0; pairs.len() * 9], vec![0.0; pairs.len() * 9]);
    body_edge_features(&pairs, &pos, &bpos, &bnext, dt, &mut g2b, &mut b2g).unwrap();
    check("raw garment->body", &g2b, &f.io.f32("raw_edge_features_world_cloth2body").unwrap().data, 1e-5);
    check("raw body->garment", &b2g, &f.io.f32("raw_edge_features_world_body2cloth").unwrap().data, 1e-5);
    let s = stats(&f, "world_edge");
    normalise_rows(&mut g2b, BODY_EDGE_WIDTH, &s.mean, &s.std);
    normalise_rows(&mut b2g, BODY_EDGE_WIDTH, &s.mean, &s.std);
    check("garment->body input", &g2b, &f.io.f32("in_edge_world_cloth2body").unwrap().data, 1e-4);
    check("body->garment input", &b2g, &f.io.f32("in_edge_world_body2cloth").unwrap().data, 1e-4);
}

#[test]
fn features_refuse_bad_lengths() {
    let t9 = [0.5f32; 81];
    let t4 = [0.25f32; 16];
    let emb = Embeddings { node_type: &t9, level: &t4 };
    let v = [[0.1f32, 0.2, 0.3]; 2];
    let gn = GarmentNodes {
        velocity: &v,
        normals: &v,
        mass: &[1.0, 2.0],
        pinned: &[false, true],
        level: &[0, 3],
        material: &v,
        dt: DT,
    };
    let mut out = vec![0.0; 47];
    assert!(garment_node_features(&gn, &emb, &mut out).is_err());
    let mut out = vec![0.0; 48];
    garment_node_features(&gn, &emb, &mut out).unwrap();
    assert_eq!(out[20], 0.0); // ln 1
    assert!((out[24 + 20] - 2f32.ln()).abs() < 1e-7);
    assert_eq!(out[19], DT);
    let bad_level = GarmentNodes { level: &[0, 4], ..gn };
    assert!(garment_node_features(&bad_level, &emb, &mut out).is_err());
    let short = Embeddings { node_type: &t9[..80], level: &t4 };
    assert!(garment_node_features(&gn, &short, &mut out).is_err());
}

#[cfg(feature = "tools")]
#[test]
fn features_reference_state_dict_loads() {
    let Some(f) = fixture("features_reference_state_dict_loads") else { return };
    let h = hood::model::reference::latent_width(&f.weights).unwrap();
    let spec = hood::model::ModelSpec::hood(h);
    let p = hood::model::reference::params_from_state_dict(&f.weights, &spec).unwrap();
    assert_eq!(p.count(), 5_146_852);
    let s = p.normalisers.output.stats();
    check("output normaliser mean", &s.mean, &f.io.f32("_output_normalizer.mean").unwrap().data, 1e-5);
}
