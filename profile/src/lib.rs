//! Robot profiles: joint count, rate, limits, safety policy, sim parameters, read from TOML and validated before
//! anything moves; and each driver's own table (`[fci]`, `[ros2]`) kept as TOML, which that driver reads and checks
//! ([`Profile::driver_table`]): the profile knows no driver, and marsd reads limits without linking one.

use std::path::Path;

use mars_ipc::MAX_JOINTS;
use serde::Deserialize;

pub mod faults;
pub mod velocity_limits;

use faults::FaultConfig;
use velocity_limits::{JointVelocityBound, VelocityLimits};

/// What the safety filter does with a command outside the limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LimitPolicy {
    /// Bring it inside the limits (libfranka's `limit_rate = true` behaviour) and count it.
    Clamp,
    /// Refuse it, keep following the last valid command, and count it.
    Reject,
}

/// Parameters of the sim backend's plant.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimParams {
    /// Ticks between a setpoint being applied and the plant starting to follow it.
    #[serde(default)]
    pub latency_ticks: usize,
    /// First-order tracking time constant of the joints (s); 0 follows the setpoint exactly.
    #[serde(default)]
    pub tracking_time_constant_s: f64,
    /// Standard deviation of the Gaussian noise on measured positions (rad).
    #[serde(default)]
    pub position_noise_std: f64,
    #[serde(default)]
    pub seed: u64,
    /// Joint positions the plant starts at, instead of the profile's `home` (e.g. to test that a HAL starts from
    /// where the arm is, not from `home`).
    #[serde(default)]
    pub start: Option<Vec<f64>>,
    /// Gripper opening the plant starts at (default: `gripper_max`).
    #[serde(default)]
    pub start_gripper: Option<f64>,
    /// Faults to inject (all off by default); see [`faults`].
    #[serde(default)]
    pub faults: FaultConfig,
}

impl Default for SimParams {
    fn default() -> Self {
        Self {
            latency_ticks: 0,
            tracking_time_constant_s: 0.0,
            position_noise_std: 0.0,
            seed: 0,
            start: None,
            start_gripper: None,
            faults: FaultConfig::default(),
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    pub name: String,
    pub joints: usize,
    pub rate_hz: f64,
    /// No valid command for this long → brake to rest and hold.
    pub command_timeout_ms: f64,
    pub limit_policy: LimitPolicy,
    pub q_min: Vec<f64>,
    pub q_max: Vec<f64>,
    pub dq_max: Vec<f64>,
    /// Whether the velocity bound depends on position (the FR3's braking curves, see [`velocity_limits`]);
    /// `dq_max` caps it either way.
    #[serde(default)]
    pub velocity_limits: VelocityLimits,
    /// How far (rad/s) every trajectory is planned below the velocity bounds (default 0). A robot that judges the
    /// arm's *measured* velocity (the FR3's safety controller) sees the commanded velocity plus the arm's tracking
    /// overshoot; commands themselves are still judged against the bounds.
    #[serde(default)]
    pub velocity_headroom: f64,
    pub ddq_max: Vec<f64>,
    pub jerk_max: Vec<f64>,
    /// Where the sim backend starts (unless `sim.start` says otherwise); must lie inside the limits. The HAL
    /// itself never moves the arm here: it starts from wherever the arm is measured.
    pub home: Vec<f64>,
    pub gripper_min: f64,
    pub gripper_max: f64,
    /// The fastest the gripper opening may change (m/s): a command's `gripper_speed` is capped by it.
    pub gripper_speed_max: f64,
    /// A new gripper target goes to the backend only when it differs from the one sent last by more than
    /// this (m): a gripper takes one move at a time, not a stream.
    pub gripper_deadband: f64,
    /// …and at most once per this long (ms); a target that changes meanwhile is sent when it ends.
    pub gripper_command_interval_ms: f64,
    /// Which backend drives the robot: the sim plant (default), a Franka robot over FCI (`[fci]`), or a robot
    /// over ROS 2 topics (`[ros2]`).
    #[serde(default)]
    pub backend: BackendKind,
    #[serde(default)]
    pub sim: SimParams,
    /// The fci backend's table (`[fci]`): the HAL's `fci::FciParams` reads and checks it.
    #[serde(default)]
    pub fci: toml::Table,
    /// The ros2 backend's table (`[ros2]`): the HAL's `ros2::Ros2Params` reads and checks it.
    #[serde(default)]
    pub ros2: toml::Table,
}

/// The robot behind the HAL.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum BackendKind {
    /// The simulated plant with fault injection (`[sim]`), paced by the HAL's own timer.
    #[default]
    Sim,
    /// A Franka robot (FR3) or franka-sim over the Franka Control Interface (`[fci]`), paced by the robot.
    Fci,
    /// A robot driven over ROS 2 topics (`[ros2]`: the Galaxea R1 Lite's), paced by the HAL's own timer.
    Ros2,
}

/// The largest joint position magnitude (rad or m), velocity (/s), acceleration (/s²) and jerk (/s³) limits, and
/// gripper opening (m) and speed (m/s) a profile may give: far above any arm's (the FR3: 2.62 rad/s, 10 rad/s²,
/// 5000 rad/s³), and they keep every product the safety filter and the smoother form finite (a `ddq_max` of 1e11
/// turned the filter's rest range inside out, and 1e300 would make its setpoints NaN).
pub const MAX_POSITION: f64 = 1e3;
pub const MAX_VELOCITY: f64 = 1e2;
pub const MAX_ACCELERATION: f64 = 1e4;
pub const MAX_JERK: f64 = 1e7;

/// The longest `command_timeout_ms`, `gripper_command_interval_ms` and `[ros2] feedback_timeout_ms` (a minute):
/// far above any sensible setting, and it keeps their conversions to ticks and nanoseconds far from overflow.
pub const MAX_TIMEOUT_MS: f64 = 60_000.0;

#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    // The cause is in the message and deliberately not a `source`, so `{:#}` does not print it twice.
    #[error("reading profile {path}: {error}")]
    Read { path: String, error: std::io::Error },
    #[error("parsing profile {path}: {error}")]
    Parse { path: String, error: Box<toml::de::Error> },
    #[error("profile {name:?}: {msg}")]
    Invalid { name: String, msg: String },
}

impl Profile {
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        let text = std::fs::read_to_string(path)
            .map_err(|error| ProfileError::Read { path: path.display().to_string(), error })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parse and validate; `origin` names the source in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, ProfileError> {
        let p: Profile =
            toml::from_str(text).map_err(|e| ProfileError::Parse { path: origin.to_owned(), error: Box::new(e) })?;
        p.validate()?;
        Ok(p)
    }

    pub fn period_s(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// Command timeout (ns).
    pub fn timeout_ns(&self) -> u64 {
        (self.command_timeout_ms * 1e6) as u64
    }

    /// The velocity bound of each joint.
    pub fn velocity_bounds(&self) -> Vec<JointVelocityBound> {
        (0..self.joints).map(|i| JointVelocityBound::new(self.velocity_limits, i, self.dq_max[i])).collect()
    }

    /// The bounds the safety filter plans its own trajectories with: the planning bounds, a further A²/J inside
    /// (the velocity a joint gains while its acceleration ramps down at the jerk limit).
    pub fn filter_velocity_bounds(&self) -> Vec<JointVelocityBound> {
        let lag = |i: usize| self.ddq_max[i] * self.ddq_max[i] / self.jerk_max[i];
        self.planning_velocity_bounds().iter().enumerate().map(|(i, b)| b.tightened(lag(i))).collect()
    }

    /// The bounds trajectories are planned with: [`Self::velocity_bounds`] less `velocity_headroom`.
    pub fn planning_velocity_bounds(&self) -> Vec<JointVelocityBound> {
        self.velocity_bounds().iter().map(|b| b.with_headroom(self.velocity_headroom)).collect()
    }

    /// The position range each joint may be commanded to and rest in: `[q_min, q_max]`, narrowed where the
    /// planning velocity bound forbids standing still (the FR3's braking curves reach zero a little inside some
    /// limits).
    pub fn position_limits(&self) -> (Vec<f64>, Vec<f64>) {
        self.planning_velocity_bounds()
            .iter()
            .enumerate()
            .map(|(i, b)| b.rest_range(self.q_min[i], self.q_max[i]))
            .unzip()
    }

    /// Gripper target interval in ticks (at least one).
    pub fn gripper_interval_ticks(&self) -> u64 {
        ((self.gripper_command_interval_ms * 1e-3 * self.rate_hz).round() as u64).max(1)
    }

    pub fn validate(&self) -> Result<(), ProfileError> {
        let checks = || -> Result<(), String> {
            self.check_rate_and_timeout()?;
            self.check_joint_tables()?;
            self.check_joint_limits()?;
            self.check_gripper()?;
            self.check_sim()?;
            Ok(())
        };
        checks().map_err(|msg| ProfileError::Invalid { name: self.name.clone(), msg })
    }

    /// The robot's size, rate and command timeout.
    fn check_rate_and_timeout(&self) -> Result<(), String> {
        if self.joints == 0 || self.joints > MAX_JOINTS {
            return Err(format!("joints = {} but must be 1..={MAX_JOINTS}", self.joints));
        }
        if !(self.rate_hz.is_finite() && (1.0..=10_000.0).contains(&self.rate_hz)) {
            return Err(format!("rate_hz = {} but must be in 1..=10000", self.rate_hz));
        }
        let period_ms = 1e3 / self.rate_hz;
        if !(self.command_timeout_ms.is_finite()
            && self.command_timeout_ms >= 2.0 * period_ms
            && self.command_timeout_ms <= MAX_TIMEOUT_MS)
        {
            return Err(format!(
                "command_timeout_ms = {} but must be at least two control periods ({:.3} ms) and at most \
                 {MAX_TIMEOUT_MS} ms",
                self.command_timeout_ms,
                2.0 * period_ms
            ));
        }
        Ok(())
    }

    /// Every per-joint table: one finite value per joint, each within this build's magnitudes.
    fn check_joint_tables(&self) -> Result<(), String> {
        for (field, v) in [
            ("q_min", &self.q_min),
            ("q_max", &self.q_max),
            ("dq_max", &self.dq_max),
            ("ddq_max", &self.ddq_max),
            ("jerk_max", &self.jerk_max),
            ("home", &self.home),
        ] {
            if v.len() != self.joints {
                return Err(format!("{field} has {} values but the robot has {} joints", v.len(), self.joints));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(format!("{field}[{i}] is not a finite number"));
            }
        }
        for (field, v, max) in [
            ("q_min", &self.q_min, MAX_POSITION),
            ("q_max", &self.q_max, MAX_POSITION),
            ("home", &self.home, MAX_POSITION),
            ("dq_max", &self.dq_max, MAX_VELOCITY),
            ("ddq_max", &self.ddq_max, MAX_ACCELERATION),
            ("jerk_max", &self.jerk_max, MAX_JERK),
        ] {
            if let Some(i) = v.iter().position(|x| x.abs() > max) {
                return Err(format!("{field}[{i}] = {:?} but its magnitude must be at most {max}", v[i]));
            }
        }
        Ok(())
    }

    /// The limits as the safety filter will use them: ordered, leaving a position to rest in, home inside, one tick of
    /// maximal jerk within the acceleration limit.
    fn check_joint_limits(&self) -> Result<(), String> {
        self.velocity_limits.check_joints(self.joints)?;
        let slowest = self.dq_max.iter().copied().fold(f64::INFINITY, f64::min);
        if !(self.velocity_headroom.is_finite()
            && self.velocity_headroom >= 0.0
            && self.velocity_headroom < 0.5 * slowest)
        {
            return Err(format!(
                "velocity_headroom = {} but must be ≥ 0 and below half the smallest dq_max ({slowest})",
                self.velocity_headroom
            ));
        }
        for i in 0..self.joints {
            if self.q_min[i] >= self.q_max[i] {
                return Err(format!("joint {i}: q_min {} must be below q_max {}", self.q_min[i], self.q_max[i]));
            }
        }
        let (lo, hi) = self.position_limits();
        for i in 0..self.joints {
            if lo[i] >= hi[i] {
                return Err(format!(
                    "joint {i}: the velocity bounds leave no position to rest in [{}, {}]",
                    lo[i], hi[i]
                ));
            }
            if !(lo[i]..=hi[i]).contains(&self.home[i]) {
                return Err(format!("joint {i}: home {} lies outside [{}, {}]", self.home[i], lo[i], hi[i]));
            }
            for (field, v) in [("dq_max", &self.dq_max), ("ddq_max", &self.ddq_max), ("jerk_max", &self.jerk_max)] {
                if v[i] <= 0.0 {
                    return Err(format!("{field}[{i}] = {} but must be positive", v[i]));
                }
            }
            // The safety filter's velocity-dependent acceleration bound keeps velocity and jerk inside their
            // limits only if one tick of maximal jerk does not exceed the acceleration limit.
            if self.jerk_max[i] / self.rate_hz > self.ddq_max[i] {
                return Err(format!(
                    "joint {i}: jerk_max/rate_hz = {} exceeds ddq_max {}: raise the rate or lower jerk_max",
                    self.jerk_max[i] / self.rate_hz,
                    self.ddq_max[i]
                ));
            }
        }
        for (i, b) in self.filter_velocity_bounds().iter().enumerate() {
            let (lo, hi) = b.rest_range(self.q_min[i], self.q_max[i]);
            if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
                return Err(format!(
                    "joint {i}: the safety filter keeps ddq_max²/jerk_max = {} further inside the velocity bounds, which \
                     leaves it no position to rest in: lower ddq_max or raise jerk_max",
                    self.ddq_max[i] * self.ddq_max[i] / self.jerk_max[i]
                ));
            }
        }
        Ok(())
    }

    /// The gripper's range, speed, deadband and command interval.
    fn check_gripper(&self) -> Result<(), String> {
        if !(self.gripper_min.is_finite() && self.gripper_max.is_finite() && self.gripper_min < self.gripper_max) {
            return Err(format!(
                "gripper range [{}, {}] is not a finite, non-empty interval",
                self.gripper_min, self.gripper_max
            ));
        }
        if self.gripper_min.abs().max(self.gripper_max.abs()) > MAX_POSITION {
            return Err(format!(
                "gripper range [{}, {}] reaches past ±{MAX_POSITION}",
                self.gripper_min, self.gripper_max
            ));
        }
        for (field, v) in [
            ("gripper_speed_max", self.gripper_speed_max),
            ("gripper_deadband", self.gripper_deadband),
            ("gripper_command_interval_ms", self.gripper_command_interval_ms),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{field} = {v} but must be a positive number"));
            }
        }
        if self.gripper_speed_max > MAX_VELOCITY {
            return Err(format!("gripper_speed_max = {} but must be at most {MAX_VELOCITY}", self.gripper_speed_max));
        }
        if self.gripper_command_interval_ms > MAX_TIMEOUT_MS {
            return Err(format!(
                "gripper_command_interval_ms = {} but must be at most {MAX_TIMEOUT_MS} ms",
                self.gripper_command_interval_ms
            ));
        }
        Ok(())
    }

    /// The mock plant's settings.
    fn check_sim(&self) -> Result<(), String> {
        let s = &self.sim;
        if !(s.tracking_time_constant_s.is_finite() && (0.0..=3600.0).contains(&s.tracking_time_constant_s)) {
            return Err(format!("sim.tracking_time_constant_s = {} must be in [0, 3600]", s.tracking_time_constant_s));
        }
        if !(s.position_noise_std.is_finite() && s.position_noise_std >= 0.0) {
            return Err(format!("sim.position_noise_std = {} must be ≥ 0", s.position_noise_std));
        }
        if let Some(start) = &s.start
            && (start.len() != self.joints || start.iter().any(|x| !x.is_finite()))
        {
            return Err(format!("sim.start must be {} finite joint positions", self.joints));
        }
        if s.start_gripper.is_some_and(|g| !g.is_finite()) {
            return Err("sim.start_gripper must be a finite number".into());
        }
        if s.latency_ticks > 1000 {
            return Err(format!("sim.latency_ticks = {} is more than 1000", s.latency_ticks));
        }
        if let Err(msg) = s.faults.validate(self.joints) {
            return Err(format!("sim.{msg}"));
        }
        Ok(())
    }

    /// A driver's own table (`[fci]`, `[ros2]`: `table`, named `name`) as that driver's parameters: what it leaves
    /// out takes the driver's defaults; an error names the table and the field.
    pub fn driver_table<T: serde::de::DeserializeOwned>(
        &self,
        name: &str,
        table: &toml::Table,
    ) -> Result<T, ProfileError> {
        toml::Value::Table(table.clone()).try_into().map_err(|e| self.invalid(format!("{name}: {e}")))
    }

    /// An [`ProfileError::Invalid`] of this profile.
    pub fn invalid(&self, msg: String) -> ProfileError {
        ProfileError::Invalid { name: self.name.clone(), msg }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs").join(name)
    }

    #[test]
    fn fr3_profile_carries_the_datasheet_limits_exactly() {
        let p = Profile::load(&config("fr3.toml")).unwrap();
        assert_eq!((p.joints, p.rate_hz, p.limit_policy), (7, 1000.0, LimitPolicy::Clamp));
        assert_eq!(p.q_max, [2.9007, 1.8361, 2.9007, -0.1169, 2.8763, 4.6216, 3.0508]);
        assert_eq!(p.q_min, [-2.9007, -1.8361, -2.9007, -3.0770, -2.8763, 0.4398, -3.0508]);
        assert_eq!(p.dq_max, [2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26]);
        assert_eq!(p.ddq_max, [10.0; 7]);
        assert_eq!(p.jerk_max, [5000.0; 7]);
        assert_eq!(p.command_timeout_ms, 20.0);
        assert_eq!(p.velocity_limits, VelocityLimits::Fr3);
        // The braking curves narrow joint 1 to about the datasheet's ±2.7437 rad…
        let (lo, hi) = p.velocity_bounds()[0].rest_range(p.q_min[0], p.q_max[0]);
        assert!((hi - 2.7426).abs() < 1e-3 && (lo + 2.7426).abs() < 1e-3, "{lo} {hi}");
        // … and the 0.25 rad/s velocity headroom the planners keep narrows it to where that bound is 0.25 rad/s.
        assert_eq!(p.velocity_headroom, 0.25);
        let (lo, hi) = p.position_limits();
        let bound = p.velocity_bounds()[0];
        assert!(
            (bound.hard(hi[0]).1 - 0.25).abs() < 1e-9 && (bound.hard(lo[0]).0 + 0.25).abs() < 1e-9,
            "{lo:?} {hi:?}"
        );
    }

    #[test]
    fn velocity_headroom_must_leave_a_velocity_to_plan_with() {
        for bad in ["-0.1", "1.4", "nan"] {
            let t = fr3_text().replace("velocity_headroom = 0.25", &format!("velocity_headroom = {bad}"));
            assert!(invalid(&t).contains("velocity_headroom"), "{bad}: {}", invalid(&t));
        }
    }

    #[test]
    fn gripper_rates_must_be_positive() {
        let t = fr3_text().replace("gripper_speed_max = 0.1", "gripper_speed_max = 0.0");
        assert!(invalid(&t).contains("gripper_speed_max = 0 but must be a positive number"), "{}", invalid(&t));
    }

    #[test]
    fn r1_lite_profile_is_valid() {
        let p = Profile::load(&config("r1_lite.toml")).unwrap();
        assert_eq!(p.joints, 6);
    }

    fn fr3_text() -> String {
        std::fs::read_to_string(config("fr3.toml")).unwrap()
    }

    fn invalid(text: &str) -> String {
        match Profile::parse(text, "test") {
            Err(e @ ProfileError::Invalid { .. }) | Err(e @ ProfileError::Parse { .. }) => e.to_string(),
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn wrong_length_limit_arrays_are_refused_naming_the_field() {
        let t = fr3_text().replace("dq_max = [2.62, 2.62,", "dq_max = [2.62,");
        assert!(invalid(&t).contains("dq_max has 6 values but the robot has 7 joints"));
    }

    #[test]
    fn inverted_limits_home_outside_and_bad_rates_are_refused() {
        let t = fr3_text().replace("q_min = [-2.9007,", "q_min = [3.5,");
        assert!(invalid(&t).contains("joint 0: q_min 3.5 must be below q_max 2.9007"), "{}", invalid(&t));
        let t = fr3_text().replace("rate_hz = 1000.0", "rate_hz = 0.0");
        assert!(invalid(&t).contains("rate_hz = 0"));
        let t = fr3_text().replace("command_timeout_ms = 20.0", "command_timeout_ms = 1.0");
        assert!(invalid(&t).contains("at least two control periods"));
        let t = fr3_text()
            .replace("rate_hz = 1000.0", "rate_hz = 100.0")
            .replace("command_timeout_ms = 20.0", "command_timeout_ms = 50.0");
        assert!(invalid(&t).contains("jerk_max/rate_hz"), "{}", invalid(&t));
    }

    #[test]
    fn faults_are_read_from_the_profile_and_validated() {
        let p = Profile::parse(&format!("{}\n[sim.faults]\ndrop_every = 10\ncrash_at_tick = 500\n", fr3_text()), "t")
            .unwrap();
        assert_eq!((p.sim.faults.drop_every, p.sim.faults.crash_at_tick), (10, Some(500)));
        assert!(!Profile::load(&config("fr3.toml")).unwrap().sim.faults.any(), "shipped profiles inject nothing");
        let t = format!("{}\n[sim.faults]\nnan_joint = 9\nnan_at_tick = 0\n", fr3_text());
        assert!(invalid(&t).contains("sim.faults.nan_joint = 9"), "{}", invalid(&t));
        let t = format!("{}\n[sim.faults]\ndrop_sometimes = 1\n", fr3_text());
        assert!(invalid(&t).contains("drop_sometimes"));
    }

    /// Found by mars-fuzz: `ddq_max = 1.01e11` on one joint passed and the safety filter's first step panicked
    /// (its rest range, A²/J inside the braking curves, was inside out). Limits far beyond any arm's are refused,
    /// and so is a ratio that leaves the filter nowhere to rest.
    #[test]
    fn limits_beyond_any_arm_and_an_empty_filter_range_are_refused() {
        let ddq = |v: &str| {
            fr3_text().replace("ddq_max = [10.0, 10.0, 10.0, 10.0,", &format!("ddq_max = [10.0, 10.0, 10.0, {v},"))
        };
        assert!(invalid(&ddq("101e9")).contains("ddq_max[3] = 101000000000.0 but its magnitude must be at most"));
        let e =
            invalid(&ddq("9000.0").replace(
                "jerk_max = [5000.0, 5000.0, 5000.0, 5000.0,",
                "jerk_max = [5000.0, 5000.0, 5000.0, 9000000.0,",
            ));
        assert!(e.contains("joint 3: the safety filter keeps ddq_max²/jerk_max = 9 further inside"), "{e}");
        let t = fr3_text().replace("q_min = [-2.9007,", "q_min = [-1e300,");
        assert!(invalid(&t).contains("q_min[0] = -1e300"), "{}", invalid(&t));
    }

    #[test]
    fn unknown_keys_and_bad_policy_are_parse_errors() {
        assert!(invalid(&format!("{}\nspeed = 3\n", fr3_text())).contains("speed"));
        let t = fr3_text().replace("limit_policy = \"clamp\"", "limit_policy = \"ignore\"");
        assert!(invalid(&t).contains("ignore"));
    }
}
