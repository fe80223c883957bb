//! `marsd`'s TOML configuration: which robot, which policy, the two loops' rates and cores, and the
//! watchdog's thresholds. Everything is validated before anything moves; every error names the file and key.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

/// The longest `handshake_timeout_s` (a day): a HAL started by hand later than that is a mistake, and every bound
/// here keeps the conversions to `Duration` and to nanoseconds far from overflow (a `1e300` is refused at load,
/// not a panic in a running loop).
pub const MAX_HANDSHAKE_TIMEOUT_S: f64 = 86_400.0;
/// The longest of the loops' times in ms (a minute): `servo.stale_state_ms`, `policy.lead_ms`,
/// `policy.handoff_margin_ms`, `watchdog.max_state_gap_ms` and the injected fault delays.
pub const MAX_LOOP_MS: f64 = 60_000.0;
/// The fastest policy rate (the fastest servo rate a profile may have).
pub const MAX_POLICY_RATE_HZ: f64 = 10_000.0;
/// `histograms.interval_s`: at least 10 ms (an interval log line and a live update per interval), at most an hour.
pub const HISTOGRAM_INTERVAL_S: (f64, f64) = (0.01, 3600.0);
/// The most episode traces kept for the plot: each holds up to 4096 steps of joint positions (~0.25 MB), all
/// allocated up front and locked with the rest of marsd's memory.
pub const MAX_TRACES_KEPT: usize = 1000;

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
    /// The policy on an inference host (`marsd serve`) reached over Zenoh; the local engine stays loaded and
    /// answers whenever the host's chunk is not back in time.
    #[serde(default)]
    pub remote: Option<RemoteConfig>,
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
    /// Each chunk is asked for this many policy periods earlier than `lead_ms` alone would (default 0), for an
    /// inference host whose round trip is longer than the lead: the chunk's first rows are then the previous
    /// chunk's (committed), the call is guided toward them and only the rows after them are executed, so chunks
    /// follow each other every `chunk_len − ask_ahead_periods` periods. At most (chunk_len − 1)/2 (checked at load).
    #[serde(default)]
    pub ask_ahead_periods: usize,
    /// With `ask_ahead_periods` > 0, how a chunk continues the rows the previous one commits: `guided` (the call is
    /// guided toward them, the default) or `drop-late` (the chunk computed without them, its first rows dropped).
    #[serde(default)]
    pub continuity: Continuity,
}

/// How an early-asked chunk continues the previous chunk's committed rows (`[policy] continuity`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Continuity {
    #[default]
    Guided,
    DropLate,
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
    /// SCHED_FIFO priority (1–99) of the threads that watch and report: the HAL's liveness watch, our heartbeat
    /// and the main thread that logs a trip. Under the loops', above every ordinary process: a busy machine then
    /// delays neither the verdict that the HAL died nor a trip's report (default 60).
    #[serde(default = "default_watch_priority")]
    pub priority: i32,
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

/// `[remote]`: where the inference host is, and what the robot keeps for itself.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RemoteConfig {
    /// Key prefix shared with the host (`marsd serve --prefix`): this robot's queries go to
    /// `<prefix>/<robot>/infer`.
    #[serde(default = "default_remote_prefix")]
    pub prefix: String,
    /// This robot's name on the Zenoh network, which the host serves (`marsd serve --robot NAME=…`); default:
    /// `robot`. Apart from `robot` because that one is also the iceoryx2 namespace, which the HIL demo makes per run.
    #[serde(default)]
    pub name: Option<String>,
    /// Zenoh locators to connect to (the inference host or a router), e.g. `["tcp/192.168.1.20:7447"]`.
    #[serde(default)]
    pub connect: Vec<String>,
    /// Zenoh locators to listen on (when the host connects to the robot instead).
    #[serde(default)]
    pub listen: Vec<String>,
    /// Also find the host by UDP multicast scouting.
    #[serde(default)]
    pub multicast_scouting: bool,
    /// Time kept for the local engine when the host's chunk is not back (ms): the host's wait ends this long
    /// before the handoff margin. At least one local call at full K (the FR3 demo's: ~2 ms); with `on_miss = "rest"`
    /// nothing runs in it, and it may be small.
    #[serde(default = "default_local_reserve_ms")]
    pub local_reserve_ms: f64,
    /// What replaces a chunk the host did not give in time: `local` (the local engine computes it, the default)
    /// or `rest` (none: the servo finishes the chunk it has and holds its last action, so the arm comes to rest
    /// there until the host answers again).
    #[serde(default)]
    pub on_miss: OnMiss,
    /// Choose `[policy] ask_ahead_periods` from the round trip measured at start (the median of the clock's pings):
    /// the fewest periods that leave the host that round trip and its answer before the local reserve; 0 when no
    /// host answered then, or when the round trip needs more periods than the chunk allows. Not with
    /// `ask_ahead_periods` set too.
    #[serde(default)]
    pub auto_ask_ahead: bool,
}

/// `[remote] on_miss`: what the robot does while the inference host's chunks are missing.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnMiss {
    /// The local engine computes the chunk in the reserve.
    #[default]
    Local,
    /// No chunk: the arm comes to rest at the last action it was given.
    Rest,
}

impl RemoteConfig {
    /// The name the host knows this robot by.
    pub fn name<'a>(&'a self, robot: &'a str) -> &'a str {
        self.name.as_deref().unwrap_or(robot)
    }

    pub fn link(&self) -> mars_remote::link::LinkConfig {
        mars_remote::link::LinkConfig {
            connect: self.connect.clone(),
            listen: self.listen.clone(),
            multicast_scouting: self.multicast_scouting,
        }
    }
}

fn default_remote_prefix() -> String {
    "mars".into()
}
/// `[remote] local_reserve_ms` when the table does not set it.
pub const DEFAULT_LOCAL_RESERVE_MS: f64 = 10.0;

fn default_local_reserve_ms() -> f64 {
    DEFAULT_LOCAL_RESERVE_MS
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
    /// The policy loop sleeps this long once, in period `policy_stall_period` of episode 1 (the first), as a machine
    /// that takes its core away would (ms; 0: never).
    #[serde(default)]
    pub policy_stall_ms: f64,
    #[serde(default)]
    pub policy_stall_period: u64,
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
fn default_watch_priority() -> i32 {
    60
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

    /// Checks every field; also after the command line changed some ([`crate::daemon::prepare`] calls it
    /// again), so that nothing a loop converts to a `Duration` or to nanoseconds can overflow there.
    pub fn validate(&self, origin: &str) -> Result<(), ConfigError> {
        let bad = |key: &'static str, msg: String| Err(ConfigError::Invalid { path: origin.to_owned(), key, msg });
        let in_range = |key: &'static str, v: f64, zero_ok: bool, max: f64, unit: &str| {
            let low_ok = if zero_ok { v >= 0.0 } else { v > 0.0 };
            if v.is_finite() && low_ok && v <= max {
                return Ok(());
            }
            let what = if zero_ok { "a number ≥ 0" } else { "a positive number" };
            bad(key, format!("must be {what} of at most {max} {unit}, got {v:?}"))
        };
        if self.robot.is_empty() {
            return bad("robot", "must not be empty".into());
        }
        in_range("handshake_timeout_s", self.handshake_timeout_s, false, MAX_HANDSHAKE_TIMEOUT_S, "s")?;
        if self.traces_kept > MAX_TRACES_KEPT {
            return bad("traces_kept", format!("must be at most {MAX_TRACES_KEPT}, got {}", self.traces_kept));
        }
        in_range("servo.stale_state_ms", self.servo.stale_state_ms, false, MAX_LOOP_MS, "ms")?;
        if !(self.servo.settle_tolerance.is_finite() && self.servo.settle_tolerance > 0.0) {
            return bad(
                "servo.settle_tolerance",
                format!("must be a positive number, got {}", self.servo.settle_tolerance),
            );
        }
        if !(self.servo.reset_speed.is_finite() && self.servo.reset_speed > 0.0 && self.servo.reset_speed <= 1.0) {
            return bad("servo.reset_speed", format!("must be in (0, 1], got {}", self.servo.reset_speed));
        }
        if !(self.servo.position_margin.is_finite() && (0.0..0.5).contains(&self.servo.position_margin)) {
            return bad(
                "servo.position_margin",
                format!("must be in [0, 0.5) rad, got {}", self.servo.position_margin),
            );
        }
        let priorities = [
            ("servo.priority", self.servo.priority),
            ("policy.priority", self.policy.priority),
            ("watchdog.priority", self.watchdog.priority),
        ];
        for (key, p) in priorities {
            if !(1..=99).contains(&p) {
                return bad(key, format!("SCHED_FIFO priorities are 1..=99, got {p}"));
            }
        }
        in_range("policy.rate_hz", self.policy.rate_hz, false, MAX_POLICY_RATE_HZ, "Hz")?;
        in_range("policy.lead_ms", self.policy.lead_ms, false, MAX_LOOP_MS, "ms")?;
        in_range("policy.handoff_margin_ms", self.policy.handoff_margin_ms, true, MAX_LOOP_MS, "ms")?;
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
        in_range("watchdog.max_state_gap_ms", self.watchdog.max_state_gap_ms, false, MAX_LOOP_MS, "ms")?;
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
        let (lo, hi) = HISTOGRAM_INTERVAL_S;
        let interval = self.histograms.interval_s;
        if !(interval.is_finite() && (lo..=hi).contains(&interval)) {
            return bad("histograms.interval_s", format!("must be in [{lo}, {hi}] s, got {interval:?}"));
        }
        in_range("faults.engine_step_delay_ms", self.faults.engine_step_delay_ms, true, MAX_LOOP_MS, "ms")?;
        if let Some(r) = &self.remote {
            if let Err(e) = mars_remote::link::infer_key(&r.prefix, r.name(&self.robot)) {
                let key =
                    if matches!(e, mars_remote::link::LinkError::Prefix(_)) { "remote.prefix" } else { "remote.name" };
                return bad(key, e.to_string());
            }
            let room = self.policy.lead_ms - self.policy.handoff_margin_ms;
            in_range(
                "remote.local_reserve_ms",
                r.local_reserve_ms,
                false,
                room,
                "ms (policy.lead_ms less the margin)",
            )?;
            if r.auto_ask_ahead && self.policy.ask_ahead_periods > 0 {
                return bad("remote.auto_ask_ahead", "policy.ask_ahead_periods is set too: give one of the two".into());
            }
            if r.connect.is_empty() && r.listen.is_empty() && !r.multicast_scouting {
                return bad("remote", "names no way to the host: give connect, listen or multicast_scouting".into());
            }
        }
        in_range("faults.record_writer_delay_ms", self.faults.record_writer_delay_ms, true, MAX_LOOP_MS, "ms")?;
        in_range("faults.policy_stall_ms", self.faults.policy_stall_ms, true, MAX_LOOP_MS, "ms")?;
        Ok(())
    }

    /// How long marsd waits for the HAL's first usable frame (validated: never overflows).
    pub fn handshake_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.handshake_timeout_s)
    }

    /// One histogram interval (validated).
    pub fn histogram_interval(&self) -> Duration {
        Duration::from_secs_f64(self.histograms.interval_s)
    }

    /// The injected busy-wait of every ODE step (validated).
    pub fn engine_step_delay(&self) -> Duration {
        Duration::from_secs_f64(self.faults.engine_step_delay_ms * 1e-3)
    }

    /// The injected sleep of the recording's writer per frame (validated).
    pub fn record_writer_delay(&self) -> Duration {
        Duration::from_secs_f64(self.faults.record_writer_delay_ms * 1e-3)
    }

    /// The injected stall of the policy loop (validated), and the period of episode 1 it happens in.
    pub fn policy_stall(&self) -> (Duration, u64) {
        (Duration::from_secs_f64(self.faults.policy_stall_ms * 1e-3), self.faults.policy_stall_period)
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

    /// Values TOML accepts that a loop could not convert (`Duration::from_secs_f64` panics on 1e300 and on a
    /// negative number): each refused at load, naming its key, so marsd exits 2 before anything moves.
    #[test]
    fn hostile_times_and_sizes_are_refused_at_load_naming_the_key() {
        let with = |key: &str, line: &str| {
            let text = shipped();
            let old = text.lines().find(|l| l.starts_with(&format!("{key} ="))).unwrap_or_else(|| panic!("{key}"));
            text.replace(old, line)
        };
        let faults = |line: &str| format!("{}\n[faults]\n{line}\n", shipped());
        let cases = [
            ("handshake_timeout_s", with("handshake_timeout_s", "handshake_timeout_s = 1e300")),
            ("handshake_timeout_s", with("handshake_timeout_s", "handshake_timeout_s = nan")),
            ("histograms.interval_s", with("interval_s", "interval_s = 1e300")),
            ("histograms.interval_s", with("interval_s", "interval_s = 1e-12")),
            ("faults.record_writer_delay_ms", faults("record_writer_delay_ms = -1.0")),
            ("faults.record_writer_delay_ms", faults("record_writer_delay_ms = inf")),
            ("faults.engine_step_delay_ms", faults("engine_step_delay_ms = 1e300")),
            ("faults.policy_stall_ms", faults("policy_stall_ms = -5")),
            ("servo.stale_state_ms", with("stale_state_ms", "stale_state_ms = 1e300")),
            ("watchdog.max_state_gap_ms", with("max_state_gap_ms", "max_state_gap_ms = 1e20")),
            ("traces_kept", with("traces_kept", "traces_kept = 1000000000000")),
        ];
        for (key, text) in cases {
            match DaemonConfig::parse(&text, "marsd.toml") {
                Err(ConfigError::Invalid { key: k, msg, .. }) => assert_eq!(k, key, "{msg}"),
                other => panic!("{key}: expected a refusal naming it, got {other:?}"),
            }
        }
        // What the command line changes is checked again by `prepare`, through the same `validate`.
        let mut cfg = DaemonConfig::parse(&shipped(), "marsd.toml").unwrap();
        cfg.faults.record_writer_delay_ms = -1.0;
        let e = cfg.validate("marsd.toml").unwrap_err().to_string();
        assert!(e.contains("faults.record_writer_delay_ms") && e.contains("got -1"), "{e}");
    }

    /// `[remote] on_miss`: `local` unless set, `rest` when asked, anything else refused at load with the words.
    #[test]
    fn on_miss_defaults_to_the_local_engine_and_refuses_an_unknown_choice() {
        let remote = |line: &str| format!("{}\n[remote]\nconnect = [\"tcp/127.0.0.1:7447\"]\n{line}\n", shipped());
        let on_miss = |line: &str| DaemonConfig::parse(&remote(line), "t").map(|c| c.remote.unwrap().on_miss);
        assert_eq!(on_miss("").unwrap(), OnMiss::Local);
        assert_eq!(on_miss("on_miss = \"rest\"").unwrap(), OnMiss::Rest);
        let e = on_miss("on_miss = \"halt\"").unwrap_err().to_string();
        assert!(e.contains("on_miss") && e.contains("local") && e.contains("rest"), "{e}");
    }

    /// Every duration of an accepted configuration converts (what the daemon does with them).
    #[test]
    fn the_largest_accepted_times_convert_to_durations() {
        let mut cfg = DaemonConfig::parse(&shipped(), "marsd.toml").unwrap();
        cfg.handshake_timeout_s = MAX_HANDSHAKE_TIMEOUT_S;
        cfg.histograms.interval_s = HISTOGRAM_INTERVAL_S.1;
        cfg.faults.engine_step_delay_ms = MAX_LOOP_MS;
        cfg.faults.record_writer_delay_ms = MAX_LOOP_MS;
        cfg.validate("t").unwrap();
        assert_eq!(cfg.handshake_timeout(), Duration::from_secs(86_400));
        assert_eq!(cfg.histogram_interval(), Duration::from_secs(3600));
        assert_eq!(
            (cfg.engine_step_delay(), cfg.record_writer_delay()),
            (Duration::from_secs(60), Duration::from_secs(60))
        );
    }
}
