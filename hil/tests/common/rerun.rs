//! When a HIL test may blame the machine: only on the stall witness's evidence (crate stall-witness, which shares
//! no code with marsd or the HAL) for that very failure's time, and at most once per test
//! ([`at_most_one_rerun`]). The processes under test say only *when* they failed (a trip's log line, a late
//! chunk's times); whether the machine stalled then is the witness's to say.

use std::path::Path;

#[allow(unused_imports)] // each test binary uses a part
pub use stall_witness::{Attempt, Excuse, at_most_one_rerun, report_machine_time, witness};

use super::{Proc, Recorded, u64_at};

/// A stall explains a trip from this long before it (the slowest timing detector, 20 ms, plus marsd's 2 ms
/// supervisor poll that logs the trip, with room for a stalled logger) ...
pub const BEFORE_TRIP_NS: u64 = 100_000_000;
/// ... to this long after its logged time (the line is written up to ~2 ms after the trip).
pub const AFTER_TRIP_NS: u64 = 10_000_000;
/// ... if it lasted this long: three quarters of the watchdog's 20 ms budgets.
pub const MIN_TRIP_STALL_MS: f64 = 15.0;

/// Trips that a stall of the machine can cause: timing checks, not logic (the watchdog's words in summary.json).
pub fn is_timing_trip(trip: &str) -> bool {
    ["no usable state frame", "servo ticks overran", "the HAL stopped following this controller (CommandTimeout)"]
        .iter()
        .any(|t| trip.contains(t))
        || is_inference_trip(trip)
}

/// The policy's inference did not fit one ODE step in its deadline: timing, on the policy's core.
fn is_inference_trip(trip: &str) -> bool {
    trip.contains("inference could not fit one ODE step")
}

/// marsd tripped with `trip` at `trip_ns` (CLOCK_MONOTONIC): a timing trip with the witness's stall around it on
/// the core of the loop that tripped: the policy's for an inference over its deadline, otherwise the servo's
/// (which the tests' HAL shares: `spawn_hal`).
pub fn trip_excuse(trip: &str, trip_ns: u64) -> Option<Excuse> {
    if !is_timing_trip(trip) {
        return None;
    }
    let core = if is_inference_trip(trip) { super::policy_core() } else { super::servo_core() };
    let (failure, from) = (format!("marsd tripped ({trip})"), trip_ns.saturating_sub(BEFORE_TRIP_NS));
    witness().excuse_on(core, failure, from, trip_ns + AFTER_TRIP_NS, MIN_TRIP_STALL_MS)
}

/// The trip of a marsd whose summary is `s`, at the time of its "watchdog trip" log line.
pub fn marsd_trip_excuse(s: &serde_json::Value, marsd: &Proc) -> Option<Excuse> {
    let trip = s["trip"].as_str()?;
    let log = marsd.stderr_text();
    let line = log.lines().find(|l| l.contains("watchdog trip"))?;
    trip_excuse(trip, stall_witness::log_time::monotonic_of_line(line)?)
}

/// The trip of a `mars-hil demo` (or replay) whose output folder is `out`: its trip.json names the trip and when.
pub fn demo_trip_excuse(out: &Path) -> Option<Excuse> {
    let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("trip.json")).ok()?).ok()?;
    trip_excuse(t["trip"].as_str()?, t["evidence"]["trip_ns"].as_u64()?)
}

/// Late chunks of a run with no trip: each one needs the witness's stall on the policy's core, while it was
/// computed, at least as long as it was late. The excuse of the latest chunk.
pub fn late_chunks_excuse(s: &serde_json::Value) -> Option<Excuse> {
    let late = u64_at(s, "/deadline_misses/late_chunks");
    let times = s["deadline_misses"]["late_chunk_times"].as_array()?;
    if late == 0 || times.len() as u64 != late {
        return None;
    }
    let mut worst: Option<Excuse> = None;
    for t in times {
        let (woke, need, ready) = (t["woke_ns"].as_u64()?, t["need_ns"].as_u64()?, t["ready_ns"].as_u64()?);
        let late_ms = ready.saturating_sub(need) as f64 * 1e-6;
        let e =
            witness().excuse_on(super::policy_core(), format!("a chunk {late_ms:.1} ms late"), woke, ready, late_ms)?;
        if worst.as_ref().is_none_or(|w| w.stalled_ms() < e.stalled_ms()) {
            worst = Some(e);
        }
    }
    worst
}

/// The excuse for a marsd run that failed (summary `s`): a timing trip with the witness's stall around it; or,
/// without a trip, late chunks each with a stall as long ([`late_chunks_excuse`]) — provided the servo missed no
/// more than `missed_limit` periods beyond those the witness saw the machine take ([`lost_servo_periods`]).
pub fn run_excuse(s: &serde_json::Value, marsd: &Proc, r: &Recorded, missed_limit: u64) -> Option<Excuse> {
    if s["trip"].is_string() {
        return marsd_trip_excuse(s, marsd);
    }
    let missed = u64_at(s, "/deadline_misses/servo_missed_periods");
    if missed > missed_limit.saturating_add(lost_servo_periods(r)) {
        return None;
    }
    late_chunks_excuse(s)
}

/// Periods of the recorded run the witness saw the machine take from the servo's core (configs/marsd.toml's
/// `servo.core`): periods the servo could not have run in, whatever its code.
pub fn lost_servo_periods(r: &Recorded) -> u64 {
    let (Some(first), Some(last)) = (r.states.first(), r.states.last()) else { return 0 };
    let period_ns = (r.period_ms() * 1e6) as u64;
    witness().lost_periods(super::servo_core(), first.0.timestamp_ns, last.0.timestamp_ns, period_ns)
}

/// What the witness saw over a recorded run, for the test's log.
pub fn witness_account(r: &Recorded) -> String {
    let (Some(first), Some(last)) = (r.states.first(), r.states.last()) else { return "no frames recorded".into() };
    match witness().seen_in(first.0.timestamp_ns, last.0.timestamp_ns) {
        Some(e) => format!("over the run, {e}"),
        None => "the stall witness did not watch this run".into(),
    }
}

/// A reaction time (ms) against README's figure for it, printing both: within [`CLAIM_MARGIN`] × the figure; beyond
/// it, excused only by the witness's stall in `window` (CLOCK_MONOTONIC ns) at least as long as the excess, else a
/// failure.
pub fn near_claim(what: &str, measured_ms: f64, claim_ms: f64, window: (u64, u64)) -> Attempt {
    let bound = CLAIM_MARGIN * claim_ms;
    eprintln!("{what}: {measured_ms:.1} ms (README: {claim_ms:.0} ms; bound {bound:.0} ms)");
    witness().within_or_excused(what, measured_ms, bound, window.0, window.1)
}

/// README's reaction times are bounded by this multiple of the figure README states for each.
pub const CLAIM_MARGIN: f64 = 1.5;
