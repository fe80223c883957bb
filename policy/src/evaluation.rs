//! A checkpoint's nav2d evaluation as every command runs it: the scores from many rollouts batched through the
//! model, with their 95 % bootstrap intervals against the layout's demo shares, and the inference latency from
//! a few rollouts one call at a time (a batched call's time is not one inference's).

use crate::inference::MarsPolicy;
use mars_tasks::nav2d::{EvalIntervals, EvalReport, Layout, evaluate, evaluate_batched};

/// Rollouts run side by side per model call.
pub const DEFAULT_BATCH: usize = 64;
/// Rollouts run one call at a time for the latency percentiles.
pub const LATENCY_ROLLOUTS: usize = 10;

pub struct Evaluation {
    /// Scores of the batched rollouts; latency from the timed ones.
    pub report: EvalReport,
    pub intervals: EvalIntervals,
}

/// `rollouts` rollouts with seeds `seed + i` in batches of `batch`, then [`LATENCY_ROLLOUTS`] timed ones.
pub fn evaluate_policy(
    policy: &mut MarsPolicy,
    layout: &Layout,
    rollouts: usize,
    seed: u64,
    exec_horizon: usize,
    batch: usize,
) -> anyhow::Result<Evaluation> {
    let mut report = evaluate_batched(layout, policy, rollouts, seed, exec_horizon, batch)?;
    let timed = evaluate(layout, policy, LATENCY_ROLLOUTS.min(rollouts), seed, exec_horizon)?;
    (report.latency_p50_ms, report.latency_p99_ms) = (timed.latency_p50_ms, timed.latency_p99_ms);
    let demo_shares: Vec<f64> = layout.demo_shares().iter().map(|&s| f64::from(s)).collect();
    let intervals = report.intervals(&demo_shares, seed);
    Ok(Evaluation { report, intervals })
}
