//! `marsd`, the controller daemon, as a library (so tests and benchmarks drive the code the binary runs).
//!
//! Data flow: a state frame enters in [`servo`] (from the HAL over iceoryx2), is checked, feeds the
//! [`policy_loop`] through a lock-free snapshot; the policy loop's time-stamped chunk comes back through
//! [`handoff`]; the servo tick smooths it with [`smoothing`] (ruckig) and the command leaves in [`servo`].

pub mod alloc_count;
pub mod bench;
pub mod chunk;
pub mod cli;
pub mod config;
pub mod daemon;
pub mod frame;
pub mod latency;
pub mod limits;
pub mod plots;
pub mod policy_loop;
pub mod report;
pub mod rt;
pub mod servo;
pub mod servo_loop;
pub mod shared;
pub mod smoothing;
pub mod task;
pub mod watchdog;
