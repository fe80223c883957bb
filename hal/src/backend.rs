//! The interface between the HAL loop and a robot.
//!
//! The HAL loop owns timing, the safety filter and the wire; a backend only reports what it measured and moves
//! the joints to the setpoints it is given. Each tick the loop first [`read`](Backend::read)s, then
//! [`apply`](Backend::apply)s: the HAL never commands an arm it has not read (its first setpoint is the measured
//! position). Every setpoint handed to `apply` has already passed the safety filter, so a backend need not (but
//! may) check limits again. The gripper gets a [`move_gripper`](Backend::move_gripper) only when its target
//! changes (see [`crate::gripper`]).
//!
//! Errors are `Copy` values, never allocated: the loop counts them, brakes and holds
//! ([`mars_ipc::HoldReason::HalError`]), and goes on; only a [`BackendError::Fatal`] ends the process, and only
//! once the setpoint is at rest.
//!
//! The backends:
//! - [`crate::sim::SimBackend`], the HIL mock plant, paced by the HAL's own timer ([`crate::runner::run`]).
//! - **FR3 over FCI** ([`crate::fci::drive`]): the robot owns the 1 kHz loop (franka-rs calls back once per state),
//!   so the HAL tick runs inside that callback with a backend whose `read` is the state just received and whose
//!   `apply` fills the command the callback returns; a `ControlException` (reflex) ends the motion, and the HAL
//!   holds until a recovery is asked for.
//! - **R1 Lite over ROS 2** ([`crate::ros2`]): `read` is the newest `/hdas/feedback_arm_right` (and gripper)
//!   `sensor_msgs/JointState`, `apply` publishes the setpoint on `/motion_target/target_joint_state_arm_right`,
//!   the HAL loop timed by the profile rate; feedback older than the timeout is a (transient) fault, and since
//!   the robot latches its last target the backend publishes an explicit stop rather than going quiet.

/// What a backend measured in one tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Measurement {
    pub position: [f64; mars_ipc::MAX_JOINTS],
    pub velocity: [f64; mars_ipc::MAX_JOINTS],
    pub effort: [f64; mars_ipc::MAX_JOINTS],
    pub gripper: f64,
    /// Backend fault bits (0: none).
    pub fault: u32,
    /// What the robot says about itself (all zero for a backend that reports nothing, like the sim).
    pub robot: RobotReport,
}

/// A robot's own report, passed into the state frame as it is (see `mars_ipc::RobotState::robot_errors`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RobotReport {
    /// A `mars_ipc::robot_mode` value.
    pub mode: u32,
    /// Error flags now and those that aborted the last motion, bit i = libfranka's flag i.
    pub errors: u64,
    pub reflex_errors: u64,
    /// The robot's control command success rate over its last 100 cycles.
    pub success_rate: f64,
    /// The robot's cycles since the previous state (see `RobotState::robot_cycles`); 0 when not reported.
    pub cycles: u32,
}

/// What went wrong in the backend (the text names it; `&'static` so reporting never allocates).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum BackendError {
    /// This tick failed; later ones may work (a lost packet, a busy bus).
    #[error("backend error: {0}")]
    Transient(&'static str),
    /// The robot cannot be driven any more (the connection is gone, or it needs a person to recover).
    #[error("backend failed for good: {0}")]
    Fatal(&'static str),
}

impl BackendError {
    pub fn is_fatal(&self) -> bool {
        matches!(self, BackendError::Fatal(_))
    }
}

pub trait Backend {
    /// Measure the robot at the start of a tick (the sim advances its plant one period first; a real robot moves
    /// by itself).
    fn read(&mut self) -> Result<Measurement, BackendError>;
    /// Command the joints to `position` (rad) for this tick.
    fn apply(&mut self, position: &[f64]) -> Result<(), BackendError>;
    /// Start moving the gripper to a new target (called only when the target changes).
    fn move_gripper(&mut self, to: crate::gripper::GripperMove) -> Result<(), BackendError>;
    /// Loop faults to inject into the tick just measured (only the sim backend injects any).
    fn loop_faults(&mut self) -> crate::fault::LoopFaults {
        crate::fault::LoopFaults::default()
    }
}
