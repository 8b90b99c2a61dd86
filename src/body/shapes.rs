//! Procedural closed bodies (no files needed), for tests, benches and examples.

use alloc::vec::Vec;
use core::f32::consts::PI;

/// A closed ellipsoid with semi-axes `radii` (metres) around `centre`: two poles on the y axis and
/// `rings` rings of `segments` vertices (`2 + rings·segments` vertices, `2·rings·segments`
/// triangles), counter-clockwise seen from outside.
///
/// # Panics
/// When `rings < 1` or `segments < 3`.
pub fn ellipsoid(rings: usize, segments: usize, radii: [f32; 3], centre: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    assert!(rings >= 1 && segments >= 3, "an ellipsoid needs at least 1 ring and 3 segments");
    let point = |u: [f32; 3]| [centre[0] + radii[0] * u[0], centre[1] + radii[1] * u[1], centre[2] + radii[2] * u[2]];
    let mut verts = Vec::with_capacity(2 + rings * segments);
    verts.push(point([0.0, 1.0, 0.0]));
    for r in 0..rings {
        let theta = PI * (r + 1) as f32 / (rings + 1) as f32;
        let (st, ct) = (libm::sinf(theta), libm::cosf(theta));
        for s in 0..segments {
            let phi = 2.0 * PI * s as f32 / segments as f32;
            verts.push(point([st * libm::cosf(phi), ct, st * libm::sinf(phi)]));
        }
    }
    verts.push(point([0.0, -1.0, 0.0]));
    let south = (verts.len() - 1) as u32;
    let id = |r: usize, s: usize| (1 + r * segments + s % segments) as u32;
    let mut faces = Vec::with_capacity(2 * rings * segments);
    for s in 0..segments {
        // Seen from outside (+y) with phi turning from +x towards +z, i.e. clockwise seen from
        // above, so the counter-clockwise order is (pole, next, this).
        faces.push([0, id(0, s + 1), id(0, s)]);
    }
    for r in 0..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (id(r, s), id(r, s + 1), id(r + 1, s + 1), id(r + 1, s));
            faces.push([a, b, c]);
            faces.push([a, c, d]);
        }
    }
    for s in 0..segments {
        faces.push([south, id(rings - 1, s), id(rings - 1, s + 1)]);
    }
    (verts, faces)
}
