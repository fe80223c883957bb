//! Evidence that a run was stopped by a stall of the machine rather than by the code under test, tied to the
//! very failure it explains: a gap in the HAL's state frames, or CPU time the hypervisor took (/proc/stat
//! `steal`), in a short window around the moment marsd tripped.
//!
//! The HAL is the highest-priority process of a rig (SCHED_FIFO 85 on the servo core): if it published no
//! frame for 15 ms, nothing of the rig ran, so marsd's timing trip in that window was the machine's, not
//! marsd's. A gap elsewhere in the run, or steal at another time, explains nothing and is not evidence.
//! Used by `mars-hil demo` to say why a run stopped. (The tests decide whether a failure may be rerun on the
//! evidence of `stall-witness` alone, which shares no code with marsd or the HAL: this is the product's own view.)

use std::fmt;

use serde::Serialize;

/// A gap in the HAL's frames at least this long counts as a stall (the watchdog's budget is 20 ms).
pub const MIN_GAP_MS: f64 = 15.0;
/// Steal in the window at least this large (ms, summed over the CPUs) counts as a stall: the hypervisor took as
/// much CPU time as the frame-gap threshold. (The counter's resolution is 10 ms, one tick of 1/USER_HZ.)
pub const MIN_STEAL_MS: f64 = MIN_GAP_MS;
/// A gap in the HAL's frames of at least this many of its periods is a pause (shorter ones are jitter). Pauses that
/// add up to [`MIN_GAP_MS`] in a trip's window count as one gap that long: the HAL froze as long, only in pieces.
pub const PAUSE_PERIODS: f64 = 1.5;
/// How long before the trip a stall still explains it: the slowest timing detector (stale state or the HAL's
/// command timeout, 20 ms each) plus the 2 ms in which marsd logs a trip, with room for a stalled logger.
pub const BEFORE_TRIP_MS: f64 = 100.0;
/// How long after the logged trip time a stall still counts (the log line is written up to ~2 ms after the
/// trip, and a whole-machine stall may end, and be seen, just after it).
pub const AFTER_TRIP_MS: f64 = 10.0;

/// Trips that a stall of the machine causes: timing checks, not logic.
pub fn is_timing_trip(trip: &str) -> bool {
    ["no usable state frame", "servo ticks overran", "the HAL stopped following this controller (CommandTimeout)"]
        .iter()
        .any(|t| trip.contains(t))
}

/// A stretch in which the HAL published nothing: between two consecutive frames (seq and seq + 1), by the
/// HAL's own stamps (CLOCK_MONOTONIC ns).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrameGap {
    /// The seq of the frame after the gap.
    pub seq: u64,
    pub start_ns: u64,
    pub end_ns: u64,
}

impl FrameGap {
    pub fn ms(&self) -> f64 {
        self.end_ns.saturating_sub(self.start_ns) as f64 * 1e-6
    }
}

/// Finds gaps of at least `min_ms` in a stream of the HAL's (seq, stamp), online and without allocation.
/// Frames the reader missed (a seq jump) give no gap: who did not run then is unknown.
#[derive(Debug, Default, Clone, Copy)]
pub struct GapFinder {
    last: Option<(u64, u64)>,
}

impl GapFinder {
    /// Feeds the next frame; returns the gap it ends, if ≥ `min_ms`.
    pub fn push(&mut self, seq: u64, stamp_ns: u64, min_ms: f64) -> Option<FrameGap> {
        let prev = self.last.replace((seq, stamp_ns))?;
        let gap = FrameGap { seq, start_ns: prev.1, end_ns: stamp_ns };
        (seq == prev.0 + 1 && gap.ms() >= min_ms).then_some(gap)
    }
}

/// All gaps of at least `min_ms` in (seq, stamp) frames.
pub fn frame_gaps(frames: impl IntoIterator<Item = (u64, u64)>, min_ms: f64) -> Vec<FrameGap> {
    let mut finder = GapFinder::default();
    frames.into_iter().filter_map(|(seq, t)| finder.push(seq, t, min_ms)).collect()
}

/// The hypervisor's steal counter (ms, all CPUs) at a moment (CLOCK_MONOTONIC ns).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StealSample {
    pub at_ns: u64,
    pub steal_ms: f64,
}

/// CPU time the hypervisor took from this VM since boot, summed over its CPUs (ms; /proc/stat `steal`, in
/// clock ticks of 1/USER_HZ). `None` where /proc/stat has no steal column.
pub fn steal_ms() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    steal_ms_of(&stat, clock_ticks_per_s())
}

/// The `steal` column of /proc/stat's `cpu` line, in ms at `hz` ticks per second.
pub fn steal_ms_of(proc_stat: &str, hz: f64) -> Option<f64> {
    let line = proc_stat.lines().find(|l| l.starts_with("cpu "))?;
    let ticks: f64 = line.split_whitespace().nth(8)?.parse().ok()?;
    Some(ticks * 1e3 / hz.max(1.0))
}

fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    unsafe { libc::sysconf(libc::_SC_CLK_TCK) as f64 }
}

/// Steal that grew between the last sample at or before `from_ns` and the first at or after `to_ns` (ms);
/// `None` if the samples do not bracket the window.
pub fn steal_between(samples: &[StealSample], from_ns: u64, to_ns: u64) -> Option<f64> {
    let before = samples.iter().rev().find(|s| s.at_ns <= from_ns)?;
    let after = samples.iter().find(|s| s.at_ns >= to_ns)?;
    Some(after.steal_ms - before.steal_ms)
}

/// What the machine did around a trip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Evidence {
    /// When marsd tripped (CLOCK_MONOTONIC ns).
    pub trip_ns: u64,
    /// The longest HAL frame gap ≥ [`MIN_GAP_MS`] overlapping the window around the trip.
    pub gap: Option<FrameGap>,
    /// Time in the window in which the HAL — the rig's highest-priority thread — published nothing beyond its
    /// period, summed over its pauses (ms).
    pub hal_frozen_ms: f64,
    /// Steal that grew in the window (ms), where the samples bracket it.
    pub steal_ms: Option<f64>,
}

impl Evidence {
    /// Whether the machine stalled around the trip: a HAL frame gap of [`MIN_GAP_MS`], or the HAL frozen that
    /// long in pieces, or at least [`MIN_STEAL_MS`] of stolen CPU time, in the window.
    pub fn is_stall(&self) -> bool {
        self.gap.is_some() || self.hal_frozen_ms >= MIN_GAP_MS || self.steal_ms.is_some_and(|s| s >= MIN_STEAL_MS)
    }
}

impl fmt::Display for Evidence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.gap {
            Some(g) => write!(
                f,
                "the HAL published no frame for {:.1} ms (before its frame {}, ending {:+.1} ms from the trip)",
                g.ms(),
                g.seq,
                (g.end_ns as f64 - self.trip_ns as f64) * 1e-6
            )?,
            None => write!(f, "no HAL frame gap ≥ {MIN_GAP_MS} ms")?,
        }
        write!(f, ", the HAL frozen {:.1} ms in all", self.hal_frozen_ms)?;
        match self.steal_ms {
            Some(s) => write!(f, ", VM steal {s:.0} ms"),
            None => write!(f, ", VM steal unknown"),
        }?;
        write!(f, " in the {BEFORE_TRIP_MS} ms before the trip (to {AFTER_TRIP_MS} ms after)")
    }
}

/// The evidence in the window [trip − [`BEFORE_TRIP_MS`], trip + [`AFTER_TRIP_MS`]]: the longest of `gaps` that
/// overlaps it, the HAL's frozen time in it, and the steal that grew across it. `gaps`: the HAL's pauses (frame
/// gaps of at least [`PAUSE_PERIODS`] of its period `period_ms`).
pub fn around_trip(trip_ns: u64, gaps: &[FrameGap], period_ms: f64, steal: &[StealSample]) -> Evidence {
    let from = trip_ns.saturating_sub((BEFORE_TRIP_MS * 1e6) as u64);
    let to = trip_ns + (AFTER_TRIP_MS * 1e6) as u64;
    let gap = gaps
        .iter()
        .filter(|g| g.ms() >= MIN_GAP_MS && g.start_ns <= to && g.end_ns >= from)
        .max_by(|a, b| a.ms().total_cmp(&b.ms()))
        .copied();
    Evidence {
        trip_ns,
        gap,
        hal_frozen_ms: frozen_ms(gaps, from, to, period_ms),
        steal_ms: steal_between(steal, from, to),
    }
}

/// The HAL's time without a frame beyond its period, within from..to (ms, summed over `gaps`).
fn frozen_ms(gaps: &[FrameGap], from_ns: u64, to_ns: u64, period_ms: f64) -> f64 {
    gaps.iter()
        .map(|g| {
            let overlap = g.end_ns.min(to_ns).saturating_sub(g.start_ns.max(from_ns)) as f64 * 1e-6;
            (overlap.min(g.ms() - period_ms)).max(0.0)
        })
        .sum()
}

/// Seconds since UTC midnight of a tracing log line's timestamp (`2026-11-21T11:51:57.722514Z ...`).
pub fn log_time_of_day(line: &str) -> Option<f64> {
    let t = line.get(11..26)?;
    if line.get(10..11)? != "T" {
        return None;
    }
    let (h, m, s) =
        (t.get(0..2)?.parse::<f64>().ok()?, t.get(3..5)?.parse::<f64>().ok()?, t.get(6..)?.parse::<f64>().ok()?);
    Some(h * 3600.0 + m * 60.0 + s)
}

/// Seconds since UTC midnight now (wall clock, the clock of the log lines).
pub fn now_time_of_day() -> f64 {
    let d = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    (d.as_secs() % 86_400) as f64 + f64::from(d.subsec_nanos()) * 1e-9
}

/// A wall-clock time of day (s), at most 12 h ago, on CLOCK_MONOTONIC (ns), given both clocks' `now`.
pub fn time_of_day_to_monotonic(tod: f64, now_tod: f64, now_ns: u64) -> u64 {
    let ago = (now_tod - tod).rem_euclid(86_400.0);
    let ago = if ago > 43_200.0 { ago - 86_400.0 } else { ago };
    (now_ns as f64 - ago * 1e9).max(0.0) as u64
}

/// When marsd logged its watchdog trip, on CLOCK_MONOTONIC, from its log text (stderr). summary.json has no
/// trip time; the line is written by marsd's 2 ms supervisor poll, so it lags the trip by a few ms at most.
pub fn trip_time_from_log(log: &str) -> Option<u64> {
    let line = log.lines().find(|l| l.contains("watchdog trip"))?;
    let tod = log_time_of_day(line)?;
    Some(time_of_day_to_monotonic(tod, now_time_of_day(), mars_ipc::clock::monotonic_ns()))
}

/// What `mars-hil demo` says after marsd tripped with `trip` (logged at `trip_clock`), given the evidence
/// around it: `None` for a trip that is not a timing check (it says enough itself).
pub fn demo_message(trip: &str, trip_clock: &str, e: &Evidence) -> Option<String> {
    if !is_timing_trip(trip) {
        return None;
    }
    Some(if e.is_stall() {
        format!(
            "the run was stopped by a stall of this machine at {trip_clock}: {e}. The watchdog did its job (a real \
             arm would have been braked and held); see `marsd doctor` for what this machine can do and how to \
             improve it"
        )
    } else {
        format!(
            "marsd tripped on a timing check at {trip_clock} ({trip}) with no stall of this machine around it \
             ({e}): look at marsd's log and the report"
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn gap(start_ms: u64, end_ms: u64) -> FrameGap {
        FrameGap { seq: 7, start_ns: start_ms * MS, end_ns: end_ms * MS }
    }

    #[test]
    fn a_gap_counts_only_between_consecutive_frames() {
        let frames = [(1, 0), (2, MS), (3, 30 * MS), (10, 60 * MS), (11, 61 * MS)];
        let gaps = frame_gaps(frames, MIN_GAP_MS);
        assert_eq!(gaps, vec![FrameGap { seq: 3, start_ns: MS, end_ns: 30 * MS }]);
    }

    #[test]
    fn only_a_gap_overlapping_the_trip_window_is_evidence() {
        let trip = 10_000 * MS;
        // A 40 ms gap 5 s earlier: the largest of the run, and no evidence for this trip.
        let far = gap(5_000, 5_040);
        let e = around_trip(trip, &[far], 1.0, &[]);
        assert_eq!(e.gap, None);
        assert!(!e.is_stall());
        // A 25 ms gap ending 3 ms before the trip (stale state) or running past it (a stalled machine).
        for near in [gap(9_972, 9_997), gap(9_990, 10_015)] {
            let e = around_trip(trip, &[far, near], 1.0, &[]);
            assert_eq!(e.gap, Some(near), "{near:?}");
            assert!(e.is_stall());
        }
        // Too short, or after the window.
        assert_eq!(around_trip(trip, &[gap(9_990, 9_999)], 1.0, &[]).gap, None);
        assert_eq!(around_trip(trip, &[gap(10_011, 10_040)], 1.0, &[]).gap, None);
    }

    #[test]
    fn pauses_that_add_up_in_the_window_count_as_one_gap() {
        let trip = 10_000 * MS;
        // Eight 3 ms pauses (2 ms beyond the period each) in the 100 ms before the trip: 16 ms frozen, no single gap.
        let pauses: Vec<FrameGap> = (0..8).map(|i| gap(9_910 + 10 * i, 9_913 + 10 * i)).collect();
        let e = around_trip(trip, &pauses, 1.0, &[]);
        assert_eq!(e.gap, None);
        assert!((e.hal_frozen_ms - 16.0).abs() < 1e-9, "{e:?}");
        assert!(e.is_stall(), "{e}");
        assert!(e.to_string().contains("the HAL frozen 16.0 ms in all"), "{e}");
        // Seven are 14 ms: less than one gap the threshold long. The same pauses far before the trip count nothing.
        assert!(!around_trip(trip, &pauses[..7], 1.0, &[]).is_stall());
        let early: Vec<FrameGap> = (0..8).map(|i| gap(5_000 + 10 * i, 5_003 + 10 * i)).collect();
        assert_eq!(around_trip(trip, &early, 1.0, &[]).hal_frozen_ms, 0.0);
    }

    #[test]
    fn steal_counts_only_when_it_grew_across_the_window() {
        let trip = 10_000 * MS;
        let s = |at_ms: u64, steal: f64| StealSample { at_ns: at_ms * MS, steal_ms: steal };
        // Steal grew by 50 ms at 5 s, then stayed: nothing in the window.
        let flat = [s(4_000, 100.0), s(6_000, 150.0), s(9_880, 150.0), s(10_020, 150.0)];
        let e = around_trip(trip, &[], 1.0, &flat);
        assert_eq!(e.steal_ms, Some(0.0));
        assert!(!e.is_stall());
        let grew = [s(9_880, 150.0), s(9_950, 160.0), s(10_020, 180.0)];
        let e = around_trip(trip, &[], 1.0, &grew);
        assert_eq!(e.steal_ms, Some(30.0));
        assert!(e.is_stall());
        // One tick of steal (10 ms) is less than a stall that could explain a 20 ms timing trip.
        let tick = [s(9_880, 150.0), s(10_020, 160.0)];
        assert_eq!(around_trip(trip, &[], 1.0, &tick).steal_ms, Some(10.0));
        assert!(!around_trip(trip, &[], 1.0, &tick).is_stall());
        // Samples that end before the window closes bracket nothing.
        assert_eq!(around_trip(trip, &[], 1.0, &grew[..2]).steal_ms, None);
    }

    #[test]
    fn the_demo_names_a_stall_only_with_evidence_around_the_trip() {
        let trip = "the HAL stopped following this controller (CommandTimeout)";
        let stalled = around_trip(10_000 * MS, &[gap(9_975, 10_012)], 1.0, &[]);
        let m = demo_message(trip, "11:51:57.722", &stalled).unwrap();
        assert!(
            m.starts_with(
                "the run was stopped by a stall of this machine at 11:51:57.722: the HAL published no \
                 frame for 37.0 ms"
            ) && m.contains("see `marsd doctor`"),
            "{m}"
        );
        let calm = around_trip(10_000 * MS, &[gap(1_000, 1_040)], 1.0, &[]);
        let m = demo_message(trip, "11:51:57.722", &calm).unwrap();
        assert!(m.starts_with("marsd tripped on a timing check") && m.contains("no HAL frame gap"), "{m}");
        assert_eq!(demo_message("the HAL process died or left (iceoryx2 liveness)", "x", &stalled), None);
    }

    #[test]
    fn timing_trips_include_the_hals_command_timeout() {
        assert!(is_timing_trip("no usable state frame from the HAL within the allowed gap"));
        assert!(is_timing_trip("servo ticks overran their period too many times in a row"));
        assert!(is_timing_trip("the HAL stopped following this controller (CommandTimeout)"));
        assert!(!is_timing_trip("the HAL process died or left (iceoryx2 liveness)"));
        assert!(!is_timing_trip("the HAL stopped following this controller (SafetyFault)"));
    }

    #[test]
    fn log_times_map_onto_the_monotonic_clock() {
        let line = "2026-11-21T11:51:57.722514Z ERROR marsd: watchdog trip";
        let tod = log_time_of_day(line).unwrap();
        assert!((tod - (11.0 * 3600.0 + 51.0 * 60.0 + 57.722514)).abs() < 1e-9);
        assert_eq!(log_time_of_day("no timestamp here at all, none"), None);
        // 1.5 s ago, and across midnight.
        assert_eq!(time_of_day_to_monotonic(100.0, 101.5, 10_000 * MS), 8_500 * MS);
        assert_eq!(time_of_day_to_monotonic(86_399.0, 1.0, 10_000 * MS), 8_000 * MS);
        let stat = "cpu  1 2 3 4 5 6 7 250 0 0\ncpu0 1 2 3 4 5 6 7 250 0 0\n";
        assert_eq!(steal_ms_of(stat, 100.0), Some(2_500.0));
    }
}
