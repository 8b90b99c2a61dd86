//! The sim's configuration: `hood_sim_config`, its defaults, and its translation into a
//! [`SimConfig`].

use crate::arrays::{aligned, require};
use crate::consts::{
    ALL_EFFECTS, HOOD_EFFECT_AUTO_TELEPORT, HOOD_EFFECT_BODY_COLLISION, HOOD_EFFECT_COLLISION_PROJECTION,
    HOOD_EFFECT_NORMALS, HOOD_EFFECT_PINNING, HOOD_EFFECT_REFINE, HOOD_EFFECT_SLEEPING, HOOD_EFFECT_SPEED_LIMIT,
    HOOD_EFFECT_STARTUP, HOOD_EFFECT_TETHER, HOOD_LOG_WARNING, HOOD_PRECISION_BF16, HOOD_PRECISION_F32,
};
use crate::extensible::{size_problem, struct_size, write_sized, Extensible};
use crate::guard::guard;
use crate::log;
use crate::status::{hood_status, Failure, Result};
use hood::sim::{Precision, SimConfig, Sleeping, StepMode};
use hood::Error;

/// The sim's configuration (see the header).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct hood_sim_config {
    /// `sizeof(hood_sim_config)` in the caller's header (see its Conventions).
    pub struct_size: u32,
    /// `HOOD_EFFECT_*` flags.
    pub effects: u32,
    /// `HOOD_PRECISION_*`.
    pub precision: u32,
    /// Worker threads without an executor.
    pub threads: u32,
    /// Frames at rest before sleeping.
    pub sleep_frames: u32,
    /// "At rest" threshold, m/frame.
    pub sleep_threshold: f32,
    /// Auto-teleport threshold: largest body vertex jump per frame still simulated, m.
    pub teleport_threshold: f32,
    /// Speed limit: largest body centroid motion per frame the network sees, m.
    pub speed_limit: f32,
    /// Collision projection margin, m.
    pub projection_margin: f32,
    /// Solver refinement iterations per step.
    pub refine_iterations: u32,
    /// 0: the network steps; N: the solver step mode, N L-BFGS iterations per step.
    pub solver_iterations: u32,
    /// With `solver_iterations`: each step's solve also ends within this many µs (0: no budget).
    pub solver_budget_us: u32,
    /// Body tethers' slack, m.
    pub tether_slack: f32,
}

// SAFETY: `#[repr(C)]`, `struct_size` first, only integers and floats.
unsafe impl Extensible for hood_sim_config {
    const NAME: &'static str = "hood_sim_config";
    // Version 0.2.0 ended before `solver_budget_us`.
    const MIN_SIZE: usize = std::mem::offset_of!(hood_sim_config, solver_budget_us);

    /// Zero is a slack (tight ties), not "unset": a struct that ends before `tether_slack`
    /// gets the default.
    fn absent_fields() -> Self {
        hood_sim_config { tether_slack: hood::sim::DEFAULT_TETHER_SLACK, ..Default::default() }
    }
}

/// The library's defaults, with `struct_size` this library's `sizeof(hood_sim_config)`.
fn default_config() -> hood_sim_config {
    let d = SimConfig::default();
    let s = Sleeping::default();
    let flag = |on: bool, f: u32| if on { f } else { 0 };
    let effects = flag(d.body_collision, HOOD_EFFECT_BODY_COLLISION)
        | flag(d.pinning, HOOD_EFFECT_PINNING)
        | flag(d.normals, HOOD_EFFECT_NORMALS)
        | flag(d.sleeping.is_some(), HOOD_EFFECT_SLEEPING)
        | flag(d.startup, HOOD_EFFECT_STARTUP)
        | flag(d.teleport.is_some(), HOOD_EFFECT_AUTO_TELEPORT)
        | flag(d.speed_limit.is_some(), HOOD_EFFECT_SPEED_LIMIT)
        | flag(d.projection.is_some(), HOOD_EFFECT_COLLISION_PROJECTION)
        | flag(d.refine.is_some(), HOOD_EFFECT_REFINE)
        | flag(d.tether.is_some(), HOOD_EFFECT_TETHER);
    hood_sim_config {
        struct_size: struct_size::<hood_sim_config>(),
        effects,
        precision: HOOD_PRECISION_F32,
        threads: d.threads as u32,
        sleep_frames: s.frames,
        sleep_threshold: s.threshold,
        teleport_threshold: d.teleport.unwrap_or(hood::sim::DEFAULT_TELEPORT),
        speed_limit: d.speed_limit.unwrap_or(hood::sim::DEFAULT_SPEED_LIMIT),
        projection_margin: d.projection.unwrap_or(hood::sim::DEFAULT_PROJECTION_MARGIN),
        refine_iterations: d.refine.unwrap_or(hood::sim::DEFAULT_REFINE_ITERATIONS),
        solver_budget_us: match d.step {
            StepMode::SolverBudget { micros, .. } => micros,
            _ => 0,
        },
        solver_iterations: match d.step {
            StepMode::Network => 0,
            StepMode::Solver { iterations } | StepMode::SolverBudget { max_iterations: iterations, .. } => iterations,
        },
        tether_slack: d.tether.unwrap_or(hood::sim::DEFAULT_TETHER_SLACK),
    }
}

/// The defaults of the fields version 0.2.0 had, with `struct_size` set to that size: a caller
/// built against that header allocated no more, and this symbol cannot know a caller's size. The
/// header maps the name to [`hood_sim_config_init`] with the caller's `sizeof`.
///
/// # Safety
/// `out` is NULL (ignored) or points to the 0.2.0 struct's bytes, writable and aligned.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_config_default(out: *mut hood_sim_config) {
    // No status to return: a (never expected) panic just leaves `out` unwritten.
    let _ = guard(|| {
        require(out, "out")?;
        aligned(out, "out")?;
        // SAFETY: non-null and aligned; the 0.2.0 struct's bytes are writable (caller).
        unsafe { write_sized(out, default_config(), hood_sim_config::MIN_SIZE) };
        Ok(())
    });
}

/// The defaults into a caller's config of `struct_size` bytes (see the header): the fields this
/// library knows, then zeros up to `struct_size`, and `struct_size` itself.
///
/// # Safety
/// `out` is NULL or points to `struct_size` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn hood_sim_config_init(out: *mut hood_sim_config, struct_size: usize) -> hood_status {
    guard(|| {
        require(out, "out")?;
        aligned(out, "out")?;
        if let Some(why) = size_problem::<hood_sim_config>(struct_size) {
            return Err(Failure::StructSize(format!(
                "hood_sim_config_init: struct_size {struct_size} is {why}; sizeof(hood_sim_config) is {} in this library",
                size_of::<hood_sim_config>()
            )));
        }
        // SAFETY: `struct_size` writable bytes (caller), aligned, checked above.
        unsafe { write_sized(out, default_config(), struct_size) };
        Ok(())
    })
}

/// The runtime's configuration from a caller's `hood_sim_config`, checked.
pub(crate) fn sim_config(c: &hood_sim_config) -> Result<SimConfig> {
    if c.effects & !ALL_EFFECTS != 0 {
        return Err(Error::OutOfRange { what: "config effects (unknown flag)", index: c.effects as usize }.into());
    }
    let precision = match c.precision {
        HOOD_PRECISION_F32 => Precision::F32,
        HOOD_PRECISION_BF16 => Precision::Bf16,
        p => return Err(Error::OutOfRange { what: "config precision", index: p as usize }.into()),
    };
    let sleeping = if c.effects & HOOD_EFFECT_SLEEPING != 0 {
        if !(c.sleep_threshold.is_finite() && c.sleep_threshold >= 0.0) {
            return Err(Error::OutOfRange { what: "config sleep threshold", index: 0 }.into());
        }
        Some(Sleeping::new(c.sleep_threshold, c.sleep_frames))
    } else {
        None
    };
    // A distance of an effect that is on: finite and positive.
    let distance = |flag: u32, value: f32, what: &'static str| -> Result<Option<f32>> {
        if c.effects & flag == 0 {
            return Ok(None);
        }
        if !(value.is_finite() && value > 0.0) {
            return Err(Error::OutOfRange { what, index: 0 }.into());
        }
        Ok(Some(value))
    };
    let teleport = distance(HOOD_EFFECT_AUTO_TELEPORT, c.teleport_threshold, "config teleport threshold")?;
    let speed_limit = distance(HOOD_EFFECT_SPEED_LIMIT, c.speed_limit, "config speed limit")?;
    // The margin's range is checked by the sim (0 <= margin < hood::sim::PROJECTION_REACH).
    let projection = (c.effects & HOOD_EFFECT_COLLISION_PROJECTION != 0).then_some(c.projection_margin);
    // The slack's range is checked by the sim (0 <= slack <= hood::sim::MAX_TETHER_SLACK).
    let tether = (c.effects & HOOD_EFFECT_TETHER != 0).then_some(c.tether_slack);
    // The count's range is checked by the sim (1 ..= hood::sim::MAX_REFINE_ITERATIONS).
    let refine = (c.effects & HOOD_EFFECT_REFINE != 0).then_some(c.refine_iterations);
    // Likewise (and the sim refuses it beside HOOD_EFFECT_REFINE).
    let step = match (c.solver_iterations, c.solver_budget_us) {
        (0, 0) => StepMode::Network,
        (0, _) => {
            return Err(Error::UnsupportedEffect { effect: "a solver time budget without solver_iterations" }.into())
        }
        (iterations, 0) => StepMode::Solver { iterations },
        (max_iterations, micros) => StepMode::SolverBudget { micros, max_iterations },
    };
    // Every field the C struct carries; one it does not (a later addition) keeps its default.
    Ok(SimConfig::default()
        .with_step(step)
        .with_teleport(teleport)
        .with_speed_limit(speed_limit)
        .with_projection(projection)
        .with_tether(tether)
        .with_refine(refine)
        .with_body_collision(c.effects & HOOD_EFFECT_BODY_COLLISION != 0)
        .with_pinning(c.effects & HOOD_EFFECT_PINNING != 0)
        .with_normals(c.effects & HOOD_EFFECT_NORMALS != 0)
        .with_sleeping(sleeping)
        .with_precision(precision)
        .with_startup(c.effects & HOOD_EFFECT_STARTUP != 0)
        .with_tier(None)
        .with_threads(threads(c.threads)?))
}

/// The pool size for `config.threads`: a garbage count (beyond `hood::sim::MAX_THREADS`) is
/// refused; more threads than the machine's cores are capped at the cores, with a warning.
fn threads(asked: u32) -> Result<usize> {
    let asked = asked as usize;
    if asked > hood::sim::MAX_THREADS {
        return Err(Error::OutOfRange { what: "config threads (at most 256)", index: asked }.into());
    }
    let threads = hood::limits::cap_threads(asked);
    if threads < asked {
        log::log(
            HOOD_LOG_WARNING,
            &format!("config threads {asked} capped at the machine's {threads} (more would only wait for each other)"),
        );
    }
    Ok(threads)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::extensible::read_struct;

    /// A config from the 0.2.0 header ends before `tether_slack`: with tethers on it gets the
    /// default slack, not the 0 m (tight ties) a zeroed field would mean, whatever lies past it.
    #[test]
    fn an_older_config_gets_the_default_tether_slack() {
        let mut c = default_config();
        c.struct_size = hood_sim_config::MIN_SIZE as u32;
        c.effects |= HOOD_EFFECT_TETHER;
        c.tether_slack = 0.0; // past the caller's struct: never read
                              // SAFETY: a whole struct, more than its `struct_size` bytes.
        let read = unsafe { read_struct(&c, "config") }.map_err(|e| e.message()).unwrap();
        assert_eq!(sim_config(&read).map_err(|e| e.message()).unwrap().tether, Some(hood::sim::DEFAULT_TETHER_SLACK));
        // The current size reads the field as written.
        c.struct_size = size_of::<hood_sim_config>() as u32;
        // SAFETY: as above.
        let read = unsafe { read_struct(&c, "config") }.map_err(|e| e.message()).unwrap();
        assert_eq!(sim_config(&read).map_err(|e| e.message()).unwrap().tether, Some(0.0));
    }
}
