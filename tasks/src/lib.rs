//! The simulated tasks: for each, its world, its scripted expert, its success and mode, and what a camera sees.
//! One home for the policy's training and evaluation and for the HIL mock's camera.
//!
//! - [`push_t`]: the paper's FR3 Push-T — a T block pushed across a table by the end effector, seen from above;
//!   the expert goes around the block by the upper or the lower route.

pub mod push_t;
