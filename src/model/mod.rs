//! Models: their shape ([`spec`]), the MLPs it implies ([`skeleton`]), their parameters
//! ([`params`]), their files ([`mod@file`]) and, with the feature `tools`, the
//! reference-checkpoint converter (`model::reference`).

pub mod file;
pub mod params;
#[cfg(feature = "tools")]
pub mod reference;
pub mod skeleton;
pub mod spec;

pub use file::{write_model, Model, ModelBytes};
pub use params::{LayerNorm, Linear, Mlp, Normalisers, Params};
pub use skeleton::{Block, MlpShape, Mlps, Role};
pub use spec::{parse_schedule, BlockSpec, EdgeKey, LevelChange, ModelEffects, ModelSpec, HOOD_SCHEDULE};
