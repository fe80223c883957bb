//! `mars-hil delay-sweep`: the same episodes (seeds) of a pick checkpoint at each delay and each way to continue a
//! late chunk ([`super::delay`]), printed as one table: success (Wilson interval) and boundary jerk (t interval over
//! episodes), and each against drop-late at the same delay as a paired difference over the seeds (t interval), with
//! where that interval lies against 0.

use std::path::Path;

use mars_tasks::stats::{Estimate, mean_over_seeds, wilson};

use super::cli::load_task;
use super::delay::{Continuity, Delay};
use super::eval::{EvalReport, evaluate_delayed};

/// One row of the table.
pub struct SweepRow {
    pub delay: Delay,
    pub report: EvalReport,
}

/// Every delay in `delays` (policy periods) × every continuity, `n` episodes each from `seed`.
pub fn sweep(
    checkpoint: &Path,
    task: &Path,
    profile: &Path,
    delays: &[usize],
    n: usize,
    seed: u64,
) -> anyhow::Result<Vec<SweepRow>> {
    let (task, profile) = load_task(task, profile)?;
    let mut rows = Vec::new();
    for &periods in delays {
        for continuity in Continuity::ALL {
            let delay = Delay { periods, continuity };
            let report = evaluate_delayed(checkpoint, &task, &profile, n, seed, delay)?;
            rows.push(SweepRow { delay, report });
        }
    }
    Ok(rows)
}

fn successes(r: &EvalReport) -> Vec<f64> {
    r.episodes.iter().map(|e| f64::from(u8::from(e.success))).collect()
}

fn jerks(r: &EvalReport) -> Vec<f64> {
    r.episodes.iter().map(|e| e.smoothness.boundary_jerk).collect()
}

/// Per seed, `a − b` (both over the same seeds in the same order).
fn paired(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(a, b)| a - b).collect()
}

fn est(values: &[f64], scale: f64) -> String {
    mean_over_seeds(values).map_or_else(|| "-".into(), |e: Estimate| format!("{:.1}", e.scaled(scale)))
}

/// The success rate (%) with its Wilson interval.
fn success(r: &EvalReport) -> String {
    wilson(r.successes, r.n).map_or_else(|| "-".into(), |e| format!("{:.1}", e.scaled(100.0)))
}

/// "lower", "higher" or "undecided": where the paired difference's interval lies against 0; "identical" when every
/// seed's difference is 0.
fn direction(diff: &[f64]) -> &'static str {
    if diff.iter().all(|d| *d == 0.0) {
        return "identical";
    }
    match mean_over_seeds(diff) {
        Some(e) if e.hi < 0.0 => "lower",
        Some(e) if e.lo > 0.0 => "higher",
        _ => "undecided",
    }
}

/// The table, as printed.
pub fn table(rows: &[SweepRow], rate_hz: f64) -> String {
    let mut out = String::from(
        "| delay | round trip | continuity | success % | boundary jerk rad/s³ | inner jerk rad/s³ | actions out of limits | Δ success vs drop-late (pts) | Δ boundary jerk vs drop-late |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for row in rows {
        let base =
            rows.iter().find(|r| r.delay.periods == row.delay.periods && r.delay.continuity == Continuity::DropLate);
        let inner: Vec<f64> = row.report.episodes.iter().map(|e| e.smoothness.inner_jerk).collect();
        let (ds, dj) = match base.filter(|b| b.delay != row.delay) {
            Some(b) => {
                let s = paired(&successes(&row.report), &successes(&b.report));
                let j = paired(&jerks(&row.report), &jerks(&b.report));
                (format!("{} {}", est(&s, 100.0), direction(&s)), format!("{} {}", est(&j, 1.0), direction(&j)))
            }
            None => ("—".into(), "—".into()),
        };
        out += &format!(
            "| {} | {:.0} ms | {} | {} | {} | {} | {} | {ds} | {dj} |\n",
            row.delay.periods,
            row.delay.periods as f64 * 1e3 / rate_hz,
            row.delay.continuity.name(),
            success(&row.report),
            est(&jerks(&row.report), 1.0),
            est(&inner, 1.0),
            row.report.limit_violations,
        );
    }
    out
}
