//! The robot state frame the HAL publishes once per control tick.

use iceoryx2::prelude::ZeroCopySend;

/// Fixed joint capacity of every frame: no heap, one layout for every supported arm (FR3: 7, R1 Lite arm: 6).
pub const MAX_JOINTS: usize = 8;

/// Bits of [`RobotState::status`].
pub mod status {
    /// A controller session is active and its commands are being followed.
    pub const ACTIVE: u32 = 1 << 0;
    /// The HAL is braking to rest or holding; see [`super::RobotState::hold_reason`].
    pub const HOLDING: u32 = 1 << 1;
    /// The joints are at rest (every |velocity| of the applied setpoint below 1e-3 rad/s).
    pub const AT_REST: u32 = 1 << 2;
    /// The HAL's safety filter had to use a last resort this tick (a position guard stopped a joint at its
    /// limit, or no setpoint satisfied every limit at once): see `RobotState::position_guard_hits` and
    /// `RobotState::infeasible_steps`. A controller or a user must see this; it should never happen.
    pub const LAST_RESORT: u32 = 1 << 3;
    /// The HAL is braking or holding because its backend (the robot's driver) reported errors; see
    /// `RobotState::backend_errors`.
    pub const BACKEND_ERROR: u32 = 1 << 4;
}

/// Bits of [`RobotState::fault`]: a frame with any of them set carries measurements a controller must not
/// trust.
pub mod fault {
    /// The position sensor stopped updating (sim fault injection).
    pub const FROZEN_SENSOR: u32 = 1 << 0;
    /// A joint sensor reports NaN (sim fault injection).
    pub const NAN_SENSOR: u32 = 1 << 1;
    /// The HAL found a non-finite measured position or velocity, whatever the backend said.
    pub const NON_FINITE_MEASUREMENT: u32 = 1 << 2;
    /// The backend could not read the robot this tick: the measurements are the last ones read.
    pub const NO_MEASUREMENT: u32 = 1 << 3;
    /// The robot stopped itself (a Franka reflex: any `ControlException`); its own reasons are in
    /// [`super::RobotState::robot_reflex_errors`]. The HAL holds until a person recovers the robot.
    pub const ROBOT_REFLEX: u32 = 1 << 4;
    /// The connection to the robot is gone (no state within the robot protocol's timeout): the measurements are
    /// the last ones read, and the HAL is about to exit.
    pub const ROBOT_CONNECTION_LOST: u32 = 1 << 5;
}

/// What a robot says about itself, in [`RobotState::robot_mode`]: libfranka's `RobotMode` plus one, so that 0
/// means the backend reports no mode (the sim backend).
pub mod robot_mode {
    pub const NOT_REPORTED: u32 = 0;
    pub const OTHER: u32 = 1;
    pub const IDLE: u32 = 2;
    pub const MOVE: u32 = 3;
    pub const GUIDING: u32 = 4;
    pub const REFLEX: u32 = 5;
    pub const USER_STOPPED: u32 = 6;
    pub const AUTOMATIC_ERROR_RECOVERY: u32 = 7;

    /// The mode's name, as libfranka spells it without the `k`.
    pub fn name(mode: u32) -> &'static str {
        match mode {
            NOT_REPORTED => "not reported",
            OTHER => "Other",
            IDLE => "Idle",
            MOVE => "Move",
            GUIDING => "Guiding",
            REFLEX => "Reflex",
            USER_STOPPED => "UserStopped",
            AUTOMATIC_ERROR_RECOVERY => "AutomaticErrorRecovery",
            _ => "unknown",
        }
    }
}

/// Why the HAL is holding, in [`RobotState::hold_reason`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum HoldReason {
    /// Not holding.
    None = 0,
    /// No controller session has started yet.
    NoSession = 1,
    /// No valid command arrived within the profile's command timeout.
    CommandTimeout = 2,
    /// The controller ended its session (a [`crate::CommandMode::Hold`] command).
    ControllerRequested = 3,
    /// The controller's process died or closed its heartbeat (seen through [`crate::liveness`]).
    ControllerLost = 4,
    /// The HAL's backend (the robot's driver) or its own ports failed repeatedly: it braked to rest and holds
    /// until it recovers and a controller starts a new session.
    HalError = 5,
    /// The robot stopped itself (a reflex; see `fault::ROBOT_REFLEX` and `RobotState::robot_reflex_errors`): the
    /// HAL holds, and resumes only after a person recovered the robot (`mars-hal` on SIGUSR1, or
    /// `mars-hal recover`) and a controller starts a new session.
    RobotFault = 6,
    /// The HAL was asked to exit (SIGTERM): it brakes to rest before it releases the robot.
    HalStopping = 7,
}

impl HoldReason {
    /// Decode the wire value; unknown values are `None` so a newer peer cannot crash an older reader.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::None),
            1 => Some(Self::NoSession),
            2 => Some(Self::CommandTimeout),
            3 => Some(Self::ControllerRequested),
            4 => Some(Self::ControllerLost),
            5 => Some(Self::HalError),
            6 => Some(Self::RobotFault),
            7 => Some(Self::HalStopping),
            _ => None,
        }
    }
}

/// One state frame. Joint arrays are valid up to `num_joints`; the rest is zero.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("mars::RobotState")]
#[repr(C)]
pub struct RobotState {
    /// Increments by one per published frame; a gap means frames were dropped.
    pub seq: u64,
    /// Monotonic time of the measurement on the HAL's clock (ns since the HAL started).
    pub timestamp_ns: u64,
    /// The controller session the HAL is following (0: none yet).
    pub session: u64,
    /// `seq` of the last command the HAL accepted (0: none).
    pub last_command_seq: u64,
    /// Measured joint positions (rad).
    pub position: [f64; MAX_JOINTS],
    /// Measured joint velocities (rad/s).
    pub velocity: [f64; MAX_JOINTS],
    /// Measured joint efforts (N·m). The sim backend reports zero.
    pub effort: [f64; MAX_JOINTS],
    /// The setpoint the HAL applied this tick, after its safety filter (rad).
    pub applied_position: [f64; MAX_JOINTS],
    /// Velocity and acceleration of the applied setpoint (libfranka's dq_d, ddq_d): a controller that sees the
    /// HAL did not apply its last command (a late packet) continues its trajectory from this state, so its
    /// next command is again within every limit relative to what the joints actually follow.
    pub applied_velocity: [f64; MAX_JOINTS],
    pub applied_acceleration: [f64; MAX_JOINTS],
    /// Gripper opening (m).
    pub gripper: f64,
    /// The width the gripper is moving to (m): the last admitted target, reached at the profile's gripper speed.
    pub gripper_target: f64,
    /// Commands refused since start (NaN, wrong joint count, wrong schema, out of limits under `reject`).
    pub rejected_commands: u64,
    /// Commands clamped into the limits since start (under `clamp`).
    pub clamped_commands: u64,
    /// Commands that reached the HAL after the tick they answered for had passed (their `state_seq` was not
    /// the newest frame's): counted apart from out-of-limit commands, since the cause is timing, not content.
    pub late_commands: u64,
    /// Position commands that answered a frame an earlier followed command had already answered (the controller
    /// ticked twice between two frames, so the second is a tick ahead): the first is the tick's command, these
    /// are not followed. Counted apart from out-of-limit and late commands.
    pub duplicate_commands: u64,
    /// Ticks in which the safety filter's position guard stopped a joint at its limit, breaking the
    /// acceleration/jerk limits on purpose (a last resort; expected to stay 0).
    pub position_guard_hits: u64,
    /// Ticks in which no setpoint satisfied every limit at once and the filter took the middle of the
    /// (empty) feasible interval (a last resort; expected to stay 0).
    pub infeasible_steps: u64,
    /// Errors of the backend or of the HAL's own ports since start (each one brakes the arm to rest).
    pub backend_errors: u64,
    /// [`status`] bits.
    pub status: u32,
    /// Fault bits of the backend (0: none).
    pub fault: u32,
    /// A [`HoldReason`] as `u32`.
    pub hold_reason: u32,
    pub num_joints: u32,
    /// The robot's own error flags now, bit i = flag i in libfranka's order (`franka::Errors`, 41 flags); 0 for
    /// a backend that reports none.
    pub robot_errors: u64,
    /// The flags that aborted the robot's last motion (a reflex's reasons), same bits.
    pub robot_reflex_errors: u64,
    /// The fraction of the robot's last 100 cycles whose command reached it in time (libfranka's
    /// `control_command_success_rate`; 0 while no motion runs or for a backend that reports none).
    pub robot_success_rate: f64,
    /// A [`robot_mode`] value.
    pub robot_mode: u32,
    /// The robot's control cycles since the previous frame, for a backend the robot paces (fci): 1 normally, more
    /// after states the HAL never saw, across which the applied setpoint moved as the robot did (difference it
    /// over this many cycles, not one). 0 for a backend paced by the HAL's own timer: one setpoint step per frame.
    pub robot_cycles: u32,
    /// The HAL's ticks so far in which its loop thread gave the CPU up (something in the tick blocked: a bug, the
    /// tick must never block), from the kernel's accounting of that thread (`mars_rt::overlong`). A frame counts
    /// the ticks before its own, as do the two below.
    pub ticks_blocked: u64,
    /// The other ticks whose answer took longer than the HAL's period (so came late; judged up to the next tick
    /// when the thread never waited in between: a robot's driver sends the answer after the tick) because the
    /// tick's own CPU time reached the period: its work did not fit.
    pub overlong_ticks_computing: u64,
    /// ... although the tick's own CPU time stayed under the period: the thread was held off the CPU (preempted,
    /// or its virtual CPU stolen by the hypervisor) or busy in the driver and kernel after the tick.
    pub overlong_ticks_held_up: u64,
}

impl Default for RobotState {
    fn default() -> Self {
        Self {
            seq: 0,
            timestamp_ns: 0,
            session: 0,
            last_command_seq: 0,
            position: [0.0; MAX_JOINTS],
            velocity: [0.0; MAX_JOINTS],
            effort: [0.0; MAX_JOINTS],
            applied_position: [0.0; MAX_JOINTS],
            applied_velocity: [0.0; MAX_JOINTS],
            applied_acceleration: [0.0; MAX_JOINTS],
            gripper: 0.0,
            gripper_target: 0.0,
            rejected_commands: 0,
            clamped_commands: 0,
            late_commands: 0,
            duplicate_commands: 0,
            position_guard_hits: 0,
            infeasible_steps: 0,
            backend_errors: 0,
            status: 0,
            fault: 0,
            hold_reason: HoldReason::NoSession as u32,
            num_joints: 0,
            robot_errors: 0,
            robot_reflex_errors: 0,
            robot_success_rate: 0.0,
            robot_mode: robot_mode::NOT_REPORTED,
            robot_cycles: 0,
            ticks_blocked: 0,
            overlong_ticks_computing: 0,
            overlong_ticks_held_up: 0,
        }
    }
}

impl RobotState {
    /// The valid joint positions.
    pub fn positions(&self) -> &[f64] {
        &self.position[..(self.num_joints as usize).min(MAX_JOINTS)]
    }

    pub fn is(&self, bit: u32) -> bool {
        self.status & bit != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hold_reason_round_trips_and_unknown_is_none() {
        for r in [
            HoldReason::None,
            HoldReason::NoSession,
            HoldReason::CommandTimeout,
            HoldReason::ControllerRequested,
            HoldReason::ControllerLost,
            HoldReason::HalError,
            HoldReason::RobotFault,
            HoldReason::HalStopping,
        ] {
            assert_eq!(HoldReason::from_u32(r as u32), Some(r));
        }
        assert_eq!(HoldReason::from_u32(77), None);
    }

    #[test]
    fn positions_are_cut_at_num_joints_and_never_past_capacity() {
        let mut s = RobotState { num_joints: 7, ..Default::default() };
        assert_eq!(s.positions().len(), 7);
        s.num_joints = 100;
        assert_eq!(s.positions().len(), MAX_JOINTS);
    }
}
