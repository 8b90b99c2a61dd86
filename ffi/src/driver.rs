//! Fixed-step driver handles: a sim's clock, stepping it at its own rate and interpolating for
//! the engine's frames.

use crate::arrays::{disjoint, points, points_mut, require, write_out};
use crate::guard::guard;
use crate::sim::{claim_failure, free_slot, hood_sim, insert_slot, sim_mut, sim_ref};
use crate::slots;
use crate::status::hood_status;
use hood::error::check_len;
use hood::sim::Interpolator;

/// A driver handle: a slot of `DRIVERS`, checked and claimed without a lock like a sim's.
pub type hood_driver = slots::Slot<DriverHandle>;

/// Live drivers (see [`slots`]).
static DRIVERS: slots::Slots<DriverHandle> = slots::Slots::new();

/// The fixed-step clock of one sim, which it names by handle (claimed for each update).
pub struct DriverHandle {
    sim: *mut hood_sim,
    clock: Interpolator,
}

// SAFETY: the sim pointer is only a handle, checked and claimed on every use.
unsafe impl Send for DriverHandle {}
// SAFETY: as above; shared access only reads the step count.
unsafe impl Sync for DriverHandle {}

/// Makes a fixed-step driver of `sim` (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_driver_new(sim: *mut hood_sim, out: *mut *mut hood_driver) -> hood_status {
    guard(|| {
        require(out, "out")?;
        let s = sim_ref(sim)?;
        let handle = DriverHandle { sim, clock: Interpolator::new(&s.sim) };
        let h = insert_slot(&DRIVERS, handle, "live drivers")?;
        // SAFETY: `out` checked non-null.
        unsafe { write_out(out, h) };
        Ok(())
    })
}

/// Frees a driver (its sim stays).
///
/// # Safety
/// `driver` is NULL or a handle (checked against the driver slots).
#[no_mangle]
pub unsafe extern "C" fn hood_driver_free(driver: *mut hood_driver) -> hood_status {
    guard(|| free_slot(&DRIVERS, driver, "driver"))
}

/// Advances engine time by `dt` seconds and writes the interpolated garment (see the header).
///
/// # Safety
/// `driver` is NULL or a handle (checked); arrays hold the stated counts; `garment_out` does not
/// overlap `body_now`.
#[no_mangle]
pub unsafe extern "C" fn hood_driver_update(
    driver: *mut hood_driver,
    dt: f32,
    body_now: *const f32,
    n_body_vertices: usize,
    garment_out: *mut f32,
    n_garment_vertices: usize,
) -> hood_status {
    guard(|| {
        require(driver, "driver")?;
        let mut d = DRIVERS.claim(driver, true).map_err(|e| claim_failure(e, "driver"))?;
        let d = d.get_mut().unwrap_or_else(|| unreachable!("a write claim is exclusive"));
        let mut s = sim_mut(d.sim)?;
        require(garment_out, "garment_out")?;
        let (input, output) = (body_now as *const [f32; 3], garment_out as *const [f32; 3]);
        disjoint(input, n_body_vertices, output, n_garment_vertices, "garment_out")?;
        check_len("garment output vertices", n_garment_vertices, s.sim.garment().n_vertices())?;
        // SAFETY: counts are the caller's promise.
        let body = unsafe { points(body_now, n_body_vertices, "body_now")? };
        // SAFETY: as above.
        let out = unsafe { points_mut(garment_out, n_garment_vertices, "garment_out")? };
        let pos = d.clock.update(&mut s.sim, dt, body)?;
        out.copy_from_slice(pos);
        Ok(())
    })
}

/// Model steps a driver has taken.
///
/// # Safety
/// `driver` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_driver_model_steps(driver: *const hood_driver, out: *mut u64) -> hood_status {
    guard(|| {
        require(driver, "driver")?;
        let d = DRIVERS.claim(driver, false).map_err(|e| claim_failure(e, "driver"))?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, d.get().clock.model_steps()) };
        Ok(())
    })
}
