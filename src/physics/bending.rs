//! Bending: dihedral-angle energy with a flat rest angle (MODEL.md section 6).

use super::{check_len, Cloth};
use crate::error::Result;
use crate::math::{add3, cross3, dot3, neg3, scale3, sub3, Real};

/// `atan2(y, x)`: in `f32` a polynomial one (Cephes' `atanf` reduction and coefficients, about
/// 2e-7 relative error, several times faster than `libm::atan2f`, which dominated the term); in
/// `f64` libm's.
#[inline(always)]
fn atan2<T: Real>(y: T, x: T) -> T {
    if core::mem::size_of::<T>() == 4 {
        T::from_f64(atan2_f32(y.to_f64() as f32, x.to_f64() as f32) as f64)
    } else {
        y.atan2(x)
    }
}

/// Branch-free (selects only: hinge angles have random signs and sizes, and mispredicted
/// branches cost more than the arithmetic): one division, the octant reduction of Cephes' atanf
/// done on `(|y|, |x|)`, a degree-9 odd polynomial, then the quadrant fix-up.
#[inline(always)]
fn atan2_f32(y: f32, x: f32) -> f32 {
    use core::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    const TAN_3PI_8: f32 = 2.414_213_6;
    const TAN_PI_8: f32 = 0.414_213_57;
    let (ay, ax) = (y.abs(), x.abs());
    let big = ay > TAN_3PI_8 * ax;
    let mid = ay > TAN_PI_8 * ax;
    let num = if big {
        -ax
    } else if mid {
        ay - ax
    } else {
        ay
    };
    let den = if big {
        ay
    } else if mid {
        ay + ax
    } else {
        ax
    };
    let base = if big {
        FRAC_PI_2
    } else if mid {
        FRAC_PI_4
    } else {
        0.0
    };
    let t = num / den.max(f32::MIN_POSITIVE);
    let z = t * t;
    let p = (((8.053_744_5e-2 * z - 1.387_768_6e-1) * z + 1.997_771_1e-1) * z - 3.333_295e-1) * z * t + t;
    let r = base + p; // atan(|y| / |x|), in [0, pi/2]
    let r = if x < 0.0 { PI - r } else { r };
    f32::from_bits(r.to_bits() | (y.to_bits() & 0x8000_0000))
}

/// Bending energy (J) at positions `x` (m): per interior edge
/// `k_bend × l² / (4 (area_A + area_B)) × θ² / 2`, with `l` the **current** edge length and
/// `θ = atan2(ê·(n_A×n_B), n_A·n_B)` (radians, rest angle 0; `n` the unit normals of the two
/// triangles in their own vertex order). When `grad` is given, `dE/dx` (J/m) is **added** to it.
///
/// The angle's gradient uses the closed form of the dihedral angle's derivatives (the opposite
/// vertex `a` of a triangle moves the angle by `l / h_a` per metre along the normal, the edge
/// vertices share the opposite move by the foot point of `a` on the edge), which is the exact
/// derivative of the formula above and needs no normalised normals.
///
/// # Errors
/// [`crate::Error::SizeMismatch`] when `x` or `grad` does not have one entry per vertex.
pub fn bending<T: Real>(cloth: &Cloth<T>, x: &[[T; 3]], mut grad: Option<&mut [[T; 3]]>) -> Result<T> {
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let mut energy = T::ZERO;
    for (hi, h) in cloth.hinges.iter().enumerate() {
        let [v0, v1] = h.edge.map(|i| i as usize);
        let [va, vb] = h.opposite.map(|i| i as usize);
        match grad.as_deref_mut() {
            Some(g) => {
                let (e, [c0, c1, ca, cb]) = hinge_bending::<T, true>(cloth, hi, x);
                energy += e;
                g[va] = add3(g[va], ca);
                g[vb] = add3(g[vb], cb);
                g[v1] = add3(g[v1], c1);
                g[v0] = add3(g[v0], c0);
            }
            None => energy += hinge_bending::<T, false>(cloth, hi, x).0,
        }
    }
    Ok(energy)
}

/// Hinge `hi`'s bending energy (J) at `x` (m) and, with `GRAD`, its gradient with respect to its
/// edge vertices and then its two opposite vertices (`[edge[0], edge[1], opposite[0],
/// opposite[1]]`, J/m; zero without `GRAD`): the one place of the term's math, which [`bending`]
/// scatters and the task-split evaluation gathers.
#[inline(always)]
pub(super) fn hinge_bending<T: Real, const GRAD: bool>(cloth: &Cloth<T>, hi: usize, x: &[[T; 3]]) -> (T, [[T; 3]; 4]) {
    let tiny = T::from_f64(1e-30);
    let two = T::from_f64(2.0);
    let h = &cloth.hinges[hi];
    let coef = cloth.bend_coef[hi];
    let [v0, v1] = h.edge.map(|i| i as usize);
    let [va, vb] = h.opposite.map(|i| i as usize);
    let x0 = x[v0];
    let e = sub3(x[v1], x0);
    let (ra, rb) = (sub3(x[va], x0), sub3(x[vb], x0));
    // Normals up to the triangles' orientation: n_A ∝ ±pa, n_B ∝ ±pb.
    let pa = cross3(e, ra);
    let pb = cross3(e, rb);
    let l2 = dot3(e, e).max(tiny);
    let l = l2.sqrt();
    let (mut sy, mut cx) = (dot3(e, cross3(pa, pb)), l * dot3(pa, pb));
    if h.consistent {
        // Opposite traversals: n_A = pa/|pa|, n_B = -pb/|pb|.
        sy = -sy;
        cx = -cx;
    }
    let theta = atan2(sy, cx);
    let energy = coef * l2 * theta * theta;
    if !GRAD {
        return (energy, [[T::ZERO; 3]; 4]);
    }
    // dθ/da = -l pa / |pa|², dθ/db = l pb / |pb|²; edge vertices by foot points.
    let ga = scale3(pa, -l / dot3(pa, pa).max(tiny));
    let gb = scale3(pb, l / dot3(pb, pb).max(tiny));
    let inv_l2 = T::ONE / l2;
    let (aa, ab) = (dot3(ra, e) * inv_l2, dot3(rb, e) * inv_l2);
    let gt = two * coef * l2 * theta;
    let gl = two * coef * theta * theta; // d(l²)/dx = 2 e, so dE/de = coef θ² 2 e
    let ge = scale3(e, gl);
    let d1 = add3(scale3(ga, aa), scale3(gb, ab));
    let d0 = sub3(add3(ga, gb), d1);
    let c0 = neg3(add3(ge, scale3(d0, gt)));
    let c1 = sub3(ge, scale3(d1, gt));
    (energy, [c0, c1, scale3(ga, gt), scale3(gb, gt)])
}

#[cfg(test)]
mod tests {
    #[test]
    fn physics_fast_atan2_f32_matches_libm() {
        let mut worst: f64 = 0.0;
        for i in 0..200_000 {
            let t = (i as f64 / 200_000.0) * 2.0 * core::f64::consts::PI - core::f64::consts::PI;
            for r in [1e-3, 1.0, 7.5] {
                let (y, x) = ((r * t.sin()) as f32, (r * t.cos()) as f32);
                let want = (y as f64).atan2(x as f64);
                let got = super::atan2_f32(y, x) as f64;
                worst = worst.max((got - want).abs() / want.abs().max(1e-30));
            }
        }
        assert!(worst < 5e-7, "worst relative error {worst:e}");
        assert_eq!(super::atan2_f32(0.0, 0.0), 0.0);
        assert_eq!(super::atan2_f32(1.0, 0.0), core::f32::consts::FRAC_PI_2);
    }
}
