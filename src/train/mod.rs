//! The trainer (feature `train`): a differentiable forward pass of the whole network that
//! follows the runtime's data path, its backward pass from the physics objective's gradient to
//! every parameter, the optimiser (Adam, learning-rate schedule, clipping), and the training
//! run around them (config, data, loss, checkpoints, validation, export).
//!
//! Parameters are trained in a flat vector ([`layout::Layout`] maps it to and from
//! [`crate::model::Params`]); gradients use the same layout. The reference passes
//! ([`Network::forward`], [`Network::backward`]) are generic over [`crate::math::Real`] (f64 for
//! gradient checks); training runs the f32 fast path ([`Network::forward_fast`],
//! [`Network::backward_fast`] with a [`FastWorkspace`]: SIMD products, two threads, no
//! allocation per step), fed by an [`InputBuilder`].

pub mod config;
pub mod data;
pub mod fast;
pub mod gemm;
pub mod inputs;
pub mod layout;
pub mod loss;
pub mod network;
pub mod ops;
pub mod optim;
pub mod session;

pub use config::{SceneSource, TrainConfig};
pub use data::{Dataset, Sample};
pub use fast::FastWorkspace;
pub use gemm::{Gemm, Mat, Out, TileChoice};
pub use inputs::{BodyFrames, GarmentState, InputBuilder, StepData};
pub use layout::Layout;
pub use loss::{LossBody, StepLoss};
pub use network::{Network, Stats, Tape};
pub use optim::{clip_global_norm, learning_rate, Adam};
pub use session::{IterationReport, StepReport, Track, Trainer, ValidationReport};
