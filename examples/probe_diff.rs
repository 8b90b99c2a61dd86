use hood::io::makehuman::{MakeHuman, METRES_PER_UNIT};
use hood::io::obj::split_components;
use hood::rig::fit::{diffused_weights, MhcloBinding};
use std::time::Instant;
fn main() {
    let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/assets"));
    let t = Instant::now();
    let mh = MakeHuman::load(dir.join("body")).unwrap();
    println!("load {:?}", t.elapsed());
    let text = std::fs::read_to_string(dir.join("garments/female_casualsuit01.mhclo")).unwrap();
    let b = MhcloBinding::parse(&text, METRES_PER_UNIT).unwrap();
    let obj = hood::io::obj::Obj::read(dir.join("garments/female_casualsuit01.obj")).unwrap();
    let mut out = vec![[0.0; 3]; b.vertices.len()];
    b.fit(&mh.obj.positions, &mh.obj.positions, &mut out).unwrap();
    let pieces = split_components(&out, &obj.triangles).unwrap();
    let shirt = pieces.iter().max_by(|a, b| (a.rest.iter().map(|p| p[1]).sum::<f32>() / a.rest.len() as f32).total_cmp(&(b.rest.iter().map(|p| p[1]).sum::<f32>() / b.rest.len() as f32))).unwrap();
    for (m, vox) in [(1000, 0.01), (10000, 0.01), (10000, 0.02)] {
        let t = Instant::now();
        let _ = diffused_weights(&shirt.rest, &mh.body.rest, &mh.body_weights, m, vox, 1).unwrap();
        println!("{} vertices M={m} voxel={vox}: {:?}", shirt.rest.len(), t.elapsed());
    }
    let man = hood::rig::procedural::Mannequin::new();
    for g in [hood::rig::procedural::long_dress(&man, 5000).unwrap(), hood::rig::procedural::cape(&man, 5000).unwrap()] {
        for vox in [0.01, 0.02] {
            let t = Instant::now();
            let _ = diffused_weights(&g.rest, man.rest(), man.weights(), 10000, vox, 1).unwrap();
            println!("{} {} vertices voxel={vox}: {:?}", g.name, g.rest.len(), t.elapsed());
        }
    }
}
