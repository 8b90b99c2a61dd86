//! File formats (feature `std`).

pub mod json;
pub mod safetensors;
