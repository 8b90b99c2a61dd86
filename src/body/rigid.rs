//! The rigid motion that best maps one set of points onto another (least squares, Horn's
//! quaternion method), used to carry a garment along when the body teleports.

use glam::{DMat3, DQuat, DVec3, Quat, Vec3};

/// A rotation then a translation: `x -> rotation * x + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidMotion {
    /// Rotation.
    pub rotation: Quat,
    /// Translation, metres.
    pub translation: Vec3,
}

impl RigidMotion {
    /// Applies the motion to a point.
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        (self.rotation * Vec3::from_array(p) + self.translation).to_array()
    }

    /// Applies only the rotation (for velocities and normals).
    pub fn rotate(&self, v: [f32; 3]) -> [f32; 3] {
        (self.rotation * Vec3::from_array(v)).to_array()
    }
}

/// The rigid motion minimising `Σ |R a_i + t - b_i|²` over paired points. Allocates nothing.
/// With fewer than three non-collinear points the rotation is not unique; one minimiser is
/// returned.
pub fn best_rigid_motion(a: &[[f32; 3]], b: &[[f32; 3]]) -> RigidMotion {
    let n = a.len().min(b.len()).max(1) as f64;
    let ca = a.iter().fold(DVec3::ZERO, |s, p| s + Vec3::from_array(*p).as_dvec3()) / n;
    let cb = b.iter().fold(DVec3::ZERO, |s, p| s + Vec3::from_array(*p).as_dvec3()) / n;
    // Cross-covariance S = Σ (a - ca)(b - cb)^T.
    let mut s = [[0.0f64; 3]; 3];
    for (p, q) in a.iter().zip(b) {
        let (x, y) = (Vec3::from_array(*p).as_dvec3() - ca, Vec3::from_array(*q).as_dvec3() - cb);
        let (x, y) = (x.to_array(), y.to_array());
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += x[i] * y[j];
            }
        }
    }
    // Horn's symmetric 4x4 matrix; its top eigenvector is the rotation quaternion (w, x, y, z).
    let (sxx, sxy, sxz) = (s[0][0], s[0][1], s[0][2]);
    let (syx, syy, syz) = (s[1][0], s[1][1], s[1][2]);
    let (szx, szy, szz) = (s[2][0], s[2][1], s[2][2]);
    let mut m = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let q = top_eigenvector(&mut m);
    let rot = DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize();
    let rot = if rot.is_finite() { rot } else { DQuat::IDENTITY };
    let t = cb - DMat3::from_quat(rot) * ca;
    RigidMotion { rotation: rot.as_quat(), translation: t.as_vec3() }
}

/// Eigenvector of the largest eigenvalue of a symmetric 4x4 matrix (cyclic Jacobi).
fn top_eigenvector(a: &mut [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + crate::math::sqrt_f64(theta * theta + 1.0));
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / crate::math::sqrt_f64(t * t + 1.0);
                let s = t * c;
                for k in 0..4 {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..4 {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4).max_by(|&i, &j| a[i][i].total_cmp(&a[j][j])).unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn body_query_rigid_motion_is_recovered() {
        let mut rng = Rng::new(9);
        let pts: alloc::vec::Vec<[f32; 3]> = (0..200)
            .map(|_| [rng.uniform(-1.0, 1.0) as f32, rng.uniform(0.0, 2.0) as f32, rng.uniform(-0.3, 0.3) as f32])
            .collect();
        for (axis, angle) in
            [(Vec3::Y, core::f32::consts::PI), (Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7), (Vec3::X, 0.0)]
        {
            let m =
                RigidMotion { rotation: Quat::from_axis_angle(axis, angle), translation: Vec3::new(1.0, -0.2, 0.4) };
            let moved: alloc::vec::Vec<[f32; 3]> = pts.iter().map(|p| m.apply(*p)).collect();
            let fit = best_rigid_motion(&pts, &moved);
            for (p, q) in pts.iter().zip(&moved) {
                let r = fit.apply(*p);
                assert!((0..3).all(|k| (r[k] - q[k]).abs() < 1e-4), "angle {angle}: {r:?} vs {q:?}");
            }
        }
    }
}
