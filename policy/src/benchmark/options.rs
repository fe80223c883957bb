//! What one benchmark run does: how many demos, epochs and rollouts, which policies, and the knobs of the
//! comparisons built on it (`mars family`, `mars family-diff`).

use crate::config::PolicyKind;

#[derive(Clone)]
pub struct BenchmarkOptions {
    pub demos: usize,
    pub epochs: Option<usize>,
    pub rollouts: usize,
    pub seed: u64,
    pub exec_horizon: usize,
    pub policies: Vec<PolicyKind>,
    /// Policies trained at the same time.
    pub jobs: usize,
    /// Keep each policy already trained under `out` with this very configuration (and the same demos) instead of
    /// training it again; it is still evaluated. Long runs (`mars family`) then continue where they stopped.
    pub resume: bool,
    /// Condition the velocity field and the scheduler on the history (`model.velocity_uses_history`,
    /// `model.scheduler_uses_history`) whatever the config says: one side of the comparison that settles it.
    pub history_conditioning: bool,
    /// Evaluate MARS with this `model.k_full_w` instead of its checkpoint's (1: the paper's K(w)); training is
    /// unchanged, so `--resume` compares the two K(w) rules on the very same checkpoints. Written to
    /// `eval_kfull<w>.json` beside the checkpoint's own `eval.json`.
    pub k_full_w: Option<f32>,
    /// Other benchmarks run at the same time (`mars family` runs its layouts × seeds side by side), so this one's
    /// evaluation is not alone on the machine: its latencies say so.
    pub side_by_side: bool,
}
