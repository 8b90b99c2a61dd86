use super::*;
use crate::rig::procedural::{skirt, Mannequin};
use crate::rig::tests::Rng;
use glam::Quat;

const MHCLO: &str = "# a comment
name test
obj_file test.obj
x_scale 0 1 2.0
y_scale 0 2 4.0
z_scale 0 3 1.0
verts 0
0 1 2 0.2 0.3 0.5 1.0 0.0 0.0
3
1 2 3 0.5 0.5 0.0 0.0 1.0 -1.0
delete_verts
5 6 7
";

fn body() -> Vec<[f32; 3]> {
    // Reference extents in file units (x 2, y 4, z 1) times unit 0.5: scales x 2/1, y 4/2, z 1/0.5.
    vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 1.0]]
}

#[test]
fn garment_fit_mhclo_parses_and_fits_at_rest() {
    let b = MhcloBinding::parse(MHCLO, 0.5).unwrap();
    assert_eq!(b.vertices.len(), 3);
    assert_eq!(b.obj_file, "test.obj");
    assert_eq!(b.scale[1], (0, 2, 2.0));
    assert_eq!(b.vertices[1].v, [3, 3, 3]);
    let body = body();
    let mut out = vec![[0.0; 3]; 3];
    b.fit(&body, &body, &mut out).unwrap();
    // Vertex 0: 0.2 b0 + 0.3 b1 + 0.5 b2 + offset (1 * 0.5 unit) * scale x (2 / 1).
    let expect = Vec3::new(0.6, 2.0, 0.0) + Vec3::new(1.0, 0.0, 0.0);
    assert!((Vec3::from(out[0]) - expect).length() < 1e-6, "{:?}", out[0]);
    assert_eq!(out[1], body[3]);
    // Vertex 2: offset (0, 0.5, -0.5) scaled by (2, 2, 2).
    let expect = Vec3::new(1.0, 2.0, 0.0) + Vec3::new(0.0, 1.0, -1.0);
    assert!((Vec3::from(out[2]) - expect).length() < 1e-6, "{:?}", out[2]);
    // Errors name the line.
    let bad = MHCLO.replace("0 1 2 0.2 0.3 0.5 1.0 0.0 0.0", "0 1 2 0.2 0.3 0.5 1.0 0.0");
    let e = MhcloBinding::parse(&bad, 1.0);
    assert!(matches!(e, Err(Error::Parse { format: "mhclo", line: 8, .. })), "{e:?}");
    let bad = MHCLO.replace("0 1 2 0.2 0.3 0.5 1.0 0.0 0.0", "0 1 x 0.2 0.3 0.5 1.0 0.0 0.0");
    assert!(matches!(MhcloBinding::parse(&bad, 1.0), Err(Error::Parse { format: "mhclo", line: 8, .. })));
    assert!(MhcloBinding::parse(&MHCLO.replace("y_scale 0 2 4.0\n", ""), 1.0).is_err());
    assert!(b.fit(&body[..3], &body[..3], &mut out).is_err(), "body vertex 3 missing");
}

#[test]
fn garment_fit_follows_a_rigidly_moved_body() {
    let b = MhcloBinding::parse(MHCLO, 0.5).unwrap();
    let body = body();
    let mut rest_fit = vec![[0.0; 3]; 3];
    b.fit(&body, &body, &mut rest_fit).unwrap();
    let mut rng = Rng(5);
    for _ in 0..10 {
        let q = rng.rotation();
        let t = Vec3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        let moved: Vec<[f32; 3]> = body.iter().map(|p| (q * Vec3::from(*p) + t).into()).collect();
        let mut out = vec![[0.0; 3]; 3];
        b.fit(&body, &moved, &mut out).unwrap();
        for (a, r) in out.iter().zip(&rest_fit) {
            let expect = q * Vec3::from(*r) + t;
            assert!((Vec3::from(*a) - expect).length() < 1e-5);
        }
    }
}

#[test]
fn garment_fit_weights_nearest_and_diffused() {
    let m = Mannequin::new();
    let g = skirt(&m, 1000).unwrap();
    let near = nearest_vertex_weights(&g.rest, m.rest(), m.weights()).unwrap();
    let diff = diffused_weights(&g.rest, m.rest(), m.weights(), 2000, 0.01, 1).unwrap();
    assert_eq!(diff, diffused_weights(&g.rest, m.rest(), m.weights(), 2000, 0.01, 1).unwrap(), "seeded");
    let skel = m.skeleton();
    let name = |w: &SkinWeights, v: usize| skel.bones()[w.dominant_bone(v)].name.as_str();
    let mut blended = 0;
    for v in 0..g.rest.len() {
        let s: f32 = diff.influences(v).map(|x| x.1).sum();
        assert!((s - 1.0).abs() < 1e-5);
        // The waist follows the pelvis or lower back in both.
        if v < 10 {
            assert!(["Hips", "LowerBack"].contains(&name(&near, v)), "{}", name(&near, v));
        }
        if diff.influences(v).count() > near.influences(v).count() {
            blended += 1;
        }
    }
    // The hem (far from the legs) blends more bones with diffusion than with the nearest vertex.
    assert!(blended > g.rest.len() / 4, "{blended} of {} vertices blended more", g.rest.len());
    // A vertex on the body (d = 0) gets exactly its nearest vertex's weights.
    let on: Vec<[f32; 3]> = vec![m.rest()[100]];
    let w = diffused_weights(&on, m.rest(), m.weights(), 100, 0.01, 1).unwrap();
    let expect: Vec<(usize, f32)> = m.weights().influences(100).collect();
    let got: Vec<(usize, f32)> = w.influences(0).collect();
    assert_eq!(expect.len(), got.len());
    for (a, b) in expect.iter().zip(&got) {
        assert_eq!(a.0, b.0);
        assert!((a.1 - b.1).abs() < 1e-5);
    }
}

#[test]
fn garment_fit_pins_and_initialisation() {
    let m = Mannequin::new();
    let g = skirt(&m, 1000).unwrap();
    let garment = g.garment(false).unwrap();
    let waist = boundary_loop_pins(&garment, LoopChoice::Highest).unwrap();
    assert_eq!(waist, g.pins);
    let hem = boundary_loop_pins(&garment, LoopChoice::Lowest).unwrap();
    assert!(hem.iter().all(|&v| garment.rest()[v as usize][1] < 0.6));
    assert!(boundary_loop_pins(&garment, LoopChoice::Index(2)).is_err());
    let flags = pinned_flags(garment.n_vertices(), &waist).unwrap();
    assert_eq!(flags.iter().filter(|&&f| f).count(), waist.len());
    assert!(pinned_flags(3, &[3]).is_err());
    // Initialisation: turning the whole body turns the skinned garment with it.
    let w = nearest_vertex_weights(&g.rest, m.rest(), m.weights()).unwrap();
    let skel = m.skeleton();
    let mut local = vec![Quat::IDENTITY; skel.len()];
    let hips = skel.find("Hips").unwrap();
    let q = Quat::from_rotation_y(1.0);
    local[hips] = skel.bones()[hips].frame.conjugate() * q * skel.bones()[hips].frame;
    let mut pose = Pose::rest(skel);
    skel.forward_kinematics(&local, [0.0; 3], &mut pose).unwrap();
    let mut out = vec![[0.0; 3]; g.rest.len()];
    pose_garment(skel, &pose, &w, &g.rest, &mut out).unwrap();
    let c = skel.bones()[hips].head;
    for (a, b) in g.rest.iter().zip(&out) {
        let expect = c + q * (Vec3::from(*a) - c);
        assert!((expect - Vec3::from(*b)).length() < 1e-4);
    }
}
