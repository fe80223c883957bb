//! Which faults the sim backend injects, as the profile's `[sim.faults]` table (or `mars-hal`'s command line)
//! states them: checked here, fired by the HAL's `fault` module. What each fault does is told there.

use serde::Deserialize;

/// Which faults to inject; everything is off by default.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultConfig {
    /// Drop each state frame with this probability (0..=1), from the seeded generator.
    #[serde(default)]
    pub drop_probability: f64,
    /// Drop every N-th state frame (ticks N-1, 2N-1, …); 0: off.
    #[serde(default)]
    pub drop_every: u64,
    /// Publish every N-th state frame late (ticks N-1, 2N-1, …); 0: off.
    #[serde(default)]
    pub late_every: u64,
    /// How late a late frame is published (ms).
    #[serde(default)]
    pub late_ms: f64,
    /// From this tick on the position sensor stops updating.
    #[serde(default)]
    pub freeze_at_tick: Option<u64>,
    /// From `nan_at_tick` on, joint `nan_joint` measures NaN.
    #[serde(default)]
    pub nan_joint: Option<usize>,
    #[serde(default)]
    pub nan_at_tick: Option<u64>,
    /// At this tick the HAL loop sleeps `stall_ms` once.
    #[serde(default)]
    pub stall_at_tick: Option<u64>,
    #[serde(default)]
    pub stall_ms: f64,
    /// At this tick the process aborts.
    #[serde(default)]
    pub crash_at_tick: Option<u64>,
    /// From this tick on, for `read_error_ticks` ticks, the backend's `read` fails (a transient error).
    #[serde(default)]
    pub read_error_at_tick: Option<u64>,
    #[serde(default)]
    pub read_error_ticks: u64,
    /// From this tick on, for `apply_error_ticks` ticks, the backend's `apply` fails (a transient error).
    #[serde(default)]
    pub apply_error_at_tick: Option<u64>,
    #[serde(default)]
    pub apply_error_ticks: u64,
    /// From this tick on the backend's `read` fails for good (a fatal error; `apply` still brakes).
    #[serde(default)]
    pub fatal_at_tick: Option<u64>,
    /// Seed of the drop generator (separate from the plant noise, so turning faults on keeps the noise).
    #[serde(default)]
    pub seed: u64,
}

impl FaultConfig {
    /// Check ranges against a robot with `joints` joints; the message names the field.
    pub fn validate(&self, joints: usize) -> Result<(), String> {
        if !(self.drop_probability.is_finite() && (0.0..=1.0).contains(&self.drop_probability)) {
            return Err(format!("faults.drop_probability = {} must be in 0..=1", self.drop_probability));
        }
        for (field, ms) in [("late_ms", self.late_ms), ("stall_ms", self.stall_ms)] {
            if !(ms.is_finite() && (0.0..=60_000.0).contains(&ms)) {
                return Err(format!("faults.{field} = {ms} must be in 0..=60000"));
            }
        }
        if self.late_every > 0 && self.late_ms == 0.0 {
            return Err("faults.late_every is set but faults.late_ms is 0".into());
        }
        if self.stall_at_tick.is_some() && self.stall_ms == 0.0 {
            return Err("faults.stall_at_tick is set but faults.stall_ms is 0".into());
        }
        for (at, ticks, name) in [
            (self.read_error_at_tick, self.read_error_ticks, "read_error"),
            (self.apply_error_at_tick, self.apply_error_ticks, "apply_error"),
        ] {
            if at.is_some() != (ticks > 0) {
                return Err(format!("faults.{name}_at_tick and faults.{name}_ticks go together"));
            }
        }
        match (self.nan_joint, self.nan_at_tick) {
            (Some(j), Some(_)) if j >= joints => {
                return Err(format!("faults.nan_joint = {j} but the robot has {joints} joints (0-based)"));
            }
            (Some(_), None) | (None, Some(_)) => {
                return Err("faults.nan_joint and faults.nan_at_tick must be given together".into());
            }
            _ => {}
        }
        Ok(())
    }

    pub fn any(&self) -> bool {
        *self != Self { seed: self.seed, ..Self::default() }
    }
}
