//! A peer simulator's own account of its timing: the one evidence besides the witness's that a rerun may rest on,
//! for a failure that only the peer's pace can cause.
//!
//! franka-sim (PyPI, not our code) is an ordinary Python process: a stall the witness cannot see (the scheduler
//! giving its core to another process of the same class) still slows its physics, and it says so itself. Every 5 s
//! of wall time in which its physics ran below 0.95× real time it logs, with Python's `asctime` (local time; the
//! rig starts it with `TZ=UTC`):
//!
//! ```text
//! 2026-11-27 12:10:49,203 WARNING franka_sim.mujoco_franka_sim: simulation running at 0.93x real time (physics overloaded)
//! ```
//!
//! Such a line covers the 5 s before it, and its physics lost (1 − factor) of them.

use std::fmt;

use crate::Excuse;
use crate::log_time::monotonic_of_time_of_day;

/// The wall time franka-sim's overload warning covers (its `RTF_WARN_INTERVAL_S`).
pub const FRANKA_SIM_WINDOW_NS: u64 = 5_000_000_000;

/// What a peer logged about its own pace over a window (CLOCK_MONOTONIC ns).
#[derive(Debug, Clone, PartialEq)]
pub struct PeerAccount {
    pub peer: &'static str,
    pub window: (u64, u64),
    /// Its real-time factor over the window.
    pub real_time_factor: f64,
    /// The line it logged, as it logged it.
    pub line: String,
}

impl PeerAccount {
    /// The wall time its physics fell behind over the window (ms).
    pub fn lost_ms(&self) -> f64 {
        (1.0 - self.real_time_factor).max(0.0) * (self.window.1 - self.window.0) as f64 * 1e-6
    }
}

impl fmt::Display for PeerAccount {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (from, to) = self.window;
        write!(
            f,
            "{}'s own log, {}–{}: {:.2}× real time, {:.0} ms behind (\"{}\")",
            self.peer,
            crate::evidence::time_of_day(from),
            crate::evidence::time_of_day(to),
            self.real_time_factor,
            self.lost_ms(),
            self.line.trim()
        )
    }
}

/// franka-sim's overload warning in `log` whose window overlaps `[from_ns, to_ns]` and lost the most, if it lost at
/// least `min_ms`.
pub fn franka_sim_overloaded(log: &str, from_ns: u64, to_ns: u64, min_ms: f64) -> Option<PeerAccount> {
    log.lines()
        .filter_map(franka_sim_warning)
        .filter(|a| a.window.0 <= to_ns && a.window.1 >= from_ns && a.lost_ms() >= min_ms)
        .max_by(|a, b| a.lost_ms().total_cmp(&b.lost_ms()))
}

/// An [`Excuse`] for `failure` if franka-sim's own log says its physics lost at least `min_ms` in a window
/// overlapping `[from_ns, to_ns]` ([`franka_sim_overloaded`]).
pub fn franka_sim_excuse(
    failure: impl Into<String>,
    log: &str,
    from_ns: u64,
    to_ns: u64,
    min_ms: f64,
) -> Option<Excuse> {
    franka_sim_overloaded(log, from_ns, to_ns, min_ms).map(|a| Excuse::by_peer(failure.into(), a))
}

/// One overload warning of franka-sim's, read.
fn franka_sim_warning(line: &str) -> Option<PeerAccount> {
    let rest = line.split_once(" WARNING ")?.1;
    let factor = rest.split_once("simulation running at ")?.1.split_once("x real time (physics overloaded)")?.0;
    let real_time_factor: f64 = factor.trim().parse().ok()?;
    let at = monotonic_of_time_of_day(asctime_of_day(line)?)?;
    let window = (at.saturating_sub(FRANKA_SIM_WINDOW_NS), at);
    Some(PeerAccount { peer: "franka-sim", window, real_time_factor, line: line.to_string() })
}

/// Seconds since midnight of Python's `asctime` at the start of a line (`2026-11-27 12:10:49,203 …`).
fn asctime_of_day(line: &str) -> Option<f64> {
    if line.get(10..11)? != " " || line.get(19..20)? != "," {
        return None;
    }
    let mut hms = line.get(11..19)?.split(':').map(|p| p.parse::<f64>().ok());
    let (h, m, s) = (hms.next()??, hms.next()??, hms.next()??);
    let ms: f64 = line.get(20..23)?.parse().ok()?;
    Some(h * 3600.0 + m * 60.0 + s + ms * 1e-3)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::monotonic_ns;

    /// A franka-sim log line stamped `ago_s` seconds before now (UTC, as the rig starts it).
    fn logged(ago_s: u64, message: &str) -> String {
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap();
        let (s, ms) = ((now.as_secs() - ago_s) % 86_400, now.subsec_millis());
        format!("2026-11-27 {:02}:{:02}:{:02},{ms:03} {message}", s / 3600, s / 60 % 60, s % 60)
    }

    #[test]
    fn an_overload_warning_covers_the_five_seconds_before_it() {
        let line = logged(
            10,
            "WARNING franka_sim.mujoco_franka_sim: simulation running at 0.80x real time (physics overloaded)",
        );
        let now = monotonic_ns();
        let a = franka_sim_overloaded(&line, now - 12_000_000_000, now - 11_000_000_000, 100.0).unwrap();
        assert!((a.real_time_factor - 0.8).abs() < 1e-9 && (a.lost_ms() - 1000.0).abs() < 1.0, "{a}");
        // A failure after the line's time, or more than its window before it, is not covered.
        assert_eq!(franka_sim_overloaded(&line, now - 9_000_000_000, now, 100.0), None);
        assert_eq!(franka_sim_overloaded(&line, now - 20_000_000_000, now - 16_000_000_000, 100.0), None);
        // Nor a stall longer than it lost.
        assert_eq!(franka_sim_overloaded(&line, now - 12_000_000_000, now - 11_000_000_000, 1001.0), None);
    }

    #[test]
    fn only_the_overload_warning_counts() {
        let now = monotonic_ns();
        for message in [
            "INFO franka_sim.mujoco_franka_sim: simulation running at 0.50x real time",
            "WARNING franka_sim.mujoco_visuals: simulation running at 0.50x real time",
            "ERROR franka_sim.franka_sim_server: Error handling client: Failed to receive message header",
        ] {
            assert_eq!(franka_sim_overloaded(&logged(2, message), now - 4_000_000_000, now, 0.0), None, "{message}");
        }
        assert_eq!(asctime_of_day("2026-11-27T12:10:49.203Z x"), None);
    }
}
