//! `hood`: HOOD-style neural cloth.
//!
//! A hierarchical graph network advances a garment on an animated body by one frame at a time
//! (Grigorev et al., *HOOD*, CVPR 2023). This crate holds the garment graph and its coarse levels,
//! the network features, the body queries, the allocation-free inference step, the physics
//! objective and (feature `train`) the trainer.
//!
//! Units everywhere: metres, kilograms, seconds; **y is up**; positions handed to the network are
//! per frame at the model's 30 Hz.
//!
//! ```
//! use hood::mesh::{Garment, GarmentDesc};
//! // One quad of 1 m x 1 m cloth, split into two triangles.
//! let rest = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]];
//! let faces = [[0, 2, 1], [0, 3, 2]];
//! let garment = Garment::new(GarmentDesc::new(&rest, &faces)).unwrap();
//! assert_eq!(garment.edges().len(), 5);
//! assert_eq!(garment.hinges().len(), 1);
//! ```
//!
//! # Features
//!
//! Without features beyond the default, the library is the runtime: what an engine (or the C ABI,
//! `hood-ffi`) needs to load a model, build a garment and a body, and step ([`model`], [`mesh`],
//! [`body`], [`sim`] and what they stand on). It is `#![no_std]` with `alloc`.
//!
//! * `std` (default): reading model files, run-time CPU dispatch, the thread pool, the wall clock.
//! * `tools` (implies `std`): making content and measuring the runtime on it: asset readers and
//!   writers (`io`), rigs, skinning and procedural content (`rig`), animated scenes (`scene`),
//!   evaluation (`eval`), previews (`render`), the named workloads and step timing (`workloads`,
//!   `bench`, `kernels::peak`), the assets folder (`assets`) and the reference-checkpoint
//!   converter (`model::reference`). The file formats' crates come with it.
//! * `train` (implies `tools`): the trainer (`train`).
//! * `cli` (implies `tools`): the `hood` command line.
#![no_std]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(missing_docs, clippy::missing_safety_doc)]
// Numeric kernels read better with explicit index loops over several parallel arrays.
#![allow(clippy::needless_range_loop)]

extern crate alloc;
#[cfg(feature = "std")]
extern crate std;

/// The README's examples, compiled and run by `cargo test --doc`.
#[cfg(all(doctest, feature = "std"))]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;

/// The chainable setters of a `#[non_exhaustive]` config struct, inside its `impl` block: one
/// `with_<field>(self, value: <field's type>) -> Self` per `doc, with_name => field: Type;`.
macro_rules! with_fields {
    ($($(#[$doc:meta])* $with:ident => $field:ident: $ty:ty;)*) => {
        $(
            $(#[$doc])*
            #[must_use]
            pub fn $with(mut self, value: $ty) -> Self {
                self.$field = value;
                self
            }
        )*
    };
}

#[cfg(feature = "tools")]
pub mod assets;
#[cfg(feature = "tools")]
pub mod bench;
pub mod body;
pub mod checksum;
pub mod error;
#[cfg(feature = "tools")]
pub mod eval;
pub mod exec;
pub mod features;
pub mod hierarchy;
#[cfg(feature = "tools")]
pub mod io;
pub mod kernels;
pub mod limits;
pub mod math;
pub mod mesh;
pub mod model;
pub mod normaliser;
pub mod physics;
#[cfg(feature = "tools")]
pub mod render;
#[cfg(feature = "tools")]
pub mod rig;
pub mod rng;
#[cfg(feature = "tools")]
pub mod scene;
pub mod sim;
pub mod solve;
#[cfg(feature = "train")]
pub mod train;
#[cfg(feature = "tools")]
pub mod workloads;

pub use error::{Error, Result};
