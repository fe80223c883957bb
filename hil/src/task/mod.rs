//! The pick task on the sim plant, outside marsd: [`expert`] (balanced demos), [`eval`] (a checkpoint rolled out
//! in-process) and [`sim_arm`] (the plant behind the servo both use); [`cli`] is what `mars-hil demos` / `eval-sim`
//! run, [`push_t_cli`] what `mars-hil push-t-train` / `push-t-eval` run. The task as marsd runs it is
//! `mars_runtime::task`, re-exported here so these files name it as their own.

pub use mars_runtime::task::*;

pub mod boundary;
pub mod cli;
pub mod delay;
pub mod delay_sweep;
pub mod eval;
pub mod expert;
pub mod push_t_cli;
pub mod sim_arm;
