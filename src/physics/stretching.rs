//! Stretching: StVK membrane energy on the rest frames (MODEL.md section 6).

use super::{check_len, Cloth};
use crate::error::Result;
use crate::math::{add3, dot3, neg3, scale3, sub3, Real};

/// Stretching energy (J) at positions `x` (m): per triangle
/// `area × thickness × (mu |G|² + lambda/2 tr(G)²)` with `G = (FᵀF - I)/2`,
/// `F = [x0 - x2, x1 - x2] Dm⁻¹`. When `grad` is given, `dE/dx` (J/m) is **added** to it.
///
/// # Errors
/// [`crate::Error::SizeMismatch`] when `x` or `grad` does not have one entry per vertex.
pub fn stretching<T: Real>(cloth: &Cloth<T>, x: &[[T; 3]], mut grad: Option<&mut [[T; 3]]>) -> Result<T> {
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let mut energy = T::ZERO;
    for (fi, f) in cloth.faces.iter().enumerate() {
        let [i0, i1, i2] = f.map(|i| i as usize);
        match grad.as_deref_mut() {
            Some(g) => {
                let (e, [c0, c1, c2]) = face_stretching::<T, true>(cloth, fi, x);
                energy += e;
                g[i0] = add3(g[i0], c0);
                g[i1] = add3(g[i1], c1);
                g[i2] = add3(g[i2], c2);
            }
            None => energy += face_stretching::<T, false>(cloth, fi, x).0,
        }
    }
    Ok(energy)
}

/// Triangle `fi`'s stretching energy (J) at `x` (m) and, with `GRAD`, its gradient with respect
/// to its three vertices in face order (J/m; zero without `GRAD`): the one place of the term's
/// math, which [`stretching`] scatters and the task-split evaluation gathers.
#[inline(always)]
pub(super) fn face_stretching<T: Real, const GRAD: bool>(
    cloth: &Cloth<T>,
    fi: usize,
    x: &[[T; 3]],
) -> (T, [[T; 3]; 3]) {
    let half = T::from_f64(0.5);
    let two = T::from_f64(2.0);
    let [i0, i1, i2] = cloth.faces[fi].map(|i| i as usize);
    let (d0, d1) = (sub3(x[i0], x[i2]), sub3(x[i1], x[i2]));
    let [a, b, c, d] = cloth.dm_inv[fi];
    // Columns of F = Ds Dm^-1.
    let f0 = add3(scale3(d0, a), scale3(d1, c));
    let f1 = add3(scale3(d0, b), scale3(d1, d));
    let g00 = (dot3(f0, f0) - T::ONE) * half;
    let g11 = (dot3(f1, f1) - T::ONE) * half;
    let g01 = dot3(f0, f1) * half;
    let tr = g00 + g11;
    let (km, kl) = (cloth.stretch_mu[fi], cloth.stretch_lambda[fi]);
    let energy = km * (g00 * g00 + g11 * g11 + two * g01 * g01) + kl * tr * tr;
    if !GRAD {
        return (energy, [[T::ZERO; 3]; 3]);
    }
    // S = dE/dG (symmetric), P = F S, dE/dDs = P Dm^-T.
    let s00 = two * (km * g00 + kl * tr);
    let s11 = two * (km * g11 + kl * tr);
    let s01 = two * km * g01;
    let p0 = add3(scale3(f0, s00), scale3(f1, s01));
    let p1 = add3(scale3(f0, s01), scale3(f1, s11));
    let c0 = add3(scale3(p0, a), scale3(p1, b));
    let c1 = add3(scale3(p0, c), scale3(p1, d));
    (energy, [c0, c1, neg3(add3(c0, c1))])
}
