//! `mars-hil push-t-train` and `push-t-eval`: Push-T policies trained on the expert's demos (the same trainer as
//! `mars train`; the demos are made in process from their seed, as the camera images would make a demo file of
//! hundreds of MB) and rolled out in process against the world the HIL scene runs, with the camera the policy
//! sees there.

use std::path::Path;
use std::time::Instant;

use mars_policy::config::{PolicyConfig, PolicyKind};
use mars_policy::inference::MarsPolicy;
use mars_profile::Profile;
use mars_tasks::push_t::episode::{Episode, Observer, Score, expert_demos, run_episode, score};
use serde::Serialize;

use super::PushTHil;

/// Seeds of the demos' episodes start here; evaluation uses other seeds (`--seed`, default 1000).
pub const DEMO_SEED: u64 = 0;

/// Expert demos (`n`, from `seed`) and a policy of `kind` trained on them with `config`; saved to `out`.
#[allow(clippy::too_many_arguments)] // the command line's options, one each
pub fn train(
    config: &Path,
    task: &Path,
    profile: &Path,
    kind: PolicyKind,
    n: usize,
    seed: u64,
    epochs: Option<usize>,
    out: &Path,
) -> anyhow::Result<()> {
    let task = PushTHil::load(task, &Profile::load(profile)?)?;
    let mut cfg = PolicyConfig::load(config)?;
    cfg.kind = kind;
    cfg.train.epochs = epochs.unwrap_or(cfg.train.epochs);
    cfg.validate()?;
    anyhow::ensure!(
        cfg.model.obs_dim == task.obs_dim() && cfg.model.action_dim == task.action_dim(),
        "{}: model.obs_dim {} / action_dim {}, but the task's camera and (x, y) make {} / {}",
        config.display(),
        cfg.model.obs_dim,
        cfg.model.action_dim,
        task.obs_dim(),
        task.action_dim()
    );
    let started = Instant::now();
    let demos = expert_demos(&task.cfg.world, n, seed, task.observe());
    let by_route = [0, 1].map(|m| demos.iter().filter(|d| d.mode == Some(m)).count());
    let steps: usize = demos.iter().map(|d| d.len()).sum();
    println!(
        "Push-T: {} expert demos (upper {}, lower {}), {steps} steps, made in {:.1} s",
        demos.len(),
        by_route[0],
        by_route[1],
        started.elapsed().as_secs_f64()
    );
    mars_policy::cli::train_on(&cfg, &demos, out, None)?;
    Ok(())
}

/// A checkpoint's closed-loop episodes in process.
#[derive(Debug, Clone, Serialize)]
pub struct PushTEval {
    pub checkpoint: String,
    pub kind: String,
    pub episodes: usize,
    pub successes: usize,
    /// Successes by route: upper, lower.
    pub by_route: [usize; 2],
    pub gamma: f32,
    pub mean_k: f32,
    /// One policy call through candle, this process, one thread (ms).
    pub call_p50_ms: f64,
    pub call_p99_ms: f64,
    /// The block's final distance (m) and angle (rad) to the goal, mean over episodes.
    pub final_error: [f32; 2],
}

pub fn eval(
    checkpoint_dir: &Path,
    task: &Path,
    profile: &Path,
    episodes: usize,
    seed: u64,
    exec_horizon: Option<usize>,
) -> anyhow::Result<PushTEval> {
    let task = PushTHil::load(task, &Profile::load(profile)?)?;
    let (mut policy, meta) = MarsPolicy::load(checkpoint_dir, seed)?;
    let mut observer = Observer::new(task.observe());
    let mut eps: Vec<Episode> = Vec::with_capacity(episodes);
    for i in 0..episodes as u64 {
        policy.reseed(seed.wrapping_add(i));
        // Whole chunks by default, as marsd executes them.
        let horizon = exec_horizon.unwrap_or(meta.model.chunk_len);
        eps.push(run_episode(&task.cfg.world, &mut policy, &mut observer, seed + i, horizon)?);
    }
    let goal = task.cfg.world.goal;
    let finals: Vec<[f32; 2]> = eps
        .iter()
        .map(|e| {
            let b = e.states.last().map_or(task.cfg.world.start, |s| s.block);
            let d = ((b[0] - goal[0]).powi(2) + (b[1] - goal[1]).powi(2)).sqrt();
            [d, mars_tasks::push_t::wrap(b[2] - goal[2]).abs()]
        })
        .collect();
    let mean = |i: usize| finals.iter().map(|f| f[i]).sum::<f32>() / finals.len().max(1) as f32;
    let Score { successes, by_route, gamma, mean_k, .. } = score(&eps);
    let mut ms: Vec<f64> = eps.iter().flat_map(|e| e.calls.iter().map(|c| c.2.as_secs_f64() * 1e3)).collect();
    ms.sort_by(f64::total_cmp);
    let at = |q: f64| ms.get(((ms.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN);
    Ok(PushTEval {
        checkpoint: checkpoint_dir.display().to_string(),
        kind: meta.kind.to_string(),
        episodes,
        successes,
        by_route,
        gamma,
        mean_k,
        call_p50_ms: at(0.5),
        call_p99_ms: at(0.99),
        final_error: [mean(0), mean(1)],
    })
}

impl std::fmt::Display for PushTEval {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "| {} | {}/{} | {}, {} | {:.2} | {:.2} | {:.2} / {:.2} | {:.3} m, {:.2} rad |",
            self.kind,
            self.successes,
            self.episodes,
            self.by_route[0],
            self.by_route[1],
            self.gamma,
            self.mean_k,
            self.call_p50_ms,
            self.call_p99_ms,
            self.final_error[0],
            self.final_error[1]
        )
    }
}
