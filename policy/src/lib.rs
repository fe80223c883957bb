//! MARS — Modality-Adaptive Robot Sampling — in candle.
//!
//! Data flow: a task produces [`demo::Demo`]s → [`dataset`] turns them into normalised training samples with
//! their nearest neighbours → [`train`] fits a [`model::MarsModel`] with the three [`losses`] → [`checkpoint`]
//! writes safetensors + config → a task's evaluation calls the model through [`rollout::ChunkPolicy`].

pub mod ablation;
pub mod augment;
pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod curve;
pub mod dataset;
pub mod demo;
pub mod diagnose;
pub mod encoder;
pub mod family;
pub mod inference;
pub mod jobs;
pub mod knn;
pub mod losses;
pub mod model;
pub mod nav2d;
pub mod nn;
pub mod normalize;
pub mod plots;
pub mod report;
pub mod rollout;
pub mod scheduler;
pub mod train;
pub mod vision;
