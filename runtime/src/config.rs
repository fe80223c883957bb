//! `marsd`'s TOML configuration: which robot, which policy, the two loops' rates and cores, and the
//! watchdog's thresholds. Everything is validated before anything moves; every error names the file and key.

use std::path::{Path, PathBuf};

use serde::Deserialize;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    // The cause is in the message and deliberately not a `source`, so `{:#}` does not print it twice.
    #[error("cannot read config {path}: {error}")]
    Read { path: String, error: std::io::Error },
    #[error("config {path}: {error}")]
    Parse { path: String, error: Box<toml::de::Error> },
    #[error("config {path}: {key}: {msg}")]
    Invalid { path: String, key: &'static str, msg: String },
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// Robot id of the iceoryx2 namespace `mars/<robot>/…`; must match the HAL's `--robot`.
    pub robot: String,
    /// Robot profile: joint count, servo rate and the limits every command must respect.
    pub profile: PathBuf,
    /// Task definition (start pose, grasp configurations, success tolerance).
    pub task: PathBuf,
    /// Checkpoint directory written by `mars train`.
    pub checkpoint: PathBuf,
    /// Where histograms, interval logs, plots and `summary.json` go.
    pub out: PathBuf,
    /// Episodes to run, then stop; 0 runs until SIGTERM/SIGINT (a daemon under systemd).
    #[serde(default)]
    pub episodes: usize,
    /// Seed of the policy's noise and of the episodes' start poses.
    #[serde(default)]
    pub seed: u64,
    /// How long to wait for the first usable state frame before giving up (exit status 4), in seconds.
    #[serde(default = "default_handshake_timeout_s")]
    pub handshake_timeout_s: f64,
    /// Episode traces kept for the episodes plot: the last this many (older ones are dropped, so a run of
    /// `episodes = 0` holds bounded memory).
    #[serde(default = "default_traces_kept")]
    pub traces_kept: usize,
    pub servo: ServoConfig,
    pub policy: PolicyLoopConfig,
    pub watchdog: WatchdogConfig,
    #[serde(default)]
    pub histograms: HistogramConfig,
    #[serde(default)]
    pub faults: FaultConfig,
    /// Record every episode as a LeRobot v3.0 dataset at this path (which must not exist yet).
    #[serde(default)]
    pub record: Option<PathBuf>,
    /// The file this configuration was read from (empty when parsed from text): a recording names it, so a
    /// replay runs with the same configuration.
    #[serde(skip)]
    pub source: PathBuf,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoConfig {
    /// Core the servo loop is pinned to (none: not pinned, with a warning).
    pub core: Option<usize>,
    /// SCHED_FIFO priority (1–99) when the process may use it.
    #[serde(default = "default_servo_priority")]
    pub priority: i32,
    /// mlockall(MCL_CURRENT | MCL_FUTURE) when allowed, so no page fault stalls the tick.
    #[serde(default = "yes")]
    pub lock_memory: bool,
    /// A state frame older than this when read is stale and not used (ms).
    pub stale_state_ms: f64,
    /// Joint targets from the policy are clamped this far inside the position limits (rad).
    pub position_margin: f64,
    /// Reset moves to a start pose end when every joint is this close and the smoother is at rest (rad).
    pub settle_tolerance: f64,
    /// Reset moves to a start pose run at this fraction of the planning velocity limits (0, 1]; the policy's
    /// motions run at full speed.
    #[serde(default = "default_reset_speed")]
    pub reset_speed: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyLoopConfig {
    /// Rate of the policy's actions (Hz): one action per period, a chunk of `chunk_len` actions.
    pub rate_hz: f64,
    pub core: Option<usize>,
    #[serde(default = "default_policy_priority")]
    pub priority: i32,
    /// Inference for the next chunk starts this long before the chunk is needed (ms): the budget it has.
    pub lead_ms: f64,
    /// The chunk must be handed over this long before its first action is due (ms).
    pub handoff_margin_ms: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WatchdogConfig {
    /// Servo ticks that overran their period (woke a full period late) in a row before tripping.
    pub max_consecutive_overruns: u64,
    /// Chunks that arrived after their first action was due, in a row, before tripping.
    pub max_consecutive_late_chunks: u64,
    /// Inference calls that could not fit even K = 1 in their budget, in a row (their chunks are dropped and
    /// the previous chunk is kept), before tripping.
    pub max_consecutive_over_budget: u64,
    /// No usable state frame for this long trips (ms).
    pub max_state_gap_ms: f64,
    /// Command sends that failed in a row before tripping (default 10).
    #[serde(default = "default_max_consecutive_send_errors")]
    pub max_consecutive_send_errors: u64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistogramConfig {
    /// Length of one HdrHistogram interval-log interval (s); every interval is also a `marsd top` refresh.
    pub interval_s: f64,
}

impl Default for HistogramConfig {
    fn default() -> Self {
        Self { interval_s: 0.25 }
    }
}

/// Fault injection for HIL tests; all off by default.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultConfig {
    /// Busy-wait this long in every ODE step of the engine, as a slower CPU would (ms).
    #[serde(default)]
    pub engine_step_delay_ms: f64,
    /// The recording's writer sleeps this long per frame, as a disk or encoder that cannot keep up would (ms).
    #[serde(default)]
    pub record_writer_delay_ms: f64,
}

fn default_handshake_timeout_s() -> f64 {
    10.0
}
fn default_traces_kept() -> usize {
    20
}
fn default_max_consecutive_send_errors() -> u64 {
    10
}
fn yes() -> bool {
    true
}
fn default_reset_speed() -> f64 {
    0.5
}
fn default_servo_priority() -> i32 {
    80
}
fn default_policy_priority() -> i32 {
    70
}

impl DaemonConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|error| ConfigError::Read { path: path.display().to_string(), error })?;
        let mut cfg = Self::parse(&text, &path.display().to_string())?;
        cfg.source = path.to_owned();
        Ok(cfg)
    }

    /// Parses and validates; relative paths inside the file are kept as written (relative to the working
    /// directory, like every path on the command line).
    pub fn parse(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let cfg: Self =
            toml::from_str(text).map_err(|e| ConfigError::Parse { path: origin.to_owned(), error: Box::new(e) })?;
        cfg.validate(origin)?;
        Ok(cfg)
    }

    fn validate(&self, origin: &str) -> Result<(), ConfigError> {
        let bad = |key: &'static str, msg: String| Err(ConfigError::Invalid { path: origin.to_owned(), key, msg });
        let positive = |key: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 { Ok(()) } else { bad(key, format!("must be a positive number, got {v}")) }
        };
        if self.robot.is_empty() {
            return bad("robot", "must not be empty".into());
        }
        positive("handshake_timeout_s", self.handshake_timeout_s)?;
        positive("servo.stale_state_ms", self.servo.stale_state_ms)?;
        positive("servo.settle_tolerance", self.servo.settle_tolerance)?;
        if !(self.servo.reset_speed.is_finite() && self.servo.reset_speed > 0.0 && self.servo.reset_speed <= 1.0) {
            return bad("servo.reset_speed", format!("must be in (0, 1], got {}", self.servo.reset_speed));
        }
        if !(self.servo.position_margin.is_finite() && (0.0..0.5).contains(&self.servo.position_margin)) {
            return bad(
                "servo.position_margin",
                format!("must be in [0, 0.5) rad, got {}", self.servo.position_margin),
            );
        }
        for (key, p) in [("servo.priority", self.servo.priority), ("policy.priority", self.policy.priority)] {
            if !(1..=99).contains(&p) {
                return bad(key, format!("SCHED_FIFO priorities are 1..=99, got {p}"));
            }
        }
        positive("policy.rate_hz", self.policy.rate_hz)?;
        positive("policy.lead_ms", self.policy.lead_ms)?;
        if !(self.policy.handoff_margin_ms.is_finite() && self.policy.handoff_margin_ms >= 0.0) {
            return bad("policy.handoff_margin_ms", format!("must be ≥ 0, got {}", self.policy.handoff_margin_ms));
        }
        if self.policy.handoff_margin_ms >= self.policy.lead_ms {
            return bad("policy.handoff_margin_ms", "must be shorter than policy.lead_ms, or no budget is left".into());
        }
        let period_ms = 1e3 / self.policy.rate_hz;
        if self.policy.lead_ms > period_ms {
            return bad(
                "policy.lead_ms",
                format!("{} ms is longer than one policy period ({period_ms:.1} ms)", self.policy.lead_ms),
            );
        }
        positive("watchdog.max_state_gap_ms", self.watchdog.max_state_gap_ms)?;
        for (key, v) in [
            ("watchdog.max_consecutive_overruns", self.watchdog.max_consecutive_overruns),
            ("watchdog.max_consecutive_late_chunks", self.watchdog.max_consecutive_late_chunks),
            ("watchdog.max_consecutive_over_budget", self.watchdog.max_consecutive_over_budget),
            ("watchdog.max_consecutive_send_errors", self.watchdog.max_consecutive_send_errors),
        ] {
            if v == 0 {
                return bad(key, "must be at least 1".into());
            }
        }
        positive("histograms.interval_s", self.histograms.interval_s)?;
        let d = self.faults.engine_step_delay_ms;
        if !(d.is_finite() && d >= 0.0) {
            return bad("faults.engine_step_delay_ms", format!("must be ≥ 0, got {d}"));
        }
        Ok(())
    }

    pub fn policy_period_ns(&self) -> u64 {
        (1e9 / self.policy.rate_hz).round() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped() -> String {
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/marsd.toml")).unwrap()
    }

    #[test]
    fn send_error_limit_and_kept_traces_default_as_documented_and_refuse_zero() {
        let cfg = DaemonConfig::parse(&shipped(), "marsd.toml").unwrap();
        assert_eq!((cfg.watchdog.max_consecutive_send_errors, cfg.traces_kept), (10, 20));
        let without: String = shipped()
            .lines()
            .filter(|l| !l.starts_with("max_consecutive_send_errors") && !l.starts_with("traces_kept"))
            .map(|l| format!("{l}\n"))
            .collect();
        let cfg = DaemonConfig::parse(&without, "marsd.toml").unwrap();
        assert_eq!((cfg.watchdog.max_consecutive_send_errors, cfg.traces_kept), (10, 20), "the defaults");
        let zero = shipped().replace("max_consecutive_send_errors = 10", "max_consecutive_send_errors = 0");
        assert!(matches!(
            DaemonConfig::parse(&zero, "marsd.toml"),
            Err(ConfigError::Invalid { key: "watchdog.max_consecutive_send_errors", .. })
        ));
    }
}
