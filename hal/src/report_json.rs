//! The HAL's exit report as JSON (`--report-json`), for programs that compare runs (`mars-hil bench-backends`)
//! rather than read the printed report.

use hdrhistogram::Histogram;
use serde_json::{Value, json};

use crate::runner::{Ended, Report};

fn quantiles(h: &Histogram<u64>) -> Value {
    json!({
        "count": h.len(),
        "p50": h.value_at_quantile(0.5),
        "p99": h.value_at_quantile(0.99),
        "p999": h.value_at_quantile(0.999),
        "max": h.max(),
    })
}

/// The report's numbers: timing quantiles (µs), counters, and the robot's side when a robot paced the loop.
pub fn to_json(r: &Report) -> Value {
    let ended = match r.ended {
        Ended::Duration => "duration".to_string(),
        Ended::Signal => "signal".to_string(),
        Ended::BackendFailed(e) => format!("backend failed: {e}"),
        Ended::ConnectionLost => "connection lost".to_string(),
        Ended::NotTakenOver(why) => format!("not taken over: {why}"),
    };
    let robot = r.robot.as_ref().map(|rb| rb.to_json());
    json!({
        "ticks": r.ticks,
        "ended": ended,
        "paced_by_robot": r.paced_by_robot,
        // Paced by the robot: how much later than one period after the last state the next came; otherwise the
        // timer's wake-up lateness.
        "late_us": quantiles(&r.wake_late_us),
        // Paced by the robot: robot state in → command out; otherwise the tick's work (read → apply → publish).
        "work_us": quantiles(&r.work_us),
        "overruns": r.overruns,
        // Ticks longer than the period, by why (see `mars_rt::overlong`).
        "period_us": r.period.as_micros() as u64,
        "overlong_ticks": r.overlong,
        "longest_overlong_tick": r.longest,
        "computing_ticks": r.computing_ticks,
        "rejected": r.rejected,
        "clamped": r.clamped,
        "late_commands": r.late_commands,
        "timing_steps": r.timing_steps,
        "position_guard_hits": r.position_guard_hits,
        "infeasible_steps": r.infeasible_steps,
        "errors": r.errors.total(),
        "loop_allocations": r.allocations_after_warmup.map(|(c, _)| c.system),
        "loop_allocations_while_robot_stopped": r.allocations_while_robot_stopped.system,
        "robot": robot,
    })
}

/// Writes [`to_json`] to `path` (through a temporary file, so a reader never sees half of it).
pub fn write(r: &Report, path: &std::path::Path) -> anyhow::Result<()> {
    use anyhow::Context as _;
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string_pretty(&to_json(r))?)
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}
