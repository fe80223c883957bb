//! The joint command frame the controller sends in answer to a state frame.

use iceoryx2::prelude::ZeroCopySend;

use crate::state::MAX_JOINTS;

/// What the controller asks of the HAL.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum CommandMode {
    /// Follow `position` (with `velocity`/`acceleration` as the controller's intent, checked against limits).
    Position = 1,
    /// End the session: brake to rest and hold until a command with a new session id arrives.
    Hold = 2,
}

impl CommandMode {
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Position),
            2 => Some(Self::Hold),
            _ => None,
        }
    }
}

/// One command frame. Joint arrays are valid up to `num_joints`.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("mars::JointCommand")]
#[repr(C)]
pub struct JointCommand {
    /// Increments per command sent by the controller.
    pub seq: u64,
    /// Monotonic time when the command was written, on the controller's clock (ns).
    pub timestamp_ns: u64,
    /// The `seq` of the state frame this command answers (for round-trip measurement and staleness checks).
    pub state_seq: u64,
    /// Controller session id, non-zero. After the HAL stops on a timeout it follows commands again only once
    /// the session id changes: an explicit restart, never a silent resume of a stream that had stalled.
    pub session: u64,
    pub position: [f64; MAX_JOINTS],
    pub velocity: [f64; MAX_JOINTS],
    pub acceleration: [f64; MAX_JOINTS],
    /// Gripper opening target (m): a width to move to, not a stream. The HAL moves the gripper there at
    /// `gripper_speed` (capped by the profile) and passes a new target to the backend only when it changes, as
    /// a Franka Hand takes one move action at a time.
    pub gripper: f64,
    /// Speed of the move to `gripper` (m/s); 0 asks for the profile's maximum.
    pub gripper_speed: f64,
    /// A [`CommandMode`] as `u32`.
    pub mode: u32,
    pub num_joints: u32,
}

impl Default for JointCommand {
    fn default() -> Self {
        Self {
            seq: 0,
            timestamp_ns: 0,
            state_seq: 0,
            session: 0,
            position: [0.0; MAX_JOINTS],
            velocity: [0.0; MAX_JOINTS],
            acceleration: [0.0; MAX_JOINTS],
            gripper: 0.0,
            gripper_speed: 0.0,
            mode: CommandMode::Position as u32,
            num_joints: 0,
        }
    }
}

impl JointCommand {
    /// A position command for the given joints; velocity and acceleration intent zero.
    pub fn position(session: u64, seq: u64, state_seq: u64, q: &[f64]) -> Self {
        let mut c = Self { session, seq, state_seq, num_joints: q.len().min(MAX_JOINTS) as u32, ..Self::default() };
        c.position[..q.len().min(MAX_JOINTS)].copy_from_slice(&q[..q.len().min(MAX_JOINTS)]);
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mode_round_trips_and_unknown_is_refused() {
        assert_eq!(CommandMode::from_u32(CommandMode::Position as u32), Some(CommandMode::Position));
        assert_eq!(CommandMode::from_u32(CommandMode::Hold as u32), Some(CommandMode::Hold));
        assert_eq!(CommandMode::from_u32(0), None);
    }

    #[test]
    fn position_constructor_fills_only_the_given_joints() {
        let c = JointCommand::position(3, 4, 5, &[0.1, 0.2]);
        assert_eq!((c.session, c.seq, c.state_seq, c.num_joints), (3, 4, 5, 2));
        assert_eq!(&c.position[..3], &[0.1, 0.2, 0.0]);
    }
}
