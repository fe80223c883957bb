//! What the witness saw in a window, as a test prints it.

use std::fmt;

use crate::core_watch::LatenessSeen;
use crate::outrank::Outranker;
use crate::steal::StealSeen;

/// The witness's account of a window (CLOCK_MONOTONIC ns): the core whose witness was late longest in it, and
/// the CPU the hypervisor took most from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evidence {
    pub window: (u64, u64),
    pub lateness: Option<LatenessSeen>,
    pub steal: Option<StealSeen>,
    /// A user-space thread seen above the witness (by the time this account was made): then the lateness and the
    /// steal are no evidence of the machine.
    pub outranked: Option<Outranker>,
}

impl Evidence {
    /// How long the machine stalled in the window, by the larger of the two accounts (ms); 0 when something
    /// outranked the witness.
    pub fn stalled_ms(&self) -> f64 {
        if self.outranked.is_some() {
            return 0.0;
        }
        let late = self.lateness.map_or(0.0, |l| l.ms);
        late.max(self.steal.map_or(0.0, |s| s.ms))
    }
}

impl Evidence {
    /// Whether the window was calm: the host's ordinary noise ([`crate::CALM_MS`], [`crate::CALM_LONGEST_MS`]).
    pub fn is_calm(&self) -> bool {
        let longest = self.lateness.map_or(0.0, |l| l.longest_ms);
        self.outranked.is_none() && self.stalled_ms() < crate::CALM_MS && longest < crate::CALM_LONGEST_MS
    }
}

impl fmt::Display for Evidence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (from, to) = self.window;
        write!(f, "stall witness, {}–{}: ", time_of_day(from), time_of_day(to))?;
        match self.lateness {
            Some(l) if l.count > 0 => write!(
                f,
                "core {} woke {} time(s) late, {:.1} ms in all (longest {:.1} ms)",
                l.core, l.count, l.ms, l.longest_ms
            )?,
            _ => write!(f, "no late wake-up")?,
        }
        match self.steal {
            Some(s) => write!(f, "; steal {:.0} ms on cpu {}", s.ms, s.cpu)?,
            None => write!(f, "; steal unknown")?,
        }
        if let Some(o) = self.outranked {
            let policy = if o.policy == 1 { "SCHED_FIFO" } else { "SCHED_RR" };
            write!(
                f,
                "; no evidence: pid {} thread {} ({}) ran at {policy} {} above the witness (seen {})",
                o.pid,
                o.tid,
                o.name(),
                o.priority,
                time_of_day(o.at_ns)
            )?;
        }
        Ok(())
    }
}

/// `hh:mm:ss.mmm` (UTC) of a CLOCK_MONOTONIC time, for matching the log lines of the processes under test.
pub fn time_of_day(monotonic_ns: u64) -> String {
    let now_mono = crate::monotonic_ns() as f64 * 1e-9;
    let now_wall = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
    let tod = (now_wall - now_mono + monotonic_ns as f64 * 1e-9).rem_euclid(86_400.0);
    let ms = (tod * 1e3).round() as u64;
    format!("{:02}:{:02}:{:02}.{:03}", ms / 3_600_000, ms / 60_000 % 60, ms / 1000 % 60, ms % 1000)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(late_ms: f64, longest_ms: f64, steal_ms: f64) -> Evidence {
        let lateness = Some(LatenessSeen { core: 0, ms: late_ms, longest_ms, count: 1 });
        Evidence {
            window: (0, 2_000_000_000),
            lateness,
            steal: Some(StealSeen { cpu: 1, ms: steal_ms }),
            outranked: None,
        }
    }

    #[test]
    fn a_window_is_calm_with_the_host_s_ordinary_noise_and_not_with_a_long_or_large_stall() {
        assert!(seen(30.0, 4.0, 40.0).is_calm(), "1–4 % of a 2 s window in short stretches: ordinary");
        assert!(!seen(30.0, 6.0, 40.0).is_calm(), "one stretch longer than a few robot cycles");
        assert!(!seen(60.0, 4.0, 10.0).is_calm(), "late too long in all");
        assert!(!seen(10.0, 2.0, 60.0).is_calm(), "too much stolen");
    }
}
