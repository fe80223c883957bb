//! The `[fci]` table of a profile: where the robot is and how the HAL talks to it.

use serde::Deserialize;

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

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FciParams {
    /// The robot's address: its Control's IP (e.g. 172.16.0.2), or host:port. `mars-hal --robot-ip` overrides it.
    pub robot_ip: Option<String>,
    pub realtime: Realtime,
    /// Connecting and each blocking request (the first state, an error recovery) give up after this long (s).
    pub connect_timeout_s: f64,
    /// libfranka's rate limiter behind our own safety filter: a second guard that keeps a command from tripping
    /// the FR3's motion-limit reflexes (our filter already keeps the same limits, so it should never act).
    pub limit_rate: bool,
    /// libfranka's low-pass filter on the commanded positions (Hz); 1000 switches it off. libfranka's default.
    pub cutoff_hz: f64,
    /// Drive the Franka Hand (the gripper's own connection, port 1338).
    pub gripper: bool,
    /// The force (N) of a grasp: a closing target is a grasp, an opening one a move.
    pub grasp_force_n: f64,
}

impl Default for FciParams {
    fn default() -> Self {
        Self {
            robot_ip: None,
            realtime: Realtime::Enforce,
            connect_timeout_s: 5.0,
            limit_rate: true,
            cutoff_hz: 100.0,
            gripper: true,
            grasp_force_n: 20.0,
        }
    }
}

impl FciParams {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.connect_timeout_s.is_finite() && self.connect_timeout_s > 0.0 && self.connect_timeout_s <= 600.0) {
            return Err(format!("connect_timeout_s = {} must be in (0, 600] s", self.connect_timeout_s));
        }
        if !(self.cutoff_hz.is_finite() && self.cutoff_hz > 0.0 && self.cutoff_hz <= 1000.0) {
            return Err(format!("cutoff_hz = {} must be in (0, 1000] Hz (1000: off)", self.cutoff_hz));
        }
        // The Franka Hand's continuous force range is 20–70 N (its datasheet); libfranka refuses more.
        if !(self.grasp_force_n.is_finite() && (0.0..=70.0).contains(&self.grasp_force_n)) {
            return Err(format!("grasp_force_n = {} must be in [0, 70] N", self.grasp_force_n));
        }
        Ok(())
    }
}
