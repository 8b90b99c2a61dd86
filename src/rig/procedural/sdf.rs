//! Signed distance functions for the mannequin's shape: tapered capsules and ellipsoids blended
//! by a smooth minimum. Values are (approximately) metres, negative inside.

use glam::Vec3;

/// One piece of the shape, attached to a bone.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Primitive {
    /// Segment `a`-`b` with radius varying linearly from `ra` to `rb`.
    Capsule { a: Vec3, b: Vec3, ra: f32, rb: f32 },
    /// Axis-aligned ellipsoid with centre `c` and radii `r`.
    Ellipsoid { c: Vec3, r: Vec3 },
}

impl Primitive {
    pub(crate) fn distance(&self, p: Vec3) -> f32 {
        match *self {
            Primitive::Capsule { a, b, ra, rb } => {
                let ab = b - a;
                let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
                (p - (a + ab * t)).length() - (ra + (rb - ra) * t)
            }
            Primitive::Ellipsoid { c, r } => {
                // Bound by Inigo Quilez: exact on the surface, close to the distance near it.
                let q = p - c;
                let k0 = (q / r).length();
                let k1 = (q / (r * r)).length();
                if k1 == 0.0 {
                    -r.min_element()
                } else {
                    k0 * (k0 - 1.0) / k1
                }
            }
        }
    }
}

/// Polynomial smooth minimum with blend width `k`.
pub(crate) fn smin(a: f32, b: f32, k: f32) -> f32 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// A blended shape: primitives with their bones.
#[derive(Clone, Debug)]
pub(crate) struct Shape {
    pub prims: alloc::vec::Vec<(Primitive, usize)>,
    pub blend: f32,
}

impl Shape {
    /// Signed distance (smooth union of all primitives), restricted to primitives `keep` accepts.
    pub(crate) fn distance_filtered(&self, p: Vec3, keep: impl Fn(usize) -> bool) -> f32 {
        let mut d = f32::INFINITY;
        for (i, (prim, _)) in self.prims.iter().enumerate() {
            if keep(i) {
                let di = prim.distance(p);
                d = if d.is_finite() { smin(d, di, self.blend) } else { di };
            }
        }
        d
    }
    pub(crate) fn distance(&self, p: Vec3) -> f32 {
        self.distance_filtered(p, |_| true)
    }
    /// Bone of the nearest primitive.
    pub(crate) fn nearest_bone(&self, p: Vec3) -> usize {
        let mut best = (f32::INFINITY, 0);
        for (prim, bone) in &self.prims {
            let d = prim.distance(p);
            if d < best.0 {
                best = (d, *bone);
            }
        }
        best.1
    }
    /// Central-difference gradient.
    pub(crate) fn gradient(&self, p: Vec3) -> Vec3 {
        let e = 1e-4;
        let dx = self.distance(p + Vec3::X * e) - self.distance(p - Vec3::X * e);
        let dy = self.distance(p + Vec3::Y * e) - self.distance(p - Vec3::Y * e);
        let dz = self.distance(p + Vec3::Z * e) - self.distance(p - Vec3::Z * e);
        Vec3::new(dx, dy, dz) / (2.0 * e)
    }
}
