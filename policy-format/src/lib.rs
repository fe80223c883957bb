//! The MARS checkpoint format: what a trained policy *is*, apart from how it was trained or how it is run.
//!
//! Data flow: `mars train` (crate `mars_policy`) fits a network and writes a checkpoint directory — the weights
//! in `model.safetensors`, and `policy.json`: a [`checkpoint::CheckpointMeta`] holding the [`config`] (policy
//! kind, network sizes, training settings), the [`normalize`] statistics and the training log. The real-time
//! engine (crate `mars_engine`) and the trainer's own evaluation read it back through this crate, size their
//! networks from [`config::ModelConfig`] (the image encoder's shape from [`encoder`]) and pick their Euler
//! steps with [`steps::steps_for`]; a camera frame becomes observation values by [`observation`].
//!
//! Nothing here depends on candle, a plotting, dataset or command-line crate: the engine, and so `marsd`,
//! links only serde and this.

pub mod checkpoint;
pub mod config;
pub mod encoder;
pub mod normalize;
pub mod observation;
pub mod steps;

pub use checkpoint::{CheckpointError, CheckpointMeta, EpochLog};
pub use config::{ConfigError, EncoderConfig, ModelConfig, PolicyConfig, PolicyKind, TrainConfig};
pub use normalize::{Normalizer, Stats};
