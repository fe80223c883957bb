//! The FR3 hardware-in-the-loop task: Pick Cup in joint space (grasp by the rim or by the handle).
//!
//! [`pick_cup`] defines it (TOML, start poses, observations, the [`pick_cup::EpisodeMonitor`]); [`expert`]
//! records balanced demos on the sim plant; [`eval`] rolls a checkpoint out in-process; [`sim_arm`] is the
//! plant behind the servo both use; [`cli`] is what `mars-hil demos` / `eval-sim` run.

pub mod cli;
pub mod eval;
pub mod expert;
pub mod pick_cup;
pub mod sim_arm;

pub use pick_cup::{DoneReason, EpisodeMonitor, PickCup, Progress, TaskError};
