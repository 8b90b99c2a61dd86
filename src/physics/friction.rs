//! Friction with the body (supplement eq. 5-10), with the reference's three quirks as parameters
//! (MODEL.md sections 6 and 8).

use super::{check_len, Cloth, FaceFrame, GRAVITY};
use crate::error::{Error, Result};
use crate::math::{add3, dot3, scale3, sub3, Real};

/// How the friction radius is compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RadiusMode {
    /// `distance < radius` (physical).
    Distance,
    /// `distance² < radius` (the reference: radius 3e-3 acts as 0.055 m).
    SquaredDistance,
}

/// Which body frames are `(B_a, B_b)`: the frame the current garment positions sit on and the
/// frame the predicted positions sit on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrictionFrames {
    /// `(body current, body next)` (physical).
    CurrentNext,
    /// `(body previous, body current)`: the reference, one frame behind the garment.
    PrevCurrent,
}

/// Friction parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionParams {
    /// Friction coefficient (dimensionless).
    pub mu: f64,
    /// Contact radius: metres, or m² with [`RadiusMode::SquaredDistance`].
    pub radius: f64,
    /// How `radius` is compared.
    pub radius_mode: RadiusMode,
    /// Axis of the floor normal in the `|cos|` factor: 1 (y, physical) or 2 (z, reference).
    pub floor_axis: usize,
    /// Which body frames are used.
    pub frames: FrictionFrames,
}

impl FrictionParams {
    /// `hood`'s physical form: radius 3 mm as a distance, floor normal y, frames (current, next).
    pub const PHYSICAL: FrictionParams = FrictionParams {
        mu: 0.5,
        radius: 3e-3,
        radius_mode: RadiusMode::Distance,
        floor_axis: 1,
        frames: FrictionFrames::CurrentNext,
    };
    /// The reference's form (postcvpr): radius 3e-3 against squared distances, floor normal z,
    /// frames (previous, current).
    pub const REFERENCE: FrictionParams = FrictionParams {
        mu: 0.5,
        radius: 3e-3,
        radius_mode: RadiusMode::SquaredDistance,
        floor_axis: 2,
        frames: FrictionFrames::PrevCurrent,
    };
}

impl Default for FrictionParams {
    fn default() -> Self {
        FrictionParams::PHYSICAL
    }
}

/// Whether a point at `p` is within the contact radius of a face centroid `c` (m), as `params`
/// compares it: friction's test on either side. A vertex that fails it at `B_a` takes no part
/// whatever its face at `B_b`, so a solver need not search that face.
pub fn within_friction_radius<T: Real>(p: [T; 3], c: [T; 3], params: &FrictionParams) -> bool {
    let d = sub3(p, c);
    let r2 = dot3(d, d);
    let r = if params.radius_mode == RadiusMode::SquaredDistance { r2 } else { r2.sqrt() };
    r < T::from_f64(params.radius)
}

/// Friction energy (J). For every vertex, `u = nearest_a[i]` is the face whose centroid at `B_a`
/// is nearest to `pos_i`, `w = nearest_b[i]` the one whose centroid at `B_b` is nearest to `x_i`;
/// the vertex takes part when both distances are below the radius. With
/// `n = (n_u(B_a) + n_w(B_b)) / 2`, `D = x - (pos + c_u(B_b) - c_u(B_a))`,
/// `D_t = D - (D·n) n`, `c = |cos ∠(floor, D_t)|`:
/// `E = sum mu × m × 9.81 × sqrt(|1 - c²| + 1e-4) × |D_t|`.
/// When `grad` is given, `dE/dx` is **added** to it (the indices are held fixed).
///
/// # Errors
/// [`Error::SizeMismatch`] for buffers of the wrong length; [`Error::IndexOutOfRange`] for a
/// nearest index past the body's faces or a floor axis above 2.
#[allow(clippy::too_many_arguments)]
pub fn friction<T: Real>(
    cloth: &Cloth<T>,
    pos: &[[T; 3]],
    x: &[[T; 3]],
    frame_a: FaceFrame<'_, T>,
    frame_b: FaceFrame<'_, T>,
    nearest_a: &[u32],
    nearest_b: &[u32],
    params: &FrictionParams,
    mut grad: Option<&mut [[T; 3]]>,
) -> Result<T> {
    let n = cloth.n_vertices();
    check_len("positions", x.len(), n)?;
    check_len("current positions", pos.len(), n)?;
    check_len("friction nearest faces (a)", nearest_a.len(), n)?;
    check_len("friction nearest faces (b)", nearest_b.len(), n)?;
    let nf = frame_a.centroids.len();
    for len in [frame_a.normals.len(), frame_b.centroids.len(), frame_b.normals.len()] {
        check_len("body face frames", len, nf)?;
    }
    if let Some(g) = grad.as_deref() {
        check_len("gradient", g.len(), n)?;
    }
    let axis = params.floor_axis;
    if axis > 2 {
        return Err(Error::IndexOutOfRange { what: "floor axis", at: 0, index: axis, len: 3 });
    }
    let mu_g = T::from_f64(params.mu * GRAVITY);
    let mut energy = T::ZERO;
    for i in 0..n {
        let (u, w) = (nearest_a[i] as usize, nearest_b[i] as usize);
        if u >= nf || w >= nf {
            return Err(Error::IndexOutOfRange { what: "friction nearest body face", at: i, index: u.max(w), len: nf });
        }
        let (e, gi) = vertex_friction(mu_g * cloth.mass[i], pos[i], x[i], [u, w], frame_a, frame_b, params);
        energy += e;
        if let Some(g) = grad.as_deref_mut() {
            g[i] = add3(g[i], gi);
        }
    }
    Ok(energy)
}

/// One vertex's friction energy (J) and gradient (J/m): `k = mu × 9.81 × m` (N), `pos` and `x`
/// the vertex now and predicted (m), `faces = [u, w]` its nearest faces at `B_a` and `B_b` (in
/// range, checked by the caller); zero when the vertex is not in contact. The one place of the
/// term's per-vertex math.
#[inline(always)]
pub(super) fn vertex_friction<T: Real>(
    k: T,
    pos: [T; 3],
    x: [T; 3],
    faces: [usize; 2],
    frame_a: FaceFrame<'_, T>,
    frame_b: FaceFrame<'_, T>,
    params: &FrictionParams,
) -> (T, [T; 3]) {
    let none = (T::ZERO, [T::ZERO; 3]);
    let [u, w] = faces;
    if !(within_friction_radius(pos, frame_a.centroids[u], params)
        && within_friction_radius(x, frame_b.centroids[w], params))
    {
        return none;
    }
    let half = T::from_f64(0.5);
    let reg = T::from_f64(1e-4);
    let tiny = T::from_f64(1e-30);
    let axis = params.floor_axis;
    let nrm = scale3(add3(frame_a.normals[u], frame_b.normals[w]), half);
    let x_hat = add3(pos, sub3(frame_b.centroids[u], frame_a.centroids[u]));
    let d = sub3(x, x_hat);
    let q = sub3(d, scale3(nrm, dot3(d, nrm)));
    let l2 = dot3(q, q);
    let l = l2.sqrt();
    if l <= tiny {
        return none;
    }
    let a = q[axis];
    let h = T::ONE - a * a / l2;
    let s = (h.abs() + reg).sqrt();
    // dE/dq = k (s q / l + l ds/dq), ds/dq = sign(h) / (2 s) dh/dq,
    // dh/dq = 2 a² q / l⁴ - 2 a f / l².
    let sign = if h < T::ZERO { -T::ONE } else { T::ONE };
    let ds = sign / (T::from_f64(2.0) * s);
    let mut gq = scale3(q, k * (s / l + l * ds * T::from_f64(2.0) * a * a / (l2 * l2)));
    gq[axis] -= k * l * ds * T::from_f64(2.0) * a / l2;
    // q = (I - n nᵀ) d is symmetric in d.
    (k * s * l, sub3(gq, scale3(nrm, dot3(gq, nrm))))
}
