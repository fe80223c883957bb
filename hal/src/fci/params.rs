//! The `[fci]` table of a profile: where the robot is and how the HAL talks to it. The profile keeps the table as
//! TOML; this driver reads it ([`FciParams::of`]) and checks it against the profile ([`FciParams::check`]).

use mars_profile::{Profile, ProfileError};
use serde::Deserialize;

/// Joints of an FR3 (and of an FER): the length of every joint array in `franka::RobotState`.
pub const JOINTS: usize = 7;

/// Whether the HAL insists on a real-time kernel before it drives a robot over FCI.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Realtime {
    /// Refuse to start unless the kernel is PREEMPT_RT (`/sys/kernel/realtime` reads 1), as libfranka does by
    /// default: on an ordinary kernel a real FR3 trips communication reflexes under load.
    #[default]
    Enforce,
    /// Run on any kernel (franka-sim, or a first look at a real arm).
    Ignore,
}

/// What the robot does with a command that missed its 1 ms cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum LateCommands {
    /// A real FR3: the command is dropped and the robot extrapolates its setpoint at constant acceleration for
    /// the cycle ("If a motion generator command packet is dropped, the robot takes the previous waypoints and
    /// performs a linear extrapolation", libfranka's docs). The HAL continues from the robot's setpoint (see
    /// `setpoint_sync`).
    #[default]
    Dropped,
    /// franka-sim 1.1.7: the late command is applied when it arrives and the extrapolation is rewound ("the robot
    /// would have dropped it, this sim applies it", its `state_stream.py`). The HAL continues its own stream:
    /// continuing from the extrapolation would break the simulator's history (it tripped its discontinuity
    /// reflexes).
    Applied,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FciParams {
    /// The robot's address: its Control's IP (e.g. 172.16.0.2), or host:port. `mars-hal --robot-ip` overrides it.
    pub robot_ip: Option<String>,
    pub realtime: Realtime,
    /// Connecting and each blocking request (the first state, an error recovery) give up after this long (s).
    pub connect_timeout_s: f64,
    /// libfranka's rate limiter on the commands, after our safety filter. Off by default: our filter already keeps
    /// libfranka's FR3 rules (its position-dependent velocity bounds, acceleration and jerk limits; see
    /// `velocity_limits` and `safety`), and libfranka's limiter differentiates from the *robot's* report of the
    /// last command, so any rounding there becomes jerk: against franka-sim, whose states are float32, it added
    /// ~500 rad/s³ of noise and tripped the acceleration-discontinuity reflex on a stream at 90 % of the limits.
    pub limit_rate: bool,
    /// libfranka's low-pass filter on the commanded positions (Hz); 1000 (the default) switches it off, for the
    /// same reason, and because our setpoints are already smooth (a filter would only add lag).
    pub cutoff_hz: f64,
    /// Drive the Franka Hand (the gripper's own connection, port 1338).
    pub gripper: bool,
    pub late_commands: LateCommands,
    /// A closing gripper target below this width (m) is a grasp (close with `grasp_force_n` until the fingers stop
    /// on an object); any other target is a move (position only, no force). Between the two the Franka Hand has no
    /// third way: a move onto an object fails, a grasp toward an opening with nothing in between closes fully.
    pub grasp_below_m: f64,
    /// The force (N) of a grasp.
    pub grasp_force_n: f64,
}

impl Default for FciParams {
    fn default() -> Self {
        Self {
            robot_ip: None,
            realtime: Realtime::Enforce,
            connect_timeout_s: 5.0,
            limit_rate: false,
            cutoff_hz: 1000.0,
            late_commands: LateCommands::Dropped,
            gripper: true,
            // Pick Cup opens to 0.07 and grasps toward 0.02: the mug's rim and handle are narrower than 5 cm.
            grasp_below_m: 0.05,
            grasp_force_n: 20.0,
        }
    }
}

impl FciParams {
    /// The profile's `[fci]` table (the defaults for what it leaves out), not yet checked: `mars-hal`'s options may
    /// override it first.
    pub fn of(profile: &Profile) -> Result<Self, ProfileError> {
        profile.driver_table("fci", &profile.fci)
    }

    /// Whether these settings can drive the robot of `profile`: a Franka arm (7 joints at 1 kHz), each setting in
    /// its range. Called before anything moves.
    pub fn check(&self, profile: &Profile) -> Result<(), ProfileError> {
        if profile.joints != JOINTS || profile.rate_hz != 1000.0 {
            return Err(profile.invalid(format!(
                "backend = \"fci\" drives a Franka arm: 7 joints at 1000 Hz, not {} at {} Hz",
                profile.joints, profile.rate_hz
            )));
        }
        self.validate().map_err(|msg| profile.invalid(format!("fci.{msg}")))
    }

    fn validate(&self) -> Result<(), String> {
        if !(self.connect_timeout_s.is_finite() && self.connect_timeout_s > 0.0 && self.connect_timeout_s <= 600.0) {
            return Err(format!("connect_timeout_s = {} must be in (0, 600] s", self.connect_timeout_s));
        }
        if !(self.cutoff_hz.is_finite() && self.cutoff_hz > 0.0 && self.cutoff_hz <= 1000.0) {
            return Err(format!("cutoff_hz = {} must be in (0, 1000] Hz (1000: off)", self.cutoff_hz));
        }
        if !(self.grasp_below_m.is_finite() && (0.0..=0.08).contains(&self.grasp_below_m)) {
            return Err(format!(
                "grasp_below_m = {} must be in [0, 0.08] m (the Franka Hand's range)",
                self.grasp_below_m
            ));
        }
        // The Franka Hand's continuous force range is 20–70 N (its datasheet); libfranka refuses more.
        if !(self.grasp_force_n.is_finite() && (0.0..=70.0).contains(&self.grasp_force_n)) {
            return Err(format!("grasp_force_n = {} must be in [0, 70] N", self.grasp_force_n));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fr3() -> Profile {
        Profile::load(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
    }

    /// The driver reads its own table from the profile, and refuses a bad one naming the field: a value out of
    /// range when checked, a value of the wrong type when read, and a profile that is no Franka arm.
    #[test]
    fn the_fci_table_is_read_and_checked_by_the_driver() {
        let p = fr3();
        let f = FciParams::of(&p).unwrap();
        f.check(&p).unwrap();
        let mut bad = p.clone();
        bad.fci.insert("cutoff_hz".into(), toml::Value::Float(0.0));
        let msg = FciParams::of(&bad).unwrap().check(&bad).unwrap_err().to_string();
        assert!(msg.contains("fci.cutoff_hz"), "{msg}");
        bad.fci.insert("cutoff_hz".into(), toml::Value::String("fast".into()));
        let msg = FciParams::of(&bad).unwrap_err().to_string();
        assert!(msg.contains("fci") && msg.contains("cutoff_hz"), "{msg}");
        let mut six = p.clone();
        six.joints = 6;
        let msg = f.check(&six).unwrap_err().to_string();
        assert!(msg.contains("drives a Franka arm"), "{msg}");
    }
}
