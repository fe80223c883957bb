//! Helpers shared by the HAL's integration tests (a directory, so cargo does not build it as a test of its own).

pub mod franka_sim;
