//! MARS — Modality-Adaptive Robot Sampling — in candle.
//!
//! Data flow: a task (crate `mars_tasks`: nav2d, Push-T) produces `mars_tasks::demo::Demo`s → [`dataset`] turns
//! them into normalised training samples with their nearest neighbours → [`train`] fits a [`model::MarsModel`]
//! with the three [`losses`] → [`checkpoint`] writes safetensors + config → a task's evaluation calls the model
//! through `mars_tasks::rollout::ChunkPolicy` or, many rollouts at once, `BatchPolicy` ([`inference::MarsPolicy`];
//! [`evaluation`] scores a checkpoint with intervals). The `mars` command ([`cli`]) runs
//! the nav2d benchmark, its layout family, curves, ablations and diagnosis on top.

pub mod ablation;
pub mod augment;
pub mod bench_train;
pub mod benchmark;
pub mod checkpoint;
pub mod cli;
pub use mars_policy_format::config;
pub mod curve;
pub mod dataset;
pub mod dataset_features;
pub mod demo_file;
pub mod diagnose;
pub mod diagnose_family;
pub mod encoder;
pub mod evaluation;
pub mod family;
pub mod family_diff;
pub mod from_dataset;
pub mod grad;
pub mod inference;
pub mod jobs;
pub mod kind_arg;
pub mod knn;
pub mod losses;
pub mod model;
pub mod nn;
pub mod obs_encoder;
pub use mars_policy_format::normalize;
pub mod plots;
pub mod scheduler;
pub mod stats;
pub mod train;
pub mod vision;
