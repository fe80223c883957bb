//! A `franka::RobotState` as the HAL sees it: the joints as our [`Measurement`], and the robot's own view of
//! itself (its mode, how many of our commands it took, its error flags by name) for reports.
//!
//! Two functions on purpose: [`measurement`] copies numbers and never allocates, so the 1 kHz loop can call it on
//! every state; [`RobotStatus::of`] collects error names into vectors, so it belongs off that loop (once per
//! status report, or when a fault is reported).

use franka::{RobotMode, RobotState};

use super::JOINTS;
use crate::backend::Measurement;

/// The joints of `s`: measured positions `q` (rad), velocities `dq` (rad/s) and link-side torques `tau_J` (N·m).
/// The gripper is not part of a robot state (the Franka Hand has a connection and a state of its own) and stays
/// 0 until the backend reads it; `fault` stays 0: the robot's own errors are in [`RobotStatus`].
pub fn measurement(s: &RobotState) -> Measurement {
    let mut m = Measurement::default();
    m.position[..JOINTS].copy_from_slice(&s.q);
    m.velocity[..JOINTS].copy_from_slice(&s.dq);
    m.effort[..JOINTS].copy_from_slice(&s.tau_J);
    m
}

/// What the robot says about itself in one state.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotStatus {
    /// Idle, Move, Reflex, User stopped, …: Reflex means a reflex stopped the last motion and the robot needs an
    /// error recovery before the next one.
    pub mode: RobotMode,
    /// The fraction of the last 100 cycles whose command reached the robot in time, in [0, 1] (0 while no motion
    /// or controller runs).
    pub control_command_success_rate: f64,
    /// The robot's error flags set now, by libfranka's names (e.g. `joint_position_limits_violation`).
    pub current_errors: Vec<&'static str>,
    /// The flags that aborted the last motion (the reflex's reason), by libfranka's names.
    pub last_motion_errors: Vec<&'static str>,
}

impl RobotStatus {
    pub fn of(s: &RobotState) -> Self {
        RobotStatus {
            mode: s.robot_mode,
            control_command_success_rate: s.control_command_success_rate,
            current_errors: s.current_errors.names(),
            last_motion_errors: s.last_motion_errors.names(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use franka::Errors;

    fn with_errors(names: &[&str]) -> Errors {
        let mut e = Errors::default();
        for name in names {
            e.0[Errors::index_of(name).unwrap_or_else(|| panic!("{name} is not a libfranka error name"))] = true;
        }
        e
    }

    fn state() -> RobotState {
        RobotState {
            q: [0.1, -0.2, 0.3, -1.5, 0.05, 1.6, 0.7],
            dq: [1e-3, -2e-3, 3e-3, -4e-3, 5e-3, -6e-3, 7e-3],
            tau_J: [1.0, -2.0, 3.0, -4.0, 5.0, -6.0, 7.0],
            // Fields the measurement must not take its joints from.
            q_d: [9.0; 7],
            theta: [8.0; 7],
            tau_J_d: [6.0; 7],
            ..RobotState::default()
        }
    }

    #[test]
    fn the_measurement_takes_q_dq_and_tau_j_and_nothing_else() {
        let s = state();
        let m = measurement(&s);
        assert_eq!(&m.position[..7], &s.q);
        assert_eq!(&m.velocity[..7], &s.dq);
        assert_eq!(&m.effort[..7], &s.tau_J);
        // The eighth slot (R1 Lite has no such joint here either) and the gripper stay zero; no fault bits.
        assert_eq!((m.position[7], m.velocity[7], m.effort[7]), (0.0, 0.0, 0.0));
        assert_eq!((m.gripper, m.fault), (0.0, 0));
    }

    #[test]
    fn the_status_carries_the_robots_mode_rate_and_error_names_in_wire_order() {
        let s = RobotState {
            robot_mode: RobotMode::Reflex,
            control_command_success_rate: 0.93,
            current_errors: with_errors(&["communication_constraints_violation", "joint_reflex"]),
            last_motion_errors: with_errors(&["joint_motion_generator_velocity_discontinuity"]),
            ..state()
        };
        let st = RobotStatus::of(&s);
        assert_eq!(st.mode, RobotMode::Reflex);
        assert_eq!(st.control_command_success_rate, 0.93);
        // libfranka's order (joint_reflex is flag 6, communication_constraints_violation flag 25), not ours.
        assert_eq!(st.current_errors, ["joint_reflex", "communication_constraints_violation"]);
        assert_eq!(st.last_motion_errors, ["joint_motion_generator_velocity_discontinuity"]);
    }

    #[test]
    fn a_robot_without_errors_reports_empty_lists() {
        let st = RobotStatus::of(&RobotState { robot_mode: RobotMode::Idle, ..state() });
        assert_eq!(st.mode, RobotMode::Idle);
        assert!(st.current_errors.is_empty() && st.last_motion_errors.is_empty());
    }
}
