//! Bending: dihedral-angle energy with a flat rest angle (MODEL.md section 6).

use super::{check_len, Cloth};
use crate::error::Result;
use crate::math::{add3, cross3, dot3, norm3, scale3, sub3, Real, V3};

/// Unnormalised face normal `(x1 - x0) × (x2 - x0)` and its two edge vectors.
#[inline(always)]
fn face_normal<T: Real>(x: &[[T; 3]], f: [u32; 3]) -> (V3<T>, V3<T>, V3<T>) {
    let x0 = x[f[0] as usize];
    let u = sub3(x[f[1] as usize], x0);
    let v = sub3(x[f[2] as usize], x0);
    (cross3(u, v), u, v)
}

/// Adds to `g` the gradient reaching the three vertices of `f` from `gn = dE/dn`, where
/// `n = N / |N|` and `N = u × v`.
#[inline(always)]
fn backprop_normal<T: Real>(g: &mut [[T; 3]], f: [u32; 3], gn: V3<T>, n: V3<T>, inv_len: T, u: V3<T>, v: V3<T>) {
    let gnn = scale3(sub3(gn, scale3(n, dot3(gn, n))), inv_len);
    let gu = cross3(v, gnn);
    let gv = cross3(gnn, u);
    let [i0, i1, i2] = f.map(|i| i as usize);
    g[i1] = add3(g[i1], gu);
    g[i2] = add3(g[i2], gv);
    g[i0] = sub3(g[i0], add3(gu, gv));
}

/// Bending energy (J) at positions `x` (m): per interior edge
/// `k_bend × l² / (4 (area_A + area_B)) × θ² / 2`, with `l` the **current** edge length and
/// `θ = atan2(ê·(n_A×n_B), n_A·n_B)` (radians, rest angle 0). When `grad` is given, `dE/dx`
/// (J/m) is **added** to it.
///
/// # Errors
/// [`crate::Error::SizeMismatch`] when `x` or `grad` does not have one entry per vertex.
pub fn bending<T: Real>(cloth: &Cloth<T>, x: &[[T; 3]], mut grad: Option<&mut [[T; 3]]>) -> Result<T> {
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let tiny = T::from_f64(1e-30);
    let two = T::from_f64(2.0);
    let mut energy = T::ZERO;
    for (h, &coef) in cloth.hinges.iter().zip(&cloth.bend_coef) {
        let (na_raw, ua, va) = face_normal(x, h.face_a);
        let (nb_raw, ub, vb) = face_normal(x, h.face_b);
        let inv_a = T::ONE / norm3(na_raw).max(tiny);
        let inv_b = T::ONE / norm3(nb_raw).max(tiny);
        let (na, nb) = (scale3(na_raw, inv_a), scale3(nb_raw, inv_b));
        let [v0, v1] = h.edge.map(|i| i as usize);
        let e = sub3(x[v1], x[v0]);
        let l = norm3(e).max(tiny);
        let inv_l = T::ONE / l;
        let eh = scale3(e, inv_l);
        let nab = cross3(na, nb);
        let c = dot3(na, nb);
        let s = dot3(eh, nab);
        let theta = s.atan2(c);
        let l2 = l * l;
        energy += coef * l2 * theta * theta;
        if let Some(g) = grad.as_deref_mut() {
            let r = (s * s + c * c).max(tiny);
            let gt = two * coef * l2 * theta / r;
            let gl = two * coef * l * theta * theta;
            let gna = scale3(sub3(scale3(cross3(nb, eh), c), scale3(nb, s)), gt);
            let gnb = scale3(sub3(scale3(cross3(eh, na), c), scale3(na, s)), gt);
            let geh = scale3(nab, gt * c);
            let ge = add3(scale3(eh, gl), scale3(sub3(geh, scale3(eh, dot3(geh, eh))), inv_l));
            g[v1] = add3(g[v1], ge);
            g[v0] = sub3(g[v0], ge);
            backprop_normal(g, h.face_a, gna, na, inv_a, ua, va);
            backprop_normal(g, h.face_b, gnb, nb, inv_b, ub, vb);
        }
    }
    Ok(energy)
}
