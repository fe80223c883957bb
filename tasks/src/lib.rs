//! The simulated tasks: for each, its world, its scripted expert, its success and mode, and what a camera sees.
//! One home for the policy's training and evaluation (crate `mars_policy` depends on this one) and for the HIL
//! scene (crate `mars_runtime`).
//!
//! - [`demo`]: what any task hands to training; [`rollout`]: what a task's evaluation needs of a policy.
//! - [`nav2d`]: the benchmark task — a point agent through one of several passages between two gates.
//! - [`push_t`]: the paper's FR3 Push-T — a T block pushed across a table by the end effector, seen from above;
//!   the expert goes around the block by the upper or the lower route.
//!
//! (FR3 Pick Cup's world is the HAL's own mock plant, so it lives beside it, in `mars_runtime::task`.)

pub mod demo;
pub mod nav2d;
pub mod push_t;
pub mod rollout;
