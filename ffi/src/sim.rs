//! Sim handles: creating and freeing a sim, claiming it for a call, stepping it and reading what
//! it holds.

use crate::arrays::{disjoint, points, points_mut, require, write_out};
use crate::body::{hood_body_desc, read_body};
use crate::config::{hood_sim_config, sim_config};
use crate::consts::{
    HOOD_LOG_WARNING, HOOD_STEP_OVER_BUDGET, HOOD_STEP_PROJECTED, HOOD_STEP_REFINED, HOOD_STEP_SLEPT,
    HOOD_STEP_SPEED_LIMITED, HOOD_STEP_STARTUP, HOOD_STEP_TELEPORTED, HOOD_STEP_TETHERED,
};
use crate::extensible::{read_struct, write_extensible, Extensible};
use crate::garment::hood_garment;
use crate::guard::guard;
use crate::log;
use crate::model::hood_model;
use crate::registry::{live, use_live, Kind};
use crate::slots;
use crate::status::{hood_status, Failure, Result};
use hood::error::check_len;
use hood::model::Model;
use hood::sim::{BodyDesc, Sim, SimConfig, StepMode};
use hood::Error;
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A sim handle: a slot of `SIMS` (see the `slots` module), checked and claimed without a lock.
pub type hood_sim = slots::Slot<SimHandle>;

/// Live sims: the step and every other call on a sim take no lock (see [`slots`]).
static SIMS: slots::Slots<SimHandle> = slots::Slots::new();

/// A simulation borrowing its model, held by a [`hood_sim`] slot.
pub struct SimHandle {
    /// Borrows `*model`; `'static` stands for "while registered in `model.sims`", which
    /// `hood_model_free` enforces.
    pub(crate) sim: ManuallyDrop<Sim<'static>>,
    model: *const hood_model,
}

// SAFETY: the model pointer is only used to release the sim's count in it (an atomic), from
// whichever thread drops the sim; the model itself is shared read-only (see the header).
unsafe impl Send for SimHandle {}
// SAFETY: shared access only reads the sim (`Sim` is `Sync`) and never the model pointer.
unsafe impl Sync for SimHandle {}

impl Drop for SimHandle {
    fn drop(&mut self) {
        // SAFETY: dropped once, here, and never used afterwards.
        unsafe { ManuallyDrop::drop(&mut self.sim) };
        // Only now may the model go.
        // SAFETY: the model outlives every sim counted in it, and this sim is still counted.
        unsafe { &*self.model }.sims.fetch_sub(1, Ordering::SeqCst);
    }
}

/// One sim's share of a model's count of live sims, released on drop unless forgotten.
struct SimCount<'a>(&'a AtomicUsize);

impl Drop for SimCount<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Creates a sim (see the header).
///
/// # Safety
/// Handles are NULL or pointers from this library (checked); `body` and `config` are NULL or
/// hold the `struct_size` bytes they state; `body`'s arrays hold the documented counts; `out` is
/// NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_new(
    model: *const hood_model,
    garment: *const hood_garment,
    body: *const hood_body_desc,
    config: *const hood_sim_config,
    out: *mut *mut hood_sim,
) -> hood_status {
    guard(|| {
        require(out, "out")?;
        // Held to the end: a log callback below may try to free the garment (refused meanwhile).
        let _garment_in_use = use_live(garment, Kind::Garment, "garment")?;
        let cfg = if config.is_null() {
            SimConfig::default()
        } else {
            // SAFETY: non-null; `struct_size` readable bytes (caller).
            sim_config(&unsafe { read_struct(config, "config")? })?
        };
        // SAFETY: a live garment handle, held by `_garment_in_use`.
        let garment = &unsafe { &*garment }.garment;
        let body_parts = if body.is_null() {
            None
        } else {
            // SAFETY: the caller's promise.
            let (_, mesh, pos) = unsafe { read_body(body)? };
            Some((mesh, pos))
        };
        // Count the sim in the model under the registry lock, so that `hood_model_free` on
        // another thread sees it (or the model is already gone and this fails).
        {
            let reg = live();
            if model.is_null() {
                return Err(Failure::Null("model"));
            }
            if reg.get(&(model as usize)).map(|e| e.kind) != Some(Kind::Model) {
                return Err(Failure::Handle("model"));
            }
            // SAFETY: a live model handle.
            unsafe { &*model }.sims.fetch_add(1, Ordering::SeqCst);
        }
        // Released on every way out but success (an error, or a panic caught by `guard`), so
        // that a failed creation never leaves the model "in use".
        // SAFETY: the model is live (our count holds it).
        let count = SimCount(unsafe { &(*model).sims });
        // SAFETY: the model is live and cannot be freed while its count includes this sim; the
        // count is released when the sim is dropped (or by `count` on failure), so the
        // `'static` borrow never outlives the model.
        let m: &'static Model<'static> = unsafe { &(*model).model };
        let bd = body_parts.as_ref().map(|(mesh, pos)| BodyDesc { mesh, positions: pos });
        match Sim::new(m, garment, bd, cfg) {
            Ok(sim) => {
                if let Some(b) = sim.body_survey().filter(|b| b.too_coarse_for(hood::sim::BODY_EDGE_RADIUS)) {
                    log::log(
                        HOOD_LOG_WARNING,
                        &format!(
                            "the body mesh is too coarse for the {} m body-edge radius: its median edge is {:.3} m \
                             (at most {:.3} m), so unpinned cloth may fall through between its vertices; use a finer body",
                            hood::sim::BODY_EDGE_RADIUS,
                            b.median_edge,
                            3f32.sqrt() * hood::sim::BODY_EDGE_RADIUS
                        ),
                    );
                }
                // The sim holds the count from here on (released when it is dropped).
                std::mem::forget(count);
                let handle = SimHandle { sim: ManuallyDrop::new(sim), model };
                // On failure the handle is dropped, releasing the model's count.
                let h = insert_slot(&SIMS, handle, "live sims")?;
                // SAFETY: `out` checked non-null.
                unsafe { write_out(out, h) };
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    })
}

/// Frees a sim; [`HOOD_ERR_BUSY`] (freeing nothing) while a call on another thread uses it.
///
/// # Safety
/// `sim` is NULL or a handle (checked against the sim slots).
///
/// [`HOOD_ERR_BUSY`]: crate::HOOD_ERR_BUSY
#[no_mangle]
pub unsafe extern "C" fn hood_sim_free(sim: *mut hood_sim) -> hood_status {
    guard(|| free_slot(&SIMS, sim, "sim"))
}

/// Makes `value` live in a slot of `slots`.
pub(crate) fn insert_slot<T>(slots: &slots::Slots<T>, value: T, what: &'static str) -> Result<*mut slots::Slot<T>> {
    let capacity = slots::CAPACITY;
    slots.insert(Box::new(value)).ok_or(Error::CapacityExceeded { what, capacity, needed: capacity + 1 }.into())
}

/// Frees the value of the slot at `p` (NULL: nothing to do); busy while a call holds it.
pub(crate) fn free_slot<T>(slots: &slots::Slots<T>, p: *const slots::Slot<T>, what: &'static str) -> Result<()> {
    if p.is_null() {
        return Ok(());
    }
    // Dropped here, outside the slot allocator's lock.
    drop(slots.remove(p).map_err(|e| claim_failure(e, what))?);
    Ok(())
}

pub(crate) fn claim_failure(e: slots::ClaimError, what: &'static str) -> Failure {
    match e {
        slots::ClaimError::NotLive => Failure::Handle(what),
        slots::ClaimError::Busy => Failure::Busy(what),
    }
}

/// A call's claim on a live sim: shared (reads) or exclusive (changes), released on drop.
type SimAccess = slots::Claim<'static, SimHandle>;

/// Checks and claims `sim` (exclusive: no other call may be in progress; shared: no exclusive
/// one). Takes no lock.
fn access(sim: *const hood_sim, exclusive: bool) -> Result<SimAccess> {
    require(sim, "sim")?;
    SIMS.claim(sim, exclusive).map_err(|e| claim_failure(e, "sim"))
}

/// Shared access for a call that reads the sim.
pub(crate) fn sim_ref(sim: *const hood_sim) -> Result<SimRead> {
    Ok(SimRead(access(sim, false)?))
}

/// Exclusive access for a call that changes the sim.
pub(crate) fn sim_mut(sim: *mut hood_sim) -> Result<SimWrite> {
    Ok(SimWrite(access(sim, true)?))
}

/// Shared access: derefs to `&SimHandle` only.
pub(crate) struct SimRead(SimAccess);

/// Exclusive access: derefs to `&mut SimHandle`.
pub(crate) struct SimWrite(SimAccess);

impl std::ops::Deref for SimRead {
    type Target = SimHandle;
    fn deref(&self) -> &SimHandle {
        self.0.get()
    }
}

impl std::ops::Deref for SimWrite {
    type Target = SimHandle;
    fn deref(&self) -> &SimHandle {
        self.0.get()
    }
}

impl std::ops::DerefMut for SimWrite {
    fn deref_mut(&mut self) -> &mut SimHandle {
        self.0.get_mut().unwrap_or_else(|| unreachable!("a write claim is exclusive"))
    }
}

/// Garment vertex count.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_vertex_count(sim: *const hood_sim, out: *mut usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, s.sim.garment().n_vertices()) };
        Ok(())
    })
}

/// The last network step's solver refinement (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct hood_refinement {
    /// `sizeof(hood_refinement)` in the caller's header, set before the call.
    pub struct_size: u32,
    /// Accepted L-BFGS iterations.
    pub iterations: u32,
    /// Objective at the network's prediction, J.
    pub energy_before: f32,
    /// Objective after the refinement, J.
    pub energy_after: f32,
    /// The time budget of a step, ns (0: none).
    pub budget_ns: u64,
    /// The step's time, ns (0 without a budget).
    pub used_ns: u64,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_refinement {
    const NAME: &'static str = "hood_refinement";
}

/// The last network step's solver refinement (all zero before the first one).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or a `hood_refinement` of the
/// `struct_size` it states.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_last_refinement(sim: *const hood_sim, out: *mut hood_refinement) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        if s.sim.config().refine.is_none() && s.sim.config().step == StepMode::Network {
            return Err(Error::UnsupportedEffect {
                effect: "refinement (HOOD_EFFECT_REFINE is off and the solver step mode is not on)",
            }
            .into());
        }
        let budget = s.sim.last_budget();
        let r = s.sim.last_refinement().map_or(hood_refinement::default(), |r| hood_refinement {
            struct_size: 0,
            iterations: r.iterations as u32,
            energy_before: r.f_start as f32,
            energy_after: r.f as f32,
            budget_ns: budget.map_or(0, |b| b.budget_ns),
            used_ns: budget.map_or(0, |b| b.used_ns),
        });
        // SAFETY: `out` is a `hood_refinement` of its `struct_size` (caller).
        unsafe { write_extensible(out, r, "out") }
    })
}

/// Body vertex count expected per step (0 without a body).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_body_vertex_count(sim: *const hood_sim, out: *mut usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(out, "out")?;
        // SAFETY: `out` non-null.
        unsafe { write_out(out, s.sim.state().body_pos.len()) };
        Ok(())
    })
}

/// What the last successful step did, as `HOOD_STEP_*` flags (see the header; teleports, resets
/// and loaded states report as [`Sim::last_effects`] does).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `flags` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_last_effects(sim: *const hood_sim, flags: *mut u32) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        require(flags, "flags")?;
        let e = s.sim.last_effects();
        let flag = |on: bool, f: u32| if on { f } else { 0 };
        let v = flag(e.teleported, HOOD_STEP_TELEPORTED)
            | flag(e.slept, HOOD_STEP_SLEPT)
            | flag(e.startup, HOOD_STEP_STARTUP)
            | flag(e.carried, HOOD_STEP_SPEED_LIMITED)
            | flag(e.refined, HOOD_STEP_REFINED)
            | flag(e.projected, HOOD_STEP_PROJECTED)
            | flag(e.over_budget, HOOD_STEP_OVER_BUDGET)
            | flag(e.tethered, HOOD_STEP_TETHERED);
        // SAFETY: `flags` non-null.
        unsafe { write_out(flags, v) };
        Ok(())
    })
}

/// Advances one frame (see the header).
///
/// # Safety
/// `sim` is NULL or a handle (checked); arrays hold the stated counts; `garment_out` does not
/// overlap `body_next`.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_step(
    sim: *mut hood_sim,
    body_next: *const f32,
    n_body_vertices: usize,
    garment_out: *mut f32,
    n_garment_vertices: usize,
) -> hood_status {
    guard(|| {
        let mut s = sim_mut(sim)?;
        check_len("body vertices", n_body_vertices, s.sim.state().body_pos.len())?;
        check_len("garment output vertices", n_garment_vertices, s.sim.garment().n_vertices())?;
        require(garment_out, "garment_out")?;
        let (input, output) = (body_next as *const [f32; 3], garment_out as *const [f32; 3]);
        disjoint(input, n_body_vertices, output, n_garment_vertices, "garment_out")?;
        // SAFETY: counts are the caller's promise.
        let body = unsafe { points(body_next, n_body_vertices, "body_next")? };
        // SAFETY: as above.
        let out = unsafe { points_mut(garment_out, n_garment_vertices, "garment_out")? };
        let pos = s.sim.step(body)?;
        out.copy_from_slice(pos);
        Ok(())
    })
}

fn copy_out(src: &[[f32; 3]], out: *mut f32, n: usize, what: &'static str) -> Result<()> {
    check_len(what, n, src.len())?;
    require(out, "out")?;
    // SAFETY: `out` holds 3n floats (caller).
    unsafe { points_mut(out, n, "out")? }.copy_from_slice(src);
    Ok(())
}

/// Current garment positions.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_positions(sim: *const hood_sim, out: *mut f32, n_vertices: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        copy_out(s.sim.positions(), out, n_vertices, "position output vertices")
    })
}

/// Current garment velocities, m/frame.
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_velocities(sim: *const hood_sim, out: *mut f32, n_vertices: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        copy_out(&s.sim.state().velocity, out, n_vertices, "velocity output vertices")
    })
}

/// Vertex normals of the current positions (needs `HOOD_EFFECT_NORMALS`).
///
/// # Safety
/// `sim` is NULL or a handle (checked); `out` holds `3 * n_vertices` floats.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_normals(sim: *const hood_sim, out: *mut f32, n_vertices: usize) -> hood_status {
    guard(|| {
        let s = sim_ref(sim)?;
        if !s.sim.config().normals {
            return Err(Error::UnsupportedEffect { effect: "normals (HOOD_EFFECT_NORMALS is off)" }.into());
        }
        copy_out(s.sim.normals(), out, n_vertices, "normal output vertices")
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{hood_garment_free, hood_garment_new, hood_model_load, HOOD_OK};
    use std::ptr::{null, null_mut};

    /// A sim of a random model (the bytes are leaked: they outlive the model).
    fn small_sim() -> *mut hood_sim {
        let spec = hood::model::ModelSpec::hood(8);
        let mut p = hood::model::Params::init(&spec, 3).unwrap();
        p.normalisers = hood::model::Normalisers::unit_scale(3);
        let file = hood::model::write_model(&p, false, &[]).unwrap();
        let bytes: &'static hood::model::ModelBytes = Box::leak(Box::new(hood::model::ModelBytes::new(&file)));
        let (rest, faces) = hood::mesh::shapes::grid(3, 3, 0.3, 0.3, 0.0);
        let (mut model, mut garment, mut sim) = (null_mut(), null_mut(), null_mut());
        // SAFETY: arrays of the stated lengths; the model bytes are leaked.
        unsafe {
            let b = bytes.as_bytes();
            assert_eq!(hood_model_load(b.as_ptr(), b.len(), &mut model), HOOD_OK);
            let (r, f) = (rest.as_ptr().cast(), faces.as_ptr().cast());
            assert_eq!(hood_garment_new(r, rest.len(), f, faces.len(), null(), 0, null(), &mut garment), HOOD_OK);
            assert_eq!(hood_sim_new(model, garment, null(), null(), &mut sim), HOOD_OK);
            assert_eq!(hood_garment_free(garment), HOOD_OK);
        }
        sim
    }

    /// The calls on a sim, the step first, need neither the handle registry's lock nor the sim
    /// slots' allocator lock: they finish while another thread holds both.
    #[test]
    fn calls_on_a_sim_take_no_lock() {
        let sim = small_sim() as usize;
        let registry = live();
        let allocator = SIMS.hold_lock();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let sim = sim as *mut hood_sim;
            let mut out = [[0.0f32; 3]; 9];
            let mut codes = Vec::new();
            // SAFETY: a live sim; `out` holds 9 points.
            unsafe {
                for _ in 0..3 {
                    codes.push(hood_sim_step(sim, null(), 0, out.as_mut_ptr().cast(), 9));
                }
                codes.push(hood_sim_positions(sim, out.as_mut_ptr().cast(), 9));
                codes.push(hood_sim_velocities(sim, out.as_mut_ptr().cast(), 9));
            }
            let _ = tx.send(codes);
        });
        let codes = rx.recv_timeout(std::time::Duration::from_secs(60)).expect("a call on a sim waited for a lock");
        assert!(codes.iter().all(|&c| c == HOOD_OK), "{codes:?}");
        drop((registry, allocator));
        // SAFETY: a live, idle sim.
        assert_eq!(unsafe { hood_sim_free(sim as *mut hood_sim) }, HOOD_OK);
    }
}
