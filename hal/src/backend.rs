//! The interface between the HAL loop and a robot.
//!
//! The HAL loop owns timing, the safety filter and the wire; a backend only moves joints to the setpoints it
//! is given and reports what it measured. Every setpoint handed to [`Backend::apply`] has already passed the
//! safety filter, so a backend need not (but may) check limits again.
//!
//! What a real backend would have to do:
//! - **FR3 over FCI (libfranka)**: libfranka owns the 1 kHz loop (`Robot::control` calls back once per packet),
//!   so the backend would run the HAL tick inside that callback: `read` from `franka::RobotState` (`q`, `dq`,
//!   `tau_J`, gripper width from `franka::Gripper` on its own thread), `apply` by returning
//!   `franka::JointPositions`; a `franka::ControlException` (reflex, communication lost) maps to a backend
//!   fault, after which the HAL holds and the robot needs `automaticErrorRecovery` before a new session.
//! - **R1 Lite over ROS 2**: subscribe to `/hdas/feedback_arm_right` (`sensor_msgs/JointState`) for `read`,
//!   publish the setpoint on `/motion_target/target_joint_state_arm_right` for `apply`, with the HAL loop timed
//!   by the profile rate; a feedback topic older than the command timeout is a fault.

/// What a backend measured in one tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Measurement {
    pub position: [f64; mars_ipc::MAX_JOINTS],
    pub velocity: [f64; mars_ipc::MAX_JOINTS],
    pub effort: [f64; mars_ipc::MAX_JOINTS],
    pub gripper: f64,
    /// Backend fault bits (0: none).
    pub fault: u32,
}

#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error("backend fault: {0}")]
    Fault(String),
}

pub trait Backend {
    /// Command the joints to `position` (rad) and the gripper to `gripper` (m) for this tick.
    fn apply(&mut self, position: &[f64], gripper: f64) -> Result<(), BackendError>;
    /// Advance one control period (a real robot does this by itself) and measure.
    fn read(&mut self) -> Result<Measurement, BackendError>;
    /// Loop faults to inject into the tick just measured (only the sim backend injects any).
    fn loop_faults(&mut self) -> crate::fault::LoopFaults {
        crate::fault::LoopFaults::default()
    }
}
