//! The deadline-miss watchdog: counts what went wrong and decides when it is too much. On a trip the servo loop
//! brings the arm to rest with a jerk-limited stop, hands the HAL a hold command, and `marsd` exits with the
//! reason in the log and a non-zero status.

use mars_ipc::HoldReason;

use crate::config::WatchdogConfig;

/// Why the watchdog stopped the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trip {
    /// Servo ticks overran their period too many times in a row.
    TickOverruns,
    /// Chunks arrived after their first action was due too many times in a row.
    LateChunks,
    /// Inference could not fit even one ODE step in its budget too many times in a row.
    InferenceOverBudget,
    /// The engine refused its input or produced a non-finite chunk.
    EngineError,
    /// No usable state frame (fresh, finite, right DOF, no sensor fault) for too long.
    StaleState,
    /// The HAL process died or closed its heartbeat (iceoryx2 liveness).
    HalDied,
    /// The HAL stopped following this controller's session.
    HalHolding(HoldReason),
    /// A command about to be sent failed the last check against the robot's limits; it was not sent.
    LimitViolation,
    /// The smoother refused its input (non-finite target).
    Smoothing,
    /// Sending commands to the HAL failed too many times in a row (`watchdog.max_consecutive_send_errors`).
    SendErrors,
    /// No usable camera frame (fresh, of the size and encoding the policy expects) for the policy's inputs, at
    /// as many chunks in a row as `max_consecutive_late_chunks`.
    NoCameraFrame,
    /// The task's scene (the referee, and the world it resets) did not answer within the task's limit.
    SceneLost,
}

impl Trip {
    pub fn code(self) -> u32 {
        match self {
            Self::TickOverruns => 1,
            Self::LateChunks => 2,
            Self::InferenceOverBudget => 3,
            Self::EngineError => 4,
            Self::StaleState => 5,
            Self::HalDied => 6,
            Self::LimitViolation => 7,
            Self::Smoothing => 8,
            Self::SendErrors => 9,
            Self::NoCameraFrame => 10,
            Self::SceneLost => 11,
            Self::HalHolding(r) => 100 + r as u32,
        }
    }

    pub fn from_code(c: u32) -> Option<Self> {
        Some(match c {
            1 => Self::TickOverruns,
            2 => Self::LateChunks,
            3 => Self::InferenceOverBudget,
            4 => Self::EngineError,
            5 => Self::StaleState,
            6 => Self::HalDied,
            7 => Self::LimitViolation,
            8 => Self::Smoothing,
            9 => Self::SendErrors,
            10 => Self::NoCameraFrame,
            11 => Self::SceneLost,
            c if c >= 100 => Self::HalHolding(HoldReason::from_u32(c - 100)?),
            _ => return None,
        })
    }
}

impl std::fmt::Display for Trip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TickOverruns => write!(f, "servo ticks overran their period too many times in a row"),
            Self::LateChunks => write!(f, "action chunks arrived late too many times in a row"),
            Self::InferenceOverBudget => write!(f, "inference could not fit one ODE step in its deadline"),
            Self::EngineError => write!(f, "the inference engine failed"),
            Self::StaleState => write!(f, "no usable state frame from the HAL within the allowed gap"),
            Self::HalDied => write!(f, "the HAL process died or left (iceoryx2 liveness)"),
            Self::HalHolding(r) => write!(f, "the HAL stopped following this controller ({r:?})"),
            Self::LimitViolation => write!(f, "a command failed the final limit check and was not sent"),
            Self::Smoothing => write!(f, "the jerk-limited smoother refused its input"),
            Self::SendErrors => write!(f, "sending commands to the HAL failed too many times in a row"),
            Self::NoCameraFrame => write!(f, "no usable camera frame for the policy's input too many times in a row"),
            Self::SceneLost => write!(f, "the task's scene did not answer (reset, start or referee frames)"),
        }
    }
}

/// Counts a fault that trips after `limit` occurrences in a row; a good event resets the run.
#[derive(Debug, Clone, Copy)]
pub struct Streak {
    limit: u64,
    run: u64,
    pub total: u64,
}

impl Streak {
    pub fn new(limit: u64) -> Self {
        Self { limit, run: 0, total: 0 }
    }

    /// A fault; returns true when the streak reached its limit.
    pub fn bad(&mut self) -> bool {
        self.run += 1;
        self.total += 1;
        self.run >= self.limit
    }

    pub fn good(&mut self) {
        self.run = 0;
    }
}

/// The servo loop's command sends: counts them, and trips when iceoryx2 refused too many in a row.
#[derive(Debug, Clone, Copy)]
pub struct SendWatch {
    failures: Streak,
    /// Samples delivered to iceoryx2.
    pub sent: u64,
}

impl SendWatch {
    pub fn new(max_consecutive_errors: u64) -> Self {
        Self { failures: Streak::new(max_consecutive_errors), sent: 0 }
    }

    /// One send's outcome; `Some(Trip::SendErrors)` when the failures in a row reached the limit.
    pub fn record(&mut self, ok: bool) -> Option<Trip> {
        if ok {
            self.sent += 1;
            self.failures.good();
            None
        } else {
            self.failures.bad().then_some(Trip::SendErrors)
        }
    }

    /// Failed sends in all.
    pub fn errors(&self) -> u64 {
        self.failures.total
    }
}

/// The servo loop's part of the watchdog: tick overruns and the age of the last usable state.
#[derive(Debug, Clone, Copy)]
pub struct ServoWatchdog {
    pub overruns: Streak,
    max_state_gap_ns: u64,
    last_usable_ns: Option<u64>,
}

impl ServoWatchdog {
    pub fn new(cfg: &WatchdogConfig) -> Self {
        Self {
            overruns: Streak::new(cfg.max_consecutive_overruns),
            max_state_gap_ns: (cfg.max_state_gap_ms * 1e6) as u64,
            last_usable_ns: None,
        }
    }

    /// One tick: `missed` periods skipped before it woke, whether a usable frame arrived.
    pub fn tick(&mut self, now_ns: u64, missed: u64, usable_frame: bool) -> Option<Trip> {
        if missed > 0 {
            if self.overruns.bad() {
                return Some(Trip::TickOverruns);
            }
        } else {
            self.overruns.good();
        }
        if usable_frame {
            self.last_usable_ns = Some(now_ns);
        }
        // Before the first frame the daemon is still waiting for the HAL handshake, which has its own timeout.
        match self.last_usable_ns {
            Some(t) if now_ns.saturating_sub(t) > self.max_state_gap_ns => Some(Trip::StaleState),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trip_codes_round_trip() {
        for t in [
            Trip::TickOverruns,
            Trip::LateChunks,
            Trip::InferenceOverBudget,
            Trip::EngineError,
            Trip::StaleState,
            Trip::HalDied,
            Trip::LimitViolation,
            Trip::Smoothing,
            Trip::SendErrors,
            Trip::HalHolding(HoldReason::CommandTimeout),
        ] {
            assert_eq!(Trip::from_code(t.code()), Some(t));
        }
        assert_eq!(Trip::from_code(0), None);
    }

    #[test]
    fn streak_trips_only_on_consecutive_faults() {
        let mut s = Streak::new(3);
        assert!(!s.bad() && !s.bad());
        s.good();
        assert!(!s.bad() && !s.bad());
        assert!(s.bad());
        assert_eq!(s.total, 5);
    }

    #[test]
    fn send_errors_trip_only_when_consecutive() {
        let mut w = SendWatch::new(3);
        assert_eq!([w.record(false), w.record(false), w.record(true)], [None, None, None]);
        assert_eq!([w.record(false), w.record(false)], [None, None]);
        assert_eq!(w.record(false), Some(Trip::SendErrors));
        assert_eq!((w.sent, w.errors()), (1, 5));
    }

    #[test]
    fn stale_state_trips_after_the_gap_but_not_before_the_first_frame() {
        let cfg = WatchdogConfig {
            max_consecutive_overruns: 2,
            max_consecutive_late_chunks: 2,
            max_consecutive_over_budget: 2,
            max_state_gap_ms: 10.0,
            max_consecutive_send_errors: 2,
            priority: 60,
        };
        let mut w = ServoWatchdog::new(&cfg);
        assert_eq!(w.tick(100_000_000, 0, false), None, "no frame yet: the handshake timeout applies");
        assert_eq!(w.tick(200_000_000, 0, true), None);
        assert_eq!(w.tick(209_000_000, 0, false), None);
        assert_eq!(w.tick(211_000_000, 0, false), Some(Trip::StaleState));
        let mut w = ServoWatchdog::new(&cfg);
        assert_eq!(w.tick(1, 1, true), None);
        assert_eq!(w.tick(2, 1, true), Some(Trip::TickOverruns));
    }
}
