//! The C ABI of `hood`: opaque handles for model, garment and sim, status codes, a thread-local
//! last-error message, and an executor callback for an engine's job system.
//!
//! `include/hood.h` is the contract engines compile against; every item here has its twin there
//! (checked by `tests/header.rs`). The rules the caller must keep (lifetimes of model bytes,
//! threads) are stated in the header.
//!
//! Every export goes through `guard`, which catches panics; handles are checked (models and
//! garments against a registry of live handles, sims against their slots, without a lock), so
//! NULL, freed or mismatched handles give a status code.
#![deny(unsafe_op_in_unsafe_fn)]
// The C names of the types are the Rust names (the header check maps them one to one).
#![allow(non_camel_case_types)]

#[cfg_attr(not(feature = "allocator"), allow(dead_code))]
mod alloc;
mod arrays;
mod body;
mod config;
mod consts;
mod driver;
mod executor;
mod extensible;
mod garment;
mod guard;
mod hooks;
mod log;
mod model;
mod registry;
mod sim;
mod slots;
mod state;
mod status;

pub use body::{hood_body_desc, hood_body_survey, hood_garment_push_out, hood_sim_body_survey};
pub use config::{hood_sim_config, hood_sim_config_default, hood_sim_config_init};
pub use consts::{
    hood_version, hood_version_string, HOOD_EFFECT_AUTO_TELEPORT, HOOD_EFFECT_BODY_COLLISION,
    HOOD_EFFECT_COLLISION_PROJECTION, HOOD_EFFECT_NORMALS, HOOD_EFFECT_PINNING, HOOD_EFFECT_REFINE,
    HOOD_EFFECT_SLEEPING, HOOD_EFFECT_SPEED_LIMIT, HOOD_EFFECT_STARTUP, HOOD_EFFECT_TETHER, HOOD_LOG_ERROR,
    HOOD_LOG_WARNING, HOOD_MAX_FACES, HOOD_MAX_MODEL_BYTES, HOOD_MAX_VERTICES, HOOD_MODEL_ALIGN, HOOD_PRECISION_BF16,
    HOOD_PRECISION_F32, HOOD_STEP_OVER_BUDGET, HOOD_STEP_PROJECTED, HOOD_STEP_REFINED, HOOD_STEP_SLEPT,
    HOOD_STEP_SPEED_LIMITED, HOOD_STEP_STARTUP, HOOD_STEP_TELEPORTED, HOOD_STEP_TETHERED, HOOD_VERSION_MAJOR,
    HOOD_VERSION_MINOR, HOOD_VERSION_PATCH,
};
pub use driver::{
    hood_driver, hood_driver_free, hood_driver_model_steps, hood_driver_new, hood_driver_update, DriverHandle,
};
pub use executor::{hood_executor, hood_sim_set_executor, hood_task_fn};
pub use garment::{
    hood_garment, hood_garment_face_count, hood_garment_free, hood_garment_new, hood_garment_vertex_count,
    hood_material,
};
pub use guard::hood_last_error;
pub use hooks::{hood_allocator, hood_log_fn, hood_set_allocator, hood_set_log_callback};
pub use model::{
    hood_model, hood_model_free, hood_model_get_info, hood_model_has_bf16, hood_model_info, hood_model_load,
    hood_model_text, HOOD_MODEL_TEXT_PROVENANCE, HOOD_MODEL_TEXT_SCHEDULE,
};
pub use sim::{
    hood_refinement, hood_sim, hood_sim_body_vertex_count, hood_sim_free, hood_sim_last_effects,
    hood_sim_last_refinement, hood_sim_new, hood_sim_normals, hood_sim_positions, hood_sim_step, hood_sim_velocities,
    hood_sim_vertex_count, SimHandle,
};
pub use state::{
    hood_sim_load_state, hood_sim_reset, hood_sim_save_state, hood_sim_set_pin_targets, hood_sim_state_size,
    hood_sim_teleport,
};
pub use status::{
    hood_status, hood_status_string, HOOD_ERR_BAD_POINTER, HOOD_ERR_BUSY, HOOD_ERR_CAPACITY_EXCEEDED,
    HOOD_ERR_CORRUPT_DATA, HOOD_ERR_DEGENERATE_FACE, HOOD_ERR_EMPTY, HOOD_ERR_INCOMPATIBLE_MODEL,
    HOOD_ERR_INDEX_OUT_OF_RANGE, HOOD_ERR_INSIDE_OUT, HOOD_ERR_INVALID_HANDLE, HOOD_ERR_IO, HOOD_ERR_MODEL_IN_USE,
    HOOD_ERR_NON_FINITE, HOOD_ERR_NULL_POINTER, HOOD_ERR_OUT_OF_RANGE, HOOD_ERR_PANIC, HOOD_ERR_PARSE,
    HOOD_ERR_REPEATED_VERTEX, HOOD_ERR_SIZE_MISMATCH, HOOD_ERR_STRUCT_SIZE, HOOD_ERR_TOO_LATE,
    HOOD_ERR_UNSUPPORTED_EFFECT, HOOD_ERR_UNUSED_VERTEX, HOOD_OK,
};
