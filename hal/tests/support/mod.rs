//! Helpers shared by the HAL's integration tests (a directory, so cargo does not build it as a test of its own).
//! Each test binary uses part of them, so the rest would warn as dead code there.
#![allow(dead_code)]

pub mod franka_sim;
pub mod reflex;
pub mod standin;
pub mod states;
