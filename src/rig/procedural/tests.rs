use super::*;
use crate::rig::testgeom::{mesh_distance, winding_number};
use crate::rig::Pose;
use alloc::vec::Vec;
use glam::Vec3;
use std::sync::OnceLock;

extern crate std;

fn mannequin() -> &'static Mannequin {
    static M: OnceLock<Mannequin> = OnceLock::new();
    M.get_or_init(Mannequin::new)
}

#[test]
fn procedural_mannequin_is_a_closed_manifold() {
    let t0 = std::time::Instant::now();
    let m = mannequin();
    std::println!("mannequin: {} vertices, {} faces, built in {:?}", m.rest().len(), m.faces().len(), t0.elapsed());
    assert!(m.rest().len() >= 5000, "{} vertices", m.rest().len());
    // Every undirected edge has exactly two faces, and they use it in opposite directions
    // (consistent orientation).
    let mut directed: Vec<(u32, u32)> = Vec::new();
    for f in m.faces() {
        for k in 0..3 {
            directed.push((f[k], f[(k + 1) % 3]));
        }
    }
    directed.sort_unstable();
    for w in directed.windows(2) {
        assert_ne!(w[0], w[1], "directed edge {:?} used twice", w[0]);
    }
    for &(a, b) in &directed {
        assert!(directed.binary_search(&(b, a)).is_ok(), "edge {a}-{b} has one face");
    }
    // One component, sphere topology: V - E + F = 2.
    let topo = crate::mesh::topology::build(m.rest().len(), m.faces());
    assert_eq!(topo.n_components, 1);
    let chi = m.rest().len() as i64 - topo.edges.len() as i64 + m.faces().len() as i64;
    assert_eq!(chi, 2, "Euler characteristic");
    // Outward orientation: positive volume, of a person's size.
    let vol: f32 = m
        .faces()
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| Vec3::from(m.rest()[i as usize]));
            a.dot(b.cross(c)) / 6.0
        })
        .sum();
    assert!((0.04..0.1).contains(&vol), "volume {vol} m^3");
    // No degenerate triangle.
    let worst = m
        .faces()
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| Vec3::from(m.rest()[i as usize]));
            let l2 = (b - a).length_squared().max((c - a).length_squared()).max((c - b).length_squared());
            (b - a).cross(c - a).length() / l2
        })
        .fold(f32::INFINITY, f32::min);
    std::println!("worst triangle: 2 area / longest edge^2 = {worst:.2e}");
    assert!(worst > 1e-4);
    // Proportions: 1.7-1.85 m tall, feet on the floor, toes forward (+z).
    let lo = m.rest().iter().fold(Vec3::splat(f32::INFINITY), |a, p| a.min(Vec3::from(*p)));
    let hi = m.rest().iter().fold(Vec3::splat(f32::NEG_INFINITY), |a, p| a.max(Vec3::from(*p)));
    assert!(lo.y.abs() < 0.01 && (1.7..1.85).contains(&hi.y), "{lo} {hi}");
    assert!(hi.z > 0.15 && lo.z > -0.15, "facing +z: {lo} {hi}");
    // Weights: every vertex sums to 1; hand vertices follow the hand.
    for v in 0..m.rest().len() {
        let s: f32 = m.weights().influences(v).map(|x| x.1).sum();
        assert!((s - 1.0).abs() < 1e-5);
    }
    let tip = (0..m.rest().len()).max_by(|&a, &b| m.rest()[a][0].total_cmp(&m.rest()[b][0])).unwrap();
    assert_eq!(m.skeleton().bones()[m.weights().dominant_bone(tip)].name, "LeftHand");
}

fn check_clear(m: &Mannequin, g: &ProceduralGarment) -> (f32, usize) {
    let mut min_d = f32::INFINITY;
    let mut inside = 0;
    for p in &g.rest {
        let p = Vec3::from(*p);
        min_d = min_d.min(mesh_distance(p, m.rest(), m.faces()));
        if winding_number(p, m.rest(), m.faces()) > 0.5 {
            inside += 1;
        }
    }
    (min_d, inside)
}

#[test]
fn procedural_garments_start_outside_the_body() {
    let m = mannequin();
    type Maker = fn(&Mannequin, usize) -> crate::Result<ProceduralGarment>;
    let makers: [(&str, Maker); 4] =
        [("square", square_cloth), ("skirt", skirt), ("dress", long_dress), ("cape", cape)];
    for (name, make) in makers {
        let g = make(m, 1000).unwrap();
        let garment = g.garment(true).unwrap();
        assert_eq!(garment.n_components(), 1, "{name}");
        let (min_d, inside) = check_clear(m, &g);
        std::println!("{name}: {} vertices, {} pins, nearest body distance {min_d:.4} m", g.rest.len(), g.pins.len());
        assert_eq!(inside, 0, "{name}: vertices inside the body");
        assert!(min_d >= 0.5 * garments_margin(), "{name}: {min_d}");
    }
}

fn garments_margin() -> f32 {
    0.012
}

#[test]
fn procedural_garment_counts_scale_with_resolution() {
    let m = mannequin();
    for target in [1000usize, 4400, 12000] {
        for g in [skirt(m, target), long_dress(m, target), cape(m, target), square_cloth(m, target)] {
            let g = g.unwrap();
            let n = g.rest.len() as f32;
            assert!((n / target as f32 - 1.0).abs() < 0.1, "{}: {n} vertices for {target}", g.name);
        }
    }
    // The pins are boundary loops: the skirt's waist is one whole boundary loop.
    let s = skirt(m, 1000).unwrap();
    let garment = s.garment(true).unwrap();
    assert_eq!(garment.boundary_loops().len(), 2);
    let mut waist: Vec<u32> = garment.boundary_loops().iter().find(|l| l.contains(&0)).unwrap().clone();
    waist.sort_unstable();
    assert_eq!(waist, s.pins);
    assert!(skirt(m, 3).is_err());
}

#[test]
fn procedural_motions_are_smooth_grounded_and_go_somewhere() {
    let m = mannequin();
    let skel = m.skeleton();
    let seconds = 3.0;
    let motions = [
        ("walk", walk(skel, seconds).unwrap()),
        ("run", run(skel, seconds).unwrap()),
        ("jump", jump(skel, seconds).unwrap()),
        ("turn", turn_on_the_spot(skel, seconds).unwrap()),
        ("arms", arm_swings(skel, seconds).unwrap()),
        ("random", random_poses(skel, seconds, 7).unwrap()),
    ];
    let mut pose = Pose::rest(skel);
    let mut prev = Pose::rest(skel);
    for (name, mo) in &motions {
        assert_eq!(mo.fps, 30.0);
        assert_eq!(mo.n_frames(), 91, "{name}");
        let mut max_step = 0.0f32;
        let mut low = f32::INFINITY;
        for f in 0..mo.n_frames() {
            mo.pose(skel, f, &mut pose).unwrap();
            for b in 0..skel.len() {
                let len = (pose.tail(skel, b) - pose.head[b]).length();
                assert!((len - skel.bones()[b].length()).abs() < 1e-4);
                if f > 0 {
                    max_step = max_step.max((pose.tail(skel, b) - prev.tail(skel, b)).length());
                }
            }
            let feet = ["LeftToeBase", "RightToeBase", "LeftFoot", "RightFoot"];
            for n in feet {
                let b = skel.find(n).unwrap();
                low = low.min(pose.head[b].y.min(pose.tail(skel, b).y));
            }
            core::mem::swap(&mut pose, &mut prev);
        }
        // Smooth: no joint moves more than 30 cm in one frame (9 m/s: the running hands are fastest).
        assert!(max_step < 0.3, "{name}: {max_step}");
        assert!((-0.01..0.1).contains(&low), "{name}: lowest foot joint at {low}");
    }
    let forward = |mo: &LocalMotion| mo.root[mo.n_frames() - 1][2] - mo.root[0][2];
    assert!(forward(&motions[0].1) > 3.0 && forward(&motions[1].1) > 8.0);
    let peak = motions[2].1.root.iter().map(|r| r[1]).fold(f32::NEG_INFINITY, f32::max);
    assert!(peak > 0.25, "jump peak {peak}");
    // Different seeds give different random motions; the same seed the same one.
    assert_eq!(random_poses(skel, 1.0, 7).unwrap(), random_poses(skel, 1.0, 7).unwrap());
    assert_ne!(random_poses(skel, 1.0, 7).unwrap(), random_poses(skel, 1.0, 8).unwrap());
}
