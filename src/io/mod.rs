//! File formats (feature `std`).

pub mod json;
pub mod bvh;
pub mod safetensors;
