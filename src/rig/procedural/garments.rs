//! Garments fitted to the [`Mannequin`] at rest, at any resolution: square cloth, skirt with a
//! pinnable waist, long dress, cape pinned at the shoulders. Each is a regular grid of quads
//! split into triangles (counter-clockwise seen from outside), placed at least [`MARGIN`] outside
//! the mannequin's surface.

use super::Mannequin;
use crate::error::{Error, Result};
use crate::mesh::{Garment, GarmentDesc};
use alloc::vec;
use alloc::vec::Vec;
use core::f32::consts::{PI, TAU};
use glam::Vec3;
use libm::{cosf, roundf, sinf, sqrtf};

/// Clearance between a garment at rest and the mannequin's surface, metres.
pub const MARGIN: f32 = 0.012;

/// A procedural garment: rest mesh (metres) and the vertices it is meant to be pinned by.
#[derive(Clone, Debug, PartialEq)]
pub struct ProceduralGarment {
    /// What it is ("skirt", ...).
    pub name: &'static str,
    /// Rest positions, metres.
    pub rest: Vec<[f32; 3]>,
    /// Triangles, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
    /// Suggested pinned vertices (the skirt's waist, the cape's shoulders; none for the others).
    pub pins: Vec<u32>,
}

impl ProceduralGarment {
    /// The [`Garment`], with the suggested pins set or not.
    pub fn garment(&self, pinned: bool) -> Result<Garment> {
        let mut flags = vec![false; self.rest.len()];
        if pinned {
            for &p in &self.pins {
                flags[p as usize] = true;
            }
        }
        Garment::new(GarmentDesc::new(&self.rest, &self.faces).pinned(&flags))
    }
}

fn check_target(n: usize) -> Result<()> {
    if !(16..=1_000_000).contains(&n) {
        return Err(Error::OutOfRange { what: "garment vertex count", index: n });
    }
    Ok(())
}

/// Quads of an `nu x nv` grid (u fastest), wrapping in u when `closed`, triangles oriented so
/// that `(u, -v)` tangents give the outward side.
fn grid_faces(nu: usize, nv: usize, closed: bool) -> Vec<[u32; 3]> {
    crate::mesh::shapes::grid_triangles(nu, nv, closed)
}

/// The smallest radius along the horizontal ray at angle `theta` (0 = +z, pi/2 = +x) from the
/// body axis at height `y` beyond which `dist` stays above `margin` (searched out to 0.8 m).
fn clear_radius(dist: &dyn Fn(Vec3) -> f32, theta: f32, y: f32, margin: f32) -> f32 {
    let dir = Vec3::new(sinf(theta), 0.0, cosf(theta));
    let at = |r: f32| dist(Vec3::new(0.0, y, 0.0) + dir * r);
    let step = 0.004;
    let mut r = 0.8;
    while r > 0.0 && at(r) >= margin {
        r -= step;
    }
    if r <= 0.0 {
        return 0.0;
    }
    // Bisect between r (too close) and r + step (clear).
    let (mut lo, mut hi) = (r, r + step);
    for _ in 0..12 {
        let m = 0.5 * (lo + hi);
        if at(m) >= margin {
            hi = m;
        } else {
            lo = m;
        }
    }
    hi
}

/// A hanging surface of revolution-like shape: rows from `y_top` down to `y_bottom`, columns at
/// angles `thetas`; each row clears the body (per `dist`) by `MARGIN`, never narrows below the
/// row above it once under `y_hang` (cloth hangs), and flares by `flare` m per m of drop.
#[allow(clippy::too_many_arguments)]
fn hanging_rows(
    dist: &dyn Fn(Vec3) -> f32,
    thetas: &[f32],
    nv: usize,
    y_top: f32,
    y_bottom: f32,
    y_hang: f32,
    flare: f32,
    min_radius: f32,
) -> Vec<[f32; 3]> {
    let nu = thetas.len();
    let mut rest = Vec::with_capacity(nu * nv);
    let mut prev = vec![0.0f32; nu];
    for j in 0..nv {
        let y = y_top + (y_bottom - y_top) * j as f32 / (nv - 1) as f32;
        let req: Vec<f32> = thetas.iter().map(|&t| clear_radius(dist, t, y, MARGIN).max(min_radius)).collect();
        // Light smoothing around the row (max with a cosine-weighted neighbourhood keeps clearance).
        let mut r: Vec<f32> = (0..nu)
            .map(|i| {
                let mut best = req[i];
                for k in 1..=3 {
                    for n in [(i + k) % nu, (i + nu - k) % nu] {
                        best = best.max(req[n] * (1.0 - 0.04 * k as f32));
                    }
                }
                best
            })
            .collect();
        if y < y_hang && j > 0 {
            let dy = (y_top - y_bottom) / (nv - 1) as f32;
            for i in 0..nu {
                r[i] = r[i].max(prev[i] + flare * dy);
            }
        }
        for i in 0..nu {
            rest.push([r[i] * sinf(thetas[i]), y, r[i] * cosf(thetas[i])]);
        }
        prev = r;
    }
    rest
}

/// Columns and rows for about `target` vertices on a sheet `width` x `length` metres.
fn grid_size(target: usize, width: f32, length: f32) -> (usize, usize) {
    let nu = roundf(sqrtf(target as f32 * width / length)).max(3.0) as usize;
    let nv = roundf(target as f32 / nu as f32).max(2.0) as usize;
    (nu, nv)
}

/// A flat square of cloth, 1 m x 1 m, horizontal, 5 cm above the top of the head, with about
/// `target_vertices` vertices. No suggested pins (it drapes over the head and shoulders).
pub fn square_cloth(body: &Mannequin, target_vertices: usize) -> Result<ProceduralGarment> {
    check_target(target_vertices)?;
    let top = body.rest().iter().map(|p| p[1]).fold(f32::NEG_INFINITY, f32::max);
    let n = roundf(sqrtf(target_vertices as f32)).max(2.0) as usize;
    let (rest, faces) = crate::mesh::shapes::grid(n, n, 1.0, 1.0, top + 0.05);
    Ok(ProceduralGarment { name: "square cloth", rest, faces, pins: Vec::new() })
}

/// A skirt from the waist (y = 1.02 m) to just above the knees, flaring, with about
/// `target_vertices` vertices; its pins are the waist ring.
pub fn skirt(body: &Mannequin, target_vertices: usize) -> Result<ProceduralGarment> {
    check_target(target_vertices)?;
    let (nu, nv) = grid_size(target_vertices, 1.4, 0.5);
    let thetas: Vec<f32> = (0..nu).map(|i| TAU * i as f32 / nu as f32).collect();
    let trunk = |p: Vec3| body.trunk_distance(p);
    let rest = hanging_rows(&trunk, &thetas, nv, 1.02, 0.55, 0.95, 0.25, 0.05);
    Ok(ProceduralGarment { name: "skirt", rest, faces: grid_faces(nu, nv, true), pins: (0..nu as u32).collect() })
}

/// A strapless long dress from mid-chest (y = 1.27 m) to 12 cm above the floor, fitted above
/// the hips and flaring below, with about `target_vertices` vertices; its pins are the top ring.
pub fn long_dress(body: &Mannequin, target_vertices: usize) -> Result<ProceduralGarment> {
    check_target(target_vertices)?;
    let (nu, nv) = grid_size(target_vertices, 1.5, 1.15);
    let thetas: Vec<f32> = (0..nu).map(|i| TAU * i as f32 / nu as f32).collect();
    let trunk = |p: Vec3| body.trunk_distance(p);
    let rest = hanging_rows(&trunk, &thetas, nv, 1.27, 0.12, 0.95, 0.18, 0.05);
    Ok(ProceduralGarment { name: "long dress", rest, faces: grid_faces(nu, nv, true), pins: (0..nu as u32).collect() })
}

/// A cape over the back from shoulder to shoulder (150 degrees around the back) down to the
/// back of the knees, with about `target_vertices` vertices; its pins are the top edge (on the
/// shoulders and the base of the neck).
pub fn cape(body: &Mannequin, target_vertices: usize) -> Result<ProceduralGarment> {
    check_target(target_vertices)?;
    let (nu, nv) = grid_size(target_vertices, 0.7, 1.0);
    let span = 150.0f32.to_radians();
    // Angles run from the right shoulder across the back to the left one so that, with rows
    // going down, the grid's (u, -v) tangents face away from the body.
    let thetas: Vec<f32> = (0..nu).map(|i| PI + span * (0.5 - i as f32 / (nu - 1) as f32)).collect();
    let full = |p: Vec3| body.signed_distance(p.into());
    let mut rest = hanging_rows(&full, &thetas, nv, 1.47, 0.5, 1.47, 0.06, 0.08);
    // Flip the order of columns if needed so normals point outward (checked on the first quad).
    let faces = grid_faces(nu, nv, false);
    let f = faces[0];
    let (a, b, c) = (Vec3::from(rest[f[0] as usize]), Vec3::from(rest[f[1] as usize]), Vec3::from(rest[f[2] as usize]));
    let n = (b - a).cross(c - a);
    let out = Vec3::new(a.x, 0.0, a.z);
    if n.dot(out) < 0.0 {
        for j in 0..nv {
            rest[j * nu..(j + 1) * nu].reverse();
        }
    }
    Ok(ProceduralGarment { name: "cape", rest, faces, pins: (0..nu as u32).collect() })
}
