//! LeRobot v3.0 datasets, the format robot-learning engineers' demonstrations come in (LeRobot's recorders
//! for SO-100, Franka, ALOHA, … and the Hugging Face hub):
//!
//! - [`info`]: `meta/info.json` — version, rate, features, path templates;
//! - [`episodes`]: `meta/episodes/*.parquet` — per episode its length and where its rows and frames are;
//! - [`table`]: a parquet file's columns through arrow; [`video`]: a video file's frames through FFmpeg;
//! - [`dataset`]: the two together — open a dataset, read its episodes with the features a policy takes;
//! - [`cache`]: decoded frames kept on disk, so that reading a dataset again does not decode its videos again;
//! - [`demos`]: episodes as the training demos every task hands to `mars train`;
//! - [`writer`]: our runs written as a dataset (with [`video_out`] for the cameras and [`stats`]), so LeRobot's
//!   tools and `mars train --dataset` read them.

pub mod cache;
pub mod contain;
pub mod dataset;
pub mod demos;
pub mod episodes;
mod error;
pub mod file_limits;
pub mod info;
pub mod page_sizes;
pub mod stats;
pub mod table;
pub mod video;
pub mod video_out;
pub mod writer;

pub use dataset::{EpisodeFrames, Keys, LeRobotDataset, ReadOptions, ReadReport};
pub use error::LeRobotError;
