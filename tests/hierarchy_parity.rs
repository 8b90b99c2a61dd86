//! The hierarchy on the parity fixture's t-shirt (1311 vertices) against the reference's coarse
//! graph. The reference's edges depend on its graph library's neighbour order (MODEL.md section
//! 8), so in general only the centre candidates and the level-0 node set are guaranteed to match.
//! On this mesh the reference's order happens to give the same result as our ascending order at
//! every level (observed: c0/c1/c2 = 3378/2108/1260 directed edges, all shared), so the test
//! holds us to that exactly: a change of visiting order would show here first.
#![cfg(feature = "tools")]

mod common;

use hood::hierarchy::{centre_candidates, CentreChoice, Hierarchy, HierarchyConfig};
use hood::io::safetensors::SafeTensors;
use hood::mesh::{Garment, GarmentDesc};
use std::collections::BTreeSet;

fn scene(test: &str) -> Option<SafeTensors> {
    let path = common::shared_dir().join("fixtures/hood-parity/fixture_scene.safetensors");
    if !path.exists() {
        common::skip(test, &path);
        return None;
    }
    Some(SafeTensors::read(&path).expect("fixture_scene"))
}

fn undirected(pairs: &[[u32; 2]]) -> BTreeSet<[u32; 2]> {
    pairs.iter().map(|&[a, b]| [a.min(b), a.max(b)]).collect()
}

#[test]
fn hierarchy_parity_with_reference_fixture() {
    let Some(st) = scene("hierarchy_parity_with_reference_fixture") else { return };
    let faces = common::faces(&st, "cloth_faces");
    let rest = common::rows3(&st, "cloth_rest_pos");
    let garment = Garment::new(GarmentDesc::new(&rest, &faces)).expect("fixture garment");
    assert_eq!(garment.n_components(), 1);

    // Centre candidates: exactly nx.center(G).
    let cand = centre_candidates(garment.n_vertices(), garment.edges(), garment.component_of(), 1).unwrap();
    let mut want: Vec<u32> = st.i64("coarse_all_centers").unwrap().data.iter().map(|&v| v as u32).collect();
    want.sort_unstable();
    assert_eq!(cand[0], want, "centre candidates differ from the reference's nx.center");
    let centre = st.i64("coarse_center").unwrap().data[0] as u32;
    assert_eq!(centre, 18);
    assert_eq!(cand[0][0], centre, "First should pick the reference's centre (its lowest candidate)");

    // Levels around the reference's centre.
    let h = Hierarchy::build(&garment, &HierarchyConfig::default().with_levels(3).with_centre(CentreChoice::First))
        .unwrap();
    assert_eq!(h.centres(), &[centre]);
    let from_graph = Hierarchy::from_graph(garment.n_vertices(), garment.edges(), &HierarchyConfig::default()).unwrap();
    assert_eq!(h, from_graph);
    for (i, level) in h.levels().iter().enumerate() {
        let reference = undirected(&common::edge_pairs(&st, &format!("coarse_edge_index{i}")));
        let ours: BTreeSet<[u32; 2]> = level.edges.iter().copied().collect();
        let common_edges = ours.intersection(&reference).count();
        let ref_nodes: BTreeSet<u32> = reference.iter().flatten().copied().collect();
        let our_nodes: BTreeSet<u32> = level.edges.iter().flatten().copied().collect();
        println!(
            "c{i}: directed edges ours {} reference {}; shared undirected {} of ours {} / reference {}; \
             nodes ours {} reference {} shared {}",
            2 * ours.len(),
            2 * reference.len(),
            common_edges,
            ours.len(),
            reference.len(),
            our_nodes.len(),
            ref_nodes.len(),
            our_nodes.intersection(&ref_nodes).count()
        );
        // Steps 2 and 3 do not depend on the visiting order, so level 0's node set must be the
        // reference's whatever the order; the edges match because the orders agree here.
        if i == 0 {
            assert_eq!(our_nodes, ref_nodes);
        }
        assert_eq!(ours, reference, "c{i} edges differ from the reference's");
    }

    // Vertex levels: distribution against cloth_vertex_level.
    let want_level = st.i64("cloth_vertex_level").unwrap().data;
    let mut ours = [0usize; 4];
    let mut reference = [0usize; 4];
    let mut same = 0;
    for (a, &b) in h.vertex_level().iter().zip(&want_level) {
        ours[*a as usize] += 1;
        reference[b as usize] += 1;
        same += (*a as i64 == b) as usize;
    }
    println!("vertex levels 0..3: ours {ours:?} reference {reference:?}; equal at {same} of {}", want_level.len());
    assert_eq!(ours, reference, "vertex level distribution");
    assert_eq!(same, want_level.len(), "vertex levels differ from cloth_vertex_level");
}
