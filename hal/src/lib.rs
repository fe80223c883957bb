//! The robot side of the MARS runtime: the safety filter, the backend interface with its sim implementation, the
//! drivers of real robots, and the `mars-hal` process loop. The robot's profile (limits, rates, each driver's
//! table) is the crate `mars-profile`, which marsd reads too without linking any of this.
//!
//! Data flow of one tick: the backend is read ([`backend`], [`sim`]) → commands arrive over iceoryx2 →
//! [`control`] judges them ([`safety`], [`session`], [`gripper`]; [`takeover`] decides whether it may start at
//! all) → the setpoint goes to the backend → the state frame leaves ([`runner`] does the I/O). [`fci`] drives a
//! Franka robot over its Control Interface (the HAL's tick inside the robot's 1 kHz callback, the Franka Hand,
//! reflex recovery; `mars-hal fci-status` reads a state and commands nothing); [`ros2`] a robot over ROS 2 topics
//! (the Galaxea R1 Lite).

pub mod backend;
pub mod cli;
pub mod control;
pub mod events;
pub mod fault;
pub mod fci;
pub mod gripper;
pub mod report_json;
pub mod ros2;
pub mod runner;
pub mod safety;
pub mod session;
pub mod sim;
pub mod takeover;
