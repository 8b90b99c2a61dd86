//! Inertia and gravity (MODEL.md section 6).

use super::{check_len, Cloth, GRAVITY};
use crate::error::Result;
use crate::math::Real;

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
        let m = cloth.mass[i];
        let mut sq = T::ZERO;
        let mut d = [T::ZERO; 3];
        for k in 0..3 {
            d[k] = x[i][k] - (pos[i][k] + velocity[i][k]);
            sq += d[k] * d[k];
        }
        energy += m * sq;
        if let Some(g) = grad.as_deref_mut() {
            let s = m * inv_dt2;
            for k in 0..3 {
                g[i][k] += s * d[k];
            }
        }
    }
    Ok(energy * inv_dt2 * T::from_f64(0.5))
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
        let mg = cloth.mass[i] * gacc;
        energy += mg * x[i][1];
        if let Some(g) = grad.as_deref_mut() {
            g[i][1] += mg;
        }
    }
    Ok(energy)
}
