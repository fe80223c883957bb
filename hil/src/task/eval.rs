//! In-process closed-loop evaluation of a checkpoint on a pick task (Pick Cup, Pick Vegetable): the allocation-free
//! engine drives the HIL sim plant directly (no IPC, no daemon), executing whole chunks and re-planning after each,
//! with the expert's servo; or, with a [`Delay`], each chunk adopted δ periods after its observation. For validating
//! checkpoints and for tests; the real runtime path is `marsd`.

use std::path::Path;

use anyhow::ensure;
use mars_engine::{Engine, EngineConfig};
use mars_ipc::MAX_JOINTS;
use mars_profile::Profile;
use mars_tasks::nav2d::eval::latency_percentiles;
use mars_tasks::nav2d::modal_balance;
use serde::{Deserialize, Serialize};

use super::boundary::{Smoothness, smoothness};
use super::delay::{Continuity, Delay, Schedule};
use super::pick::{DoneReason, Pick, Progress, max_abs_diff};
use super::sim_arm::SimArm;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Ending {
    Done(DoneReason),
    /// The engine refused an input or produced a non-finite chunk; the message is kept.
    PolicyError(String),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    pub seed: u64,
    pub success: bool,
    /// The grasp reached first (the mode), if any.
    pub mode: Option<usize>,
    pub ending: Ending,
    /// Policy actions executed.
    pub steps: usize,
    /// ODE steps of each policy call, in order.
    pub k_per_call: Vec<usize>,
    /// Each policy call's wall time (ms), in order (the whole `infer` through the engine, on this machine).
    #[serde(default)]
    pub call_ms: Vec<f64>,
    /// The closest the measured joints came to each grasp (max-abs error, rad): tells a near miss from a
    /// policy that stopped between the grasps (mode averaging).
    pub closest_to_grasp_rad: Vec<f64>,
    /// Actions whose setpoints left the profile's position, velocity or gripper limits.
    pub limit_violations: usize,
    pub duration_s: f64,
    /// The executed joint targets' acceleration and jerk at chunk boundaries and elsewhere.
    #[serde(default)]
    pub smoothness: Smoothness,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    pub policy: String,
    pub mode_names: Vec<String>,
    pub n: usize,
    pub successes: usize,
    /// Successful episodes per grasp, in the task's order.
    pub mode_counts: Vec<usize>,
    /// γ = k·min nᵢ / Σ nᵢ over the k grasps: 1 when balanced, 0 when a mode is never used.
    pub gamma: f32,
    /// Mean ODE steps over all policy calls.
    pub mean_k: f32,
    /// Policy call wall time (ms), p50 and p99 over every call but the run's first few (warm-up).
    #[serde(default)]
    pub call_p50_ms: Option<f64>,
    #[serde(default)]
    pub call_p99_ms: Option<f64>,
    pub limit_violations: usize,
    pub episodes: Vec<EpisodeResult>,
}

impl EvalReport {
    pub fn success_rate(&self) -> f32 {
        if self.n == 0 { 0.0 } else { self.successes as f32 / self.n as f32 }
    }
}

impl std::fmt::Display for EvalReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let modes: Vec<String> =
            self.mode_names.iter().zip(&self.mode_counts).map(|(m, c)| format!("{m} {c}")).collect();
        write!(
            f,
            "{}: success {}/{} ({:.1}%), modes {}, γ = {:.2}, mean K {:.2}, call p50 {} p99 {}, limit violations {}",
            self.policy,
            self.successes,
            self.n,
            100.0 * self.success_rate(),
            modes.join(" / "),
            self.gamma,
            self.mean_k,
            ms(self.call_p50_ms),
            ms(self.call_p99_ms),
            self.limit_violations
        )
    }
}

fn ms(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), |v| format!("{v:.2} ms"))
}

/// One closed-loop episode from the start pose of `seed`, with the engine's noise re-seeded by `seed`, each chunk
/// adopted as `delay` says.
pub fn run_episode(engine: &mut Engine, task: &Pick, profile: &Profile, seed: u64, delay: Delay) -> EpisodeResult {
    engine.reseed(seed);
    let (c, d) = (engine.chunk_len(), engine.action_dim());
    let start = task.start_pose(seed);
    let mut arm = SimArm::new(profile, task, seed);
    arm.move_to_start(&start, task.cfg.gripper_open);
    let mut monitor = task.monitor();
    let mut progress = Progress::Running;
    let mut obs = vec![0.0f32; task.obs_dim()];
    let rest = task.rest_action(&start);
    // The last C executed actions, oldest first; before the first one, "stay at the start".
    let mut history: Vec<f32> = rest.repeat(c);
    let mut schedule = Schedule::new(delay, c, &rest);
    let (mut committed, mut asked) = (Vec::with_capacity(c * d), vec![0.0f32; c * d]);
    let (mut executed, mut adopted) = (Vec::new(), Vec::new());
    let mut action = [0.0f64; MAX_JOINTS + 1];
    let (mut steps, mut k_per_call, mut call_ms, mut limit_violations) = (0, Vec::new(), Vec::new(), 0);
    let mut closest = vec![f64::INFINITY; task.n_modes()];
    let ending = loop {
        if schedule.calls_at(steps) {
            task.observation(arm.q(), arm.gripper(), &mut obs);
            schedule.committed(steps, &mut committed);
            let called = std::time::Instant::now();
            match ask(engine, delay.continuity, &obs, &history, &committed, &mut asked) {
                Ok(k) => {
                    call_ms.push(called.elapsed().as_secs_f64() * 1e3);
                    schedule.arrived(steps, &asked);
                    k_per_call.push(k);
                }
                Err(e) => break Ending::PolicyError(e.to_string()),
            }
        }
        let (a, new_chunk) = schedule.action(steps);
        executed.extend_from_slice(a);
        adopted.push(new_chunk);
        for (x, &v) in action.iter_mut().zip(a) {
            *x = v as f64;
        }
        let check = arm.execute(&action[..d], |q, g, t| {
            progress = monitor.update(q, g, t);
            for (c, grasp) in closest.iter_mut().zip(&task.cfg.grasps) {
                *c = c.min(max_abs_diff(q, &grasp.q));
            }
            progress != Progress::Running
        });
        limit_violations += check.any() as usize;
        history.copy_within(d.., 0);
        history[(c - 1) * d..].copy_from_slice(&executed[executed.len() - d..]);
        steps += 1;
        if let Progress::Done { reason, .. } = progress {
            break Ending::Done(reason);
        }
    };
    let (success, mode) = match progress {
        Progress::Done { success, mode, .. } => (success, mode),
        Progress::Running => (monitor.grasped().is_some(), monitor.grasped()),
    };
    EpisodeResult {
        seed,
        success,
        mode,
        ending,
        steps,
        k_per_call,
        call_ms,
        closest_to_grasp_rad: closest,
        limit_violations,
        duration_s: arm.t_s(),
        smoothness: smoothness(&executed, d, d - 1, &adopted, task.cfg.policy_rate_hz),
    }
}

/// One policy call for the chunk asked now, into `out`; its K. `committed` are the rows the robot will have executed
/// from the previous chunk when this one arrives.
fn ask(
    engine: &mut Engine,
    continuity: Continuity,
    obs: &[f32],
    history: &[f32],
    committed: &[f32],
    out: &mut [f32],
) -> Result<usize, mars_engine::EngineError> {
    let result = match continuity {
        Continuity::DropLate => engine.infer_with(obs, history, None, None),
        Continuity::Guided => engine.infer_after(obs, history, committed, std::time::Duration::MAX),
        Continuity::History => {
            // The history as it will be when the chunk starts: the committed rows after the executed ones.
            let shifted: Vec<f32> = history[committed.len()..].iter().chain(committed).copied().collect();
            engine.infer_with(obs, &shifted, None, None)
        }
    }?;
    out.copy_from_slice(result.chunk);
    Ok(result.k_used)
}

/// `n` episodes with seeds `seed + i` of the checkpoint in `dir`, aggregated.
pub fn evaluate(dir: &Path, task: &Pick, profile: &Profile, n: usize, seed: u64) -> anyhow::Result<EvalReport> {
    evaluate_delayed(dir, task, profile, n, seed, Delay::NONE)
}

/// [`evaluate`] with each chunk adopted as `delay` says.
pub fn evaluate_delayed(
    dir: &Path,
    task: &Pick,
    profile: &Profile,
    n: usize,
    seed: u64,
    delay: Delay,
) -> anyhow::Result<EvalReport> {
    ensure!(n > 0, "evaluate at least 1 episode");
    let mut engine = Engine::load(dir, EngineConfig::with_seed(seed))?;
    delay.check(engine.chunk_len()).map_err(anyhow::Error::msg)?;
    ensure!(
        engine.obs_dim() == task.obs_dim() && engine.action_dim() == task.action_dim(),
        "checkpoint {} has obs_dim {} / action_dim {}, the task needs {} / {}",
        dir.display(),
        engine.obs_dim(),
        engine.action_dim(),
        task.obs_dim(),
        task.action_dim()
    );
    let episodes: Vec<EpisodeResult> =
        (0..n as u64).map(|i| run_episode(&mut engine, task, profile, seed.wrapping_add(i), delay)).collect();
    let mut mode_counts = vec![0; task.n_modes()];
    for m in episodes.iter().filter(|e| e.success).filter_map(|e| e.mode) {
        mode_counts[m] += 1;
    }
    let calls: Vec<usize> = episodes.iter().flat_map(|e| e.k_per_call.iter().copied()).collect();
    // The run's first calls (caches, page faults) are skipped, as for nav2d.
    let times: Vec<std::time::Duration> =
        episodes.iter().flat_map(|e| &e.call_ms).map(|&m| std::time::Duration::from_secs_f64(m / 1e3)).collect();
    let latency = latency_percentiles(&times);
    Ok(EvalReport {
        policy: engine.kind().name().to_owned(),
        mode_names: task.cfg.grasps.iter().map(|g| g.name.clone()).collect(),
        n,
        successes: episodes.iter().filter(|e| e.success).count(),
        gamma: modal_balance(&mode_counts),
        mode_counts,
        mean_k: if calls.is_empty() { 0.0 } else { calls.iter().sum::<usize>() as f32 / calls.len() as f32 },
        call_p50_ms: latency.map(|l| l.0),
        call_p99_ms: latency.map(|l| l.1),
        limit_violations: episodes.iter().map(|e| e.limit_violations).sum(),
        episodes,
    })
}
