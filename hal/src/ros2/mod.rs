//! A robot driven over ROS 2 topics, `backend = "ros2"`: the Galaxea R1 Lite's right arm and gripper as its public
//! drivers use them. It publishes `/hdas/feedback_arm_right` and `/hdas/feedback_gripper_right` and takes
//! `/motion_target/target_joint_state_arm_right` and `/motion_target/target_position_gripper_right`, all
//! `sensor_msgs/JointState`, and its cameras send `sensor_msgs/CompressedImage` (JPEG) (`[ros2]` in the profile
//! names them; [`params`]).
//!
//! **The client**: ros2-client 0.12 (Atostek) over RustDDS 0.15, pure Rust: no ROS installation, no C library, and
//! it builds offline from the crates.io cache like the rest of the workspace. It maps ROS names to DDS ones
//! (`rt/…`) and registers the node in ROS 2's graph (`ros_discovery_info`) the way rmw does, so `ros2 topic info`
//! on the robot sees the HAL; only `features = ["dds", "jazzy"]`: no async executor runs (nothing needs the node's
//! spinner: no parameters, no /rosout), and the I/O thread polls ([`io`]). `JointState` and `CompressedImage` are
//! written here ([`message`]): ros2-client ships no `sensor_msgs`.
//!
//! **Discovery**: RTPS's standard SPDP (multicast `239.255.0.1`, then unicast), in the DDS domain `[ros2]
//! domain_id` (ROS_DOMAIN_ID; `mars-hal --ros-domain-id`). With `localhost_only` (`--ros-localhost-only`) RustDDS
//! advertises only 127.0.0.1 and finds peers on this host without multicast (Linux's `lo` has none) by announcing
//! itself to 127.0.0.1's well-known SPDP ports of participant indices 0–11 (RustDDS's `same_host_loopback`); a
//! peer must listen there, i.e. use a fixed participant index (Cyclone DDS: `ParticipantIndex` auto, and
//! `127.0.0.1` as its peer: what the tests' stand-in does, `tests/peers/r1_lite_standin.py`).
//!
//! Data flow: [`io`] owns DDS on a thread of its own (newest feedback → triple buffer → the loop; targets → ring
//! → published); [`backend`] turns them into the HAL's [`crate::backend::Backend`] and decides what is published
//! when the robot or the controller goes quiet; [`drive`] runs the HAL loop on its own timer around it; [`camera`]
//! turns the robot's JPEG camera topics into our image frames (`mars/<robot>/camera/<id>`) on threads of their own,
//! never on the loop's.

pub mod backend;
pub mod camera;
pub mod domain;
pub mod drive;
pub mod io;
pub mod message;
pub mod params;
pub mod topics;

pub use backend::Ros2Backend;
pub use params::{Reliability, Ros2Params};
