//! The trainer (feature `train`): a differentiable forward pass of the whole network that
//! follows the runtime's data path, its backward pass from the physics objective's gradient to
//! every parameter, the optimiser (Adam, learning-rate schedule, clipping), and the training
//! run around them (config, data, loss, checkpoints, validation, export).
//!
//! Parameters are trained in a flat vector ([`layout::Layout`] maps it to and from
//! [`crate::model::Params`]); gradients use the same layout. The network passes are generic
//! over [`crate::math::Real`]: f32 to train, f64 for gradient checks.

pub mod config;
pub mod data;
pub mod inputs;
pub mod layout;
pub mod loss;
pub mod network;
pub mod ops;
pub mod optim;
pub mod session;

pub use config::{SceneSource, TrainConfig};
pub use data::{Dataset, Sample};
pub use inputs::{BodyFrames, GarmentState, StepData};
pub use layout::Layout;
pub use loss::{LossBody, StepLoss};
pub use network::{Network, Stats, Tape};
pub use optim::{clip_global_norm, learning_rate, Adam};
pub use session::{IterationReport, StepReport, Trainer, ValidationReport};
