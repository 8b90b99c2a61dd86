//! Inertia and gravity (MODEL.md section 6).

use super::{check_len, Cloth, GRAVITY};
use crate::error::Result;
use crate::math::{add3, Real};

/// Inertia (J): `sum m |x - (pos + velocity)|² / (2 dt²)`, positions in m, velocity in m/frame,
/// `dt` in s. When `grad` is given, `dE/dx` (J/m) is **added** to it.
///
/// # Errors
/// [`crate::Error::SizeMismatch`] when a buffer does not have one entry per vertex.
pub fn inertia<T: Real>(
    cloth: &Cloth<T>,
    pos: &[[T; 3]],
    velocity: &[[T; 3]],
    dt: T,
    x: &[[T; 3]],
    mut grad: Option<&mut [[T; 3]]>,
) -> Result<T> {
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    check_len("current positions", pos.len(), n)?;
    check_len("velocities", velocity.len(), n)?;
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let inv_dt2 = T::ONE / (dt * dt);
    let mut energy = T::ZERO;
    for i in 0..n {
        let (e, gi) = vertex_inertia(cloth.mass[i], pos[i], velocity[i], inv_dt2, x[i]);
        energy += e;
        if let Some(g) = grad.as_deref_mut() {
            g[i] = add3(g[i], gi);
        }
    }
    Ok(inertia_total(energy, inv_dt2))
}

/// Gravitational energy (J): `sum m × 9.81 × x_y` (y up). When `grad` is given, `m × 9.81` is
/// **added** to its y components.
///
/// # Errors
/// [`crate::Error::SizeMismatch`] when a buffer does not have one entry per vertex.
pub fn gravity<T: Real>(cloth: &Cloth<T>, x: &[[T; 3]], mut grad: Option<&mut [[T; 3]]>) -> Result<T> {
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let gacc = T::from_f64(GRAVITY);
    let mut energy = T::ZERO;
    for i in 0..n {
        let (e, gy) = vertex_gravity(cloth.mass[i], gacc, x[i]);
        energy += e;
        if let Some(g) = grad.as_deref_mut() {
            g[i][1] += gy;
        }
    }
    Ok(energy)
}

/// Vertex inertia before the common factor (`m |x - (pos + velocity)|²`, kg m²) and its
/// gradient (J/m) for `inv_dt2 = 1 / dt²` (1/s²): the one place of the term's per-vertex math;
/// [`inertia_total`] turns a sum of the former into joules.
#[inline(always)]
pub(super) fn vertex_inertia<T: Real>(m: T, pos: [T; 3], velocity: [T; 3], inv_dt2: T, x: [T; 3]) -> (T, [T; 3]) {
    let mut sq = T::ZERO;
    let mut d = [T::ZERO; 3];
    for k in 0..3 {
        d[k] = x[k] - (pos[k] + velocity[k]);
        sq += d[k] * d[k];
    }
    let s = m * inv_dt2;
    (m * sq, [s * d[0], s * d[1], s * d[2]])
}

/// The inertia (J) of a sum of [`vertex_inertia`] energies.
#[inline(always)]
pub(super) fn inertia_total<T: Real>(sum: T, inv_dt2: T) -> T {
    sum * inv_dt2 * T::from_f64(0.5)
}

/// Vertex gravitational energy (J) of mass `m` (kg) at `x` (m) under `gacc` (m/s²), and the y
/// component of its gradient (J/m; the others are zero).
#[inline(always)]
pub(super) fn vertex_gravity<T: Real>(m: T, gacc: T, x: [T; 3]) -> (T, T) {
    let mg = m * gacc;
    (mg * x[1], mg)
}
