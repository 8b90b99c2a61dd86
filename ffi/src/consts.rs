//! The header's constants other than status codes: limits, effect and step flags, log levels,
//! precisions and the version, with the version exports.

use std::ffi::c_char;

/// Required alignment of model bytes (`hood::model::file::ALIGN`).
pub const HOOD_MODEL_ALIGN: usize = hood::model::file::ALIGN;

/// Most vertices of a garment or a body (`hood::limits::MAX_VERTICES`).
pub const HOOD_MAX_VERTICES: usize = hood::limits::MAX_VERTICES;
/// Most triangles of a garment or a body (`hood::limits::MAX_FACES`).
pub const HOOD_MAX_FACES: usize = hood::limits::MAX_FACES;
/// Most bytes of a model file, and of the weights its spec needs (`hood::limits::MAX_MODEL_BYTES`).
pub const HOOD_MAX_MODEL_BYTES: usize = hood::limits::MAX_MODEL_BYTES;

/// Effect flag: collision with the body.
pub const HOOD_EFFECT_BODY_COLLISION: u32 = 1;
/// Effect flag: pinned vertices follow their targets.
pub const HOOD_EFFECT_PINNING: u32 = 2;
/// Effect flag: output vertex normals.
pub const HOOD_EFFECT_NORMALS: u32 = 4;
/// Effect flag: sleeping.
pub const HOOD_EFFECT_SLEEPING: u32 = 8;
/// Effect flag: start-up (relaxation) step.
pub const HOOD_EFFECT_STARTUP: u32 = 16;
/// Effect flag: carry the garment along when the body jumps farther than the threshold.
pub const HOOD_EFFECT_AUTO_TELEPORT: u32 = 32;
/// Body speeds beyond `speed_limit` carry the garment instead of reaching the network.
pub const HOOD_EFFECT_SPEED_LIMIT: u32 = 64;
/// Push garment vertices that end up within `projection_margin` of the body out to it.
pub const HOOD_EFFECT_COLLISION_PROJECTION: u32 = 128;
/// Refine every network step by `refine_iterations` L-BFGS iterations of the physics objective.
pub const HOOD_EFFECT_REFINE: u32 = 256;
/// Keep every worn garment vertex within its distance from the body vertex it was put on plus
/// `tether_slack`.
pub const HOOD_EFFECT_TETHER: u32 = 512;
pub(crate) const ALL_EFFECTS: u32 = 1023;

/// Step flag: the garment was moved rigidly instead of stepped (a body jump, or
/// `hood_sim_teleport`).
pub const HOOD_STEP_TELEPORTED: u32 = 1;
/// Step flag: sleeping; the step was skipped.
pub const HOOD_STEP_SLEPT: u32 = 2;
/// Step flag: the start-up pass ran.
pub const HOOD_STEP_STARTUP: u32 = 4;
/// Step flag: the speed limit carried the garment.
pub const HOOD_STEP_SPEED_LIMITED: u32 = 8;
/// Step flag: a refinement (or the solver step mode's solve) ran.
pub const HOOD_STEP_REFINED: u32 = 16;
/// Step flag: the collision projection moved a vertex.
pub const HOOD_STEP_PROJECTED: u32 = 32;
/// Step flag: the step took longer than the solver's time budget.
pub const HOOD_STEP_OVER_BUDGET: u32 = 64;
/// Step flag: a body tether pulled a vertex back.
pub const HOOD_STEP_TETHERED: u32 = 128;

/// Log level: an internal error (a panic caught at the boundary).
pub const HOOD_LOG_ERROR: u32 = 1;
/// Log level: a warning (e.g. a body too coarse for its collisions).
pub const HOOD_LOG_WARNING: u32 = 2;

/// f32 arithmetic.
pub const HOOD_PRECISION_F32: u32 = 0;
/// bf16 weights and activations past the encoders (which run in f32).
pub const HOOD_PRECISION_BF16: u32 = 1;

const fn parse_u32(s: &str) -> u32 {
    let b = s.as_bytes();
    let mut v = 0;
    let mut i = 0;
    while i < b.len() {
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    v
}

/// `HOOD_VERSION_MAJOR`, from Cargo.toml.
pub const HOOD_VERSION_MAJOR: u32 = parse_u32(env!("CARGO_PKG_VERSION_MAJOR"));
/// `HOOD_VERSION_MINOR`, from Cargo.toml.
pub const HOOD_VERSION_MINOR: u32 = parse_u32(env!("CARGO_PKG_VERSION_MINOR"));
/// `HOOD_VERSION_PATCH`, from Cargo.toml.
pub const HOOD_VERSION_PATCH: u32 = parse_u32(env!("CARGO_PKG_VERSION_PATCH"));

/// The library version, `(major << 16) | (minor << 8) | patch`.
#[no_mangle]
pub extern "C" fn hood_version() -> u32 {
    (HOOD_VERSION_MAJOR << 16) | (HOOD_VERSION_MINOR << 8) | HOOD_VERSION_PATCH
}

/// The library version as a NUL-terminated string with static storage.
#[no_mangle]
pub extern "C" fn hood_version_string() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr() as *const c_char
}
