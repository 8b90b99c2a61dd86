//! Changing a sim other than by a step: pin targets, reset, teleport, and saving and loading its
//! whole state.

use crate::arrays::{points, require, slice, slice_mut, write_out};
use crate::guard::guard;
use crate::sim::{hood_sim, sim_mut, sim_ref};
use crate::status::{hood_status, Result};
use glam::{Mat3, Quat, Vec3};
use hood::body::rigid::RigidMotion;
use hood::error::check_len;
use hood::sim::SimState;
use hood::Error;

/// Sets the pin targets for the next frame.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `targets` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_set_pin_targets(
    sim: *mut hood_sim,
    targets: *const f32,
    n_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        check_len("pin targets", n_vertices, s.sim.garment().n_vertices())?;
        require(targets, "targets")?;
        // SAFETY: count is the caller's promise.
        let t = unsafe { points(targets, n_vertices, "targets")? };
        s.sim.set_pin_targets(t)?;
        Ok(())
    })
}

/// Restarts from given positions with zero velocity (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); arrays hold the stated counts.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_reset(
    sim: *mut hood_sim,
    positions: *const f32,
    n_vertices: usize,
    body_positions: *const f32,
    n_body_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        let n = s.sim.garment().n_vertices();
        check_len("reset positions", n_vertices, n)?;
        require(positions, "positions")?;
        // SAFETY: counts are the caller's promise.
        let pos = unsafe { points(positions, n_vertices, "positions")? };
        let old = s.sim.state();
        let body = if body_positions.is_null() && n_body_vertices == 0 {
            old.body_pos.clone()
        } else {
            check_len("reset body vertices", n_body_vertices, old.body_pos.len())?;
            // SAFETY: as above.
            unsafe { points(body_positions, n_body_vertices, "body_positions")? }.to_vec()
        };
        let state = SimState {
            pos: pos.to_vec(),
            velocity: vec![[0.0; 3]; n],
            body_prev: body.clone(),
            body_pos: body,
            started: !s.sim.config().startup,
        };
        s.sim.set_state(&state)?;
        // Pins hold where the garment was placed (always finite: `set_state` checked them).
        s.sim.set_pin_targets(pos)?;
        Ok(())
    })
}

/// Bytes of the sim's saved state (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_state_size(sim: *const hood_sim, out: *mut usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, s.sim.saved_state_len()) };
        Ok(())
    })
}

/// Saves the sim's whole state into `out` (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `len` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_save_state(sim: *const hood_sim, out: *mut u8, len: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        check_len("saved state buffer", len, s.sim.saved_state_len())?;
        // SAFETY: `len` writable bytes (caller).
        let buf = unsafe { slice_mut(out, len, "out")? };
        s.sim.save_state(buf)?;
        Ok(())
    })
}

/// Restores a saved state (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `bytes` holds `len` readable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_load_state(sim: *mut hood_sim, bytes: *const u8, len: usize) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        require(bytes, "bytes")?;
        // SAFETY: `len` readable bytes (caller).
        let b = unsafe { slice(bytes, len, "bytes")? };
        s.sim.load_state(b)?;
        Ok(())
    })
}

fn check_rotation(r: &[f32; 9]) -> Result<()> {
    if let Some(i) = r.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite { what: "rotation entry", index: i }.into());
    }
    // R R^T = I within 1e-3, and det R = +1 (no reflection).
    for i in 0..3 {
        for j in 0..3 {
            let d: f32 = (0..3).map(|k| r[3 * i + k] * r[3 * j + k]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            if (d - want).abs() > 1e-3 {
                return Err(Error::OutOfRange { what: "rotation (not orthonormal)", index: 3 * i + j }.into());
            }
        }
    }
    let det =
        r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6]) + r[2] * (r[3] * r[7] - r[4] * r[6]);
    if det < 0.0 {
        return Err(Error::OutOfRange { what: "rotation (a reflection, determinant -1)", index: 0 }.into());
    }
    Ok(())
}

/// Moves the garment rigidly, `p -> R p + t`, `v -> R v`, and puts the body at rest (see the
/// header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `rotation` is NULL or 9 floats; `translation` is NULL
/// or 3 floats; `body_now` is NULL or holds `3 * n_body_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_teleport(
    sim: *mut hood_sim,
    rotation: *const f32,
    translation: *const f32,
    body_now: *const f32,
    n_body_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        let r: [f32; 9] = if rotation.is_null() {
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        } else {
            // SAFETY: 9 readable floats (caller).
            unsafe { slice(rotation, 9, "rotation")? }.try_into().unwrap_or([0.0; 9])
        };
        let t: [f32; 3] = if translation.is_null() {
            [0.0; 3]
        } else {
            // SAFETY: 3 readable floats (caller).
            (unsafe { points(translation, 1, "translation")? })[0]
        };
        check_rotation(&r)?;
        if let Some(i) = t.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite { what: "translation entry", index: i }.into());
        }
        // Row-major in, column-major `Mat3`: transpose.
        let rotation = Quat::from_mat3(&Mat3::from_cols_array(&r).transpose()).normalize();
        let motion = RigidMotion { rotation, translation: Vec3::from_array(t) };
        let body: Vec<[f32; 3]> = if body_now.is_null() && n_body_vertices == 0 {
            s.sim.state().body_pos.iter().map(|p| motion.apply(*p)).collect()
        } else {
            check_len("teleport body vertices", n_body_vertices, s.sim.state().body_pos.len())?;
            require(body_now, "body_now")?;
            // SAFETY: count is the caller's promise.
            unsafe { points(body_now, n_body_vertices, "body_now")? }.to_vec()
        };
        s.sim.teleport(&motion, &body)?;
        Ok(())
    })
}
