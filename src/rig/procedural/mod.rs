//! Procedural scenes that need no files: a mannequin (closed smooth body mesh with a rig and
//! skinning weights), motions for it, and garments fitted to it. These are the embedded defaults
//! of examples, benches and tests.
//!
//! Everything is in metres, y up, the mannequin facing +z with x its left, feet on y = 0, rest
//! pose an A-pose (arms 45 degrees down), motions at 30 Hz.

mod corpus;
mod garments;
mod mannequin;
mod motions;
mod sdf;

pub use corpus::{family_motion, is_held_out, Family, HELD_OUT_SEEDS};
pub use garments::{cape, long_dress, skirt, square_cloth, ProceduralGarment};
pub use mannequin::{Mannequin, DEFAULT_SPACING};
pub use motions::{arm_swings, jump, random_poses, run, turn_on_the_spot, walk, LocalMotion};

#[cfg(test)]
mod tests;
