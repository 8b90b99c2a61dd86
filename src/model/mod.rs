//! Models: their shape ([`spec`]), the MLPs it implies ([`skeleton`]), their parameters
//! ([`params`]), their file form ([`mod@file`]) and, under `std`, the reference-checkpoint converter
//! ([`mod@reference`]).

pub mod file;
pub mod params;
#[cfg(feature = "std")]
pub mod reference;
pub mod skeleton;
pub mod spec;

pub use file::{write_model, Model, ModelBytes};
pub use params::{LayerNorm, Linear, Mlp, Normalisers, Params};
pub use skeleton::{Block, MlpShape, Mlps, Role};
pub use spec::{parse_schedule, BlockSpec, EdgeKey, LevelChange, ModelEffects, ModelSpec, HOOD_SCHEDULE};
