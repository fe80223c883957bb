//! The Franka Control Interface (FCI) side of the HAL, through franka-rs (lib `franka`, a pure-Rust libfranka).
//!
//! This is the first slice of issue 12 (an `fci` backend): connect to a robot without ever hanging or putting one
//! of our threads on SCHED_FIFO 99 behind our back ([`connect`]), turn a `franka::RobotState` into our
//! [`crate::backend::Measurement`] plus the robot's own view of itself ([`state`]), and the report of
//! `mars-hal fci-status` ([`status`]), which reads one state and commands nothing. The backend that drives the
//! arm at 1 kHz is still to come.

pub mod connect;
pub mod error;
pub mod state;
pub mod status;

pub use connect::{Fci, connect};
pub use error::FciError;
