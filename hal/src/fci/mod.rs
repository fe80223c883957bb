//! The Franka Control Interface (FCI) backend, through franka-rs (lib `franka`, a pure-Rust libfranka).
//!
//! Data flow: [`connect`] reaches the robot in bounded time (never hanging, never leaving one of our threads on
//! SCHED_FIFO 99 behind our back); [`drive`] runs the HAL's tick inside the robot's 1 kHz callback (a state in,
//! the filtered setpoint out, in the same cycle), holds on a reflex and recovers only when asked; [`state`] turns
//! a `franka::RobotState` into our measurement; [`hand`] drives the Franka Hand on threads of its own.
//! `mars-hal fci-status` ([`status`]) reads one state and commands nothing; `mars-hal recover` ([`recover`]) clears
//! a reflex when no HAL is running. (The simulator that speaks the same protocol, franka-sim, is started by the
//! HIL rig: `mars_hil::franka_sim`.)

pub mod connect;
pub mod drive;
pub mod error;
pub mod hand;
pub mod history;
mod late_reads;
pub mod params;
pub mod recent_cycles;
pub mod recover;
pub mod report;
pub mod setpoint_sync;
pub mod state;
pub mod status;

#[cfg(test)]
mod against_sim;
#[cfg(test)]
mod sim_checker;

pub use connect::{Fci, connect};
pub use error::FciError;
pub use params::{FciParams, JOINTS, LateCommands, Realtime};
pub use report::RobotLoopReport;
