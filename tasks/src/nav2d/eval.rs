//! Closed-loop evaluation of a [`ChunkPolicy`] on nav2d: success, modal balance across passages, ODE steps
//! and inference latency.

use std::collections::VecDeque;
use std::fmt;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure};
use rand::SeedableRng;
use rand::rngs::StdRng;
use serde::{Deserialize, Serialize};

use super::env::{Nav2dEnv, StepOutcome};
use super::layout::Layout;
use crate::rollout::{ChunkPolicy, Prediction};

/// Policy calls at the start of an evaluation excluded from latency statistics (allocator, kernel caches).
pub const WARMUP_CALLS: usize = 5;

/// How an episode ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Termination {
    Success,
    Collision,
    Timeout,
    /// The policy produced a NaN/inf action.
    InvalidAction,
    /// The policy returned an error or a malformed prediction; the message is kept.
    PolicyError(String),
}

/// One env step: where the agent ended up and the chunk that commanded it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    pub position: [f32; 2],
    /// ‖w‖∞ of the chunk in force.
    pub w_inf: f32,
    /// ODE steps of the chunk in force.
    pub k: usize,
}

/// One policy call.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CallRecord {
    pub latency: Duration,
    pub k: usize,
    pub w_inf: f32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Episode {
    pub seed: u64,
    pub start: [f32; 2],
    pub steps: Vec<StepRecord>,
    pub calls: Vec<CallRecord>,
    pub termination: Termination,
    /// The passage entered first, if any.
    pub mode: Option<usize>,
}

impl Episode {
    pub fn success(&self) -> bool {
        self.termination == Termination::Success
    }

    /// Start followed by the position after each step.
    pub fn trajectory(&self) -> Vec<[f32; 2]> {
        std::iter::once(self.start).chain(self.steps.iter().map(|s| s.position)).collect()
    }

    pub fn k_per_step(&self) -> Vec<usize> {
        self.steps.iter().map(|s| s.k).collect()
    }
}

/// One closed-loop episode. Errors only for a setup mismatch (policy action_dim ≠ 2, `exec_horizon` not
/// in `1..=chunk_len`); anything going wrong during the episode is recorded in its [`Termination`].
pub fn run_episode(
    layout: &Layout,
    policy: &mut dyn ChunkPolicy,
    seed: u64,
    exec_horizon: usize,
) -> anyhow::Result<Episode> {
    check_setup(policy.action_dim(), policy.chunk_len(), exec_horizon)?;
    let mut run = EpisodeRun::start(layout, seed, policy.history_len(), policy.chunk_len());
    let mut history = Vec::new();
    let termination = loop {
        history.clear();
        run.history_into(&mut history);
        let t0 = Instant::now();
        let prediction = policy.predict(&run.observation(), &history);
        if let Some(end) = run.apply(prediction, t0.elapsed(), exec_horizon) {
            break end;
        }
    };
    Ok(run.finish(termination))
}

/// One episode between policy calls: its env, the action history the policy sees, and what happened so far.
/// The sequential and the batched evaluations both drive episodes through it, so they score alike.
pub struct EpisodeRun<'a> {
    seed: u64,
    start: [f32; 2],
    env: Nav2dEnv<'a>,
    history: VecDeque<[f32; 2]>,
    steps: Vec<StepRecord>,
    calls: Vec<CallRecord>,
    /// chunk_len × action_dim: the values a prediction must hold.
    expected: usize,
}

impl<'a> EpisodeRun<'a> {
    /// An episode from the start `seed` draws, its history padded as "stayed at the start" (the same padding
    /// the demos' rest_action gives training).
    pub fn start(layout: &'a Layout, seed: u64, history_len: usize, chunk_len: usize) -> Self {
        let start = layout.sample_start(&mut StdRng::seed_from_u64(seed));
        let mut env = Nav2dEnv::new(layout);
        env.reset(start);
        let history = std::iter::repeat_n(start, history_len).collect();
        Self { seed, start, env, history, steps: Vec::new(), calls: Vec::new(), expected: chunk_len * 2 }
    }

    pub fn observation(&self) -> [f32; 2] {
        self.env.position()
    }

    /// Appends the history, oldest first, as the policy takes it (`history_len × 2`).
    pub fn history_into(&self, out: &mut Vec<f32>) {
        out.extend(self.history.iter().flatten());
    }

    /// Executes the first `exec_horizon` actions of `prediction`; the episode's end if it ended.
    pub fn apply(
        &mut self,
        prediction: anyhow::Result<Prediction>,
        latency: Duration,
        exec_horizon: usize,
    ) -> Option<Termination> {
        let p = match prediction {
            Ok(p) => p,
            Err(e) => return Some(Termination::PolicyError(format!("{e:#}"))),
        };
        if p.chunk.len() != self.expected {
            let msg =
                format!("chunk has {} values, expected chunk_len × action_dim = {}", p.chunk.len(), self.expected);
            return Some(Termination::PolicyError(msg));
        }
        let w_inf = p.w.iter().fold(0.0f32, |m, w| m.max(w.abs()));
        self.calls.push(CallRecord { latency, k: p.k, w_inf });
        p.chunk.chunks_exact(2).take(exec_horizon).find_map(|a| self.step([a[0], a[1]], w_inf, p.k))
    }

    fn step(&mut self, target: [f32; 2], w_inf: f32, k: usize) -> Option<Termination> {
        let outcome = self.env.step(target);
        if !self.history.is_empty() {
            self.history.pop_front();
            self.history.push_back(target);
        }
        if outcome != StepOutcome::InvalidTarget {
            self.steps.push(StepRecord { position: self.env.position(), w_inf, k });
        }
        match outcome {
            StepOutcome::Running => None,
            StepOutcome::ReachedGoal => Some(Termination::Success),
            StepOutcome::Collided => Some(Termination::Collision),
            StepOutcome::TimedOut => Some(Termination::Timeout),
            StepOutcome::InvalidTarget => Some(Termination::InvalidAction),
        }
    }

    pub fn finish(self, termination: Termination) -> Episode {
        let Self { seed, start, steps, calls, env, .. } = self;
        Episode { seed, start, steps, calls, termination, mode: env.mode() }
    }
}

pub(super) fn check_setup(action_dim: usize, chunk_len: usize, exec_horizon: usize) -> anyhow::Result<()> {
    ensure!(action_dim == 2, "nav2d actions are 2-D target positions; policy action_dim = {action_dim}");
    if exec_horizon == 0 || exec_horizon > chunk_len {
        bail!("exec_horizon must be in 1..={chunk_len} (the policy's chunk_len), got {exec_horizon}");
    }
    Ok(())
}

/// γ = k · min_i n_i / Σ n_i over the k passages: 1 when successes are spread evenly, 0 when a passage is
/// never used (mode collapse) or nothing succeeded.
pub fn modal_balance(counts: &[usize]) -> f32 {
    let total: usize = counts.iter().sum();
    match counts.iter().min() {
        Some(&min) if total > 0 => (counts.len() * min) as f32 / total as f32,
        _ => 0.0,
    }
}

/// Nearest-rank percentiles (p50, p99) in milliseconds of `latencies` after the first [`WARMUP_CALLS`].
pub fn latency_percentiles(latencies: &[Duration]) -> Option<(f64, f64)> {
    let mut ms: Vec<f64> = latencies.iter().skip(WARMUP_CALLS).map(|d| d.as_secs_f64() * 1e3).collect();
    if ms.is_empty() {
        return None;
    }
    ms.sort_by(f64::total_cmp);
    let rank = |p: f64| ms[((p / 100.0 * ms.len() as f64).ceil() as usize).clamp(1, ms.len()) - 1];
    Some((rank(50.0), rank(99.0)))
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    pub n: usize,
    pub successes: usize,
    pub collisions: usize,
    pub timeouts: usize,
    /// Invalid actions and policy errors.
    pub errors: usize,
    /// Successful rollouts per passage, in mode order.
    pub passage_counts: Vec<usize>,
    pub modal_balance: f32,
    /// Mean ODE steps over all policy calls.
    pub mean_k: f32,
    pub latency_p50_ms: Option<f64>,
    pub latency_p99_ms: Option<f64>,
    pub episodes: Vec<Episode>,
}

/// `n_rollouts` episodes with seeds `base_seed + i`, aggregated.
pub fn evaluate(
    layout: &Layout,
    policy: &mut dyn ChunkPolicy,
    n_rollouts: usize,
    base_seed: u64,
    exec_horizon: usize,
) -> anyhow::Result<EvalReport> {
    let episodes = (0..n_rollouts as u64)
        .map(|i| run_episode(layout, policy, base_seed.wrapping_add(i), exec_horizon))
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(EvalReport::from_episodes(layout.n_passages(), episodes))
}

impl EvalReport {
    pub fn from_episodes(n_passages: usize, episodes: Vec<Episode>) -> Self {
        let count = |t: &dyn Fn(&Termination) -> bool| episodes.iter().filter(|e| t(&e.termination)).count();
        let successes = count(&|t| *t == Termination::Success);
        let collisions = count(&|t| *t == Termination::Collision);
        let timeouts = count(&|t| *t == Termination::Timeout);
        let mut passage_counts = vec![0; n_passages];
        for m in episodes.iter().filter(|e| e.success()).filter_map(|e| e.mode) {
            if let Some(c) = passage_counts.get_mut(m) {
                *c += 1;
            }
        }
        let calls: Vec<&CallRecord> = episodes.iter().flat_map(|e| &e.calls).collect();
        let mean_k =
            if calls.is_empty() { 0.0 } else { calls.iter().map(|c| c.k as f32).sum::<f32>() / calls.len() as f32 };
        let latencies: Vec<Duration> = calls.iter().map(|c| c.latency).collect();
        let percentiles = latency_percentiles(&latencies);
        Self {
            n: episodes.len(),
            successes,
            collisions,
            timeouts,
            errors: episodes.len() - successes - collisions - timeouts,
            modal_balance: modal_balance(&passage_counts),
            passage_counts,
            mean_k,
            latency_p50_ms: percentiles.map(|p| p.0),
            latency_p99_ms: percentiles.map(|p| p.1),
            episodes,
        }
    }

    pub fn success_rate(&self) -> f32 {
        if self.n == 0 { 0.0 } else { self.successes as f32 / self.n as f32 }
    }

    /// Markdown table header matching [`EvalReport::to_table_row`].
    pub fn table_header() -> String {
        "| policy | success % | passages | γ | mean K | p50 ms | p99 ms |\n|---|---:|---|---:|---:|---:|---:|".into()
    }

    /// `| policy | success % | a/b/c/d | γ | mean K | p50 ms | p99 ms |`
    pub fn to_table_row(&self, policy: &str) -> String {
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.2}"));
        let counts: Vec<String> = self.passage_counts.iter().map(|c| c.to_string()).collect();
        format!(
            "| {policy} | {:.1} | {} | {:.2} | {:.1} | {} | {} |",
            100.0 * self.success_rate(),
            counts.join("/"),
            self.modal_balance,
            self.mean_k,
            ms(self.latency_p50_ms),
            ms(self.latency_p99_ms)
        )
    }
}

impl fmt::Display for EvalReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.2} ms"));
        writeln!(
            f,
            "success {}/{} ({:.1}%), collisions {}, timeouts {}, errors {}",
            self.successes,
            self.n,
            100.0 * self.success_rate(),
            self.collisions,
            self.timeouts,
            self.errors
        )?;
        writeln!(f, "passages {:?}, modal balance γ = {:.2}", self.passage_counts, self.modal_balance)?;
        write!(
            f,
            "mean K {:.1}, latency p50 {} p99 {} (first {WARMUP_CALLS} calls discarded)",
            self.mean_k,
            ms(self.latency_p50_ms),
            ms(self.latency_p99_ms)
        )?;
        if let Some(Termination::PolicyError(msg)) =
            self.episodes.iter().map(|e| &e.termination).find(|t| matches!(t, Termination::PolicyError(_)))
        {
            write!(f, "\nfirst policy error: {msg}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav2d::expert::Polyline;
    use crate::rollout::PolicyShape;

    /// Replays the nominal expert route, choosing the passage per episode from `plan` (cycling). It spots a
    /// new episode by the history being all rest actions equal to the observation, which also checks how
    /// `run_episode` pads the history.
    struct RoutePolicy {
        layout: Layout,
        plan: Vec<usize>,
        episode: usize,
        route: Option<Polyline>,
        new_episodes_seen: usize,
    }

    impl RoutePolicy {
        fn new(plan: Vec<usize>) -> Self {
            Self { layout: Layout::default_four_passages(), plan, episode: 0, route: None, new_episodes_seen: 0 }
        }
    }

    impl PolicyShape for RoutePolicy {
        fn action_dim(&self) -> usize {
            2
        }
        fn chunk_len(&self) -> usize {
            8
        }
        fn history_len(&self) -> usize {
            3
        }
    }

    impl ChunkPolicy for RoutePolicy {
        fn predict(&mut self, obs: &[f32], history: &[f32]) -> anyhow::Result<Prediction> {
            assert_eq!(history.len(), 6);
            if history.chunks(2).all(|h| h == obs) {
                let passage = self.plan[self.episode % self.plan.len()];
                self.episode += 1;
                self.new_episodes_seen += 1;
                let mut pts = vec![[obs[0], obs[1]]];
                pts.extend_from_slice(self.layout.route(passage).expect("route"));
                self.route = Some(Polyline::new(pts)?);
            }
            let route = self.route.as_ref().expect("route set on the first call");
            let s = route.project([obs[0], obs[1]], 0.0);
            let chunk = (1..=8).flat_map(|i| route.point_at(s + 0.25 * i as f32)).collect();
            Ok(Prediction { chunk, w: vec![0.5, 1.0], k: 3 })
        }
    }

    #[test]
    fn route_policy_succeeds_through_its_passage() {
        let layout = Layout::default_four_passages();
        let mut policy = RoutePolicy::new(vec![2]);
        let report = evaluate(&layout, &mut policy, 6, 100, 4).expect("eval");
        assert_eq!(report.successes, 6, "{report}");
        assert_eq!(report.passage_counts, vec![0, 0, 6, 0]);
        assert_eq!(report.modal_balance, 0.0);
        assert_eq!(policy.new_episodes_seen, 6);
        assert_eq!(report.mean_k, 3.0);
        assert!(report.latency_p50_ms.is_some() && report.latency_p99_ms.is_some());
        let e = &report.episodes[0];
        assert!(e.steps.iter().all(|s| s.w_inf == 1.0 && s.k == 3));
        assert_eq!(e.trajectory().len(), e.steps.len() + 1);
        assert_eq!(e.calls.len(), e.steps.len().div_ceil(4));
        let seeds: Vec<u64> = report.episodes.iter().map(|e| e.seed).collect();
        assert_eq!(seeds, (100..106).collect::<Vec<_>>());
        assert_ne!(report.episodes[0].start, report.episodes[1].start, "distinct seeds, distinct starts");
        // The CLI stores reports as JSON and plots from them later.
        let json = serde_json::to_string(&report).expect("serialise");
        let back: EvalReport = serde_json::from_str(&json).expect("deserialise");
        assert_eq!(back.episodes, report.episodes);
        assert_eq!(back.to_table_row("route"), report.to_table_row("route"));
        let row = report.to_table_row("route");
        assert!(row.starts_with("| route | 100.0 | 0/0/6/0 | 0.00 | 3.0 |"), "{row}");
    }

    #[test]
    fn balanced_policy_gets_gamma_one() {
        let layout = Layout::default_four_passages();
        let mut policy = RoutePolicy::new(vec![0, 1, 2, 3]);
        let report = evaluate(&layout, &mut policy, 8, 0, 8).expect("eval");
        assert_eq!(report.passage_counts, vec![2, 2, 2, 2], "{report}");
        assert_eq!(report.modal_balance, 1.0);
    }

    #[test]
    fn modal_balance_of_known_counts() {
        assert_eq!(modal_balance(&[25, 25, 25, 25]), 1.0);
        assert_eq!(modal_balance(&[50, 50, 0, 0]), 0.0);
        assert!((modal_balance(&[10, 30, 30, 30]) - 0.4).abs() < 1e-6);
        assert_eq!(modal_balance(&[0, 0, 0, 0]), 0.0);
    }

    #[test]
    fn latency_percentiles_skip_warmup() {
        let mut lat = vec![Duration::from_secs(1); WARMUP_CALLS];
        lat.extend((1..=100).map(Duration::from_millis));
        let (p50, p99) = latency_percentiles(&lat).expect("enough calls");
        assert!((p50 - 50.0).abs() < 1e-9 && (p99 - 99.0).abs() < 1e-9, "{p50} {p99}");
        assert_eq!(latency_percentiles(&lat[..WARMUP_CALLS]), None);
    }

    struct FixedPolicy(Result<Vec<f32>, String>);

    impl PolicyShape for FixedPolicy {
        fn action_dim(&self) -> usize {
            2
        }
        fn chunk_len(&self) -> usize {
            2
        }
        fn history_len(&self) -> usize {
            0
        }
    }

    impl ChunkPolicy for FixedPolicy {
        fn predict(&mut self, _: &[f32], history: &[f32]) -> anyhow::Result<Prediction> {
            assert!(history.is_empty());
            match &self.0 {
                Ok(chunk) => Ok(Prediction { chunk: chunk.clone(), w: vec![0.0, 0.0], k: 1 }),
                Err(msg) => bail!("{msg}"),
            }
        }
    }

    #[test]
    fn policy_failures_end_the_episode_without_panicking() {
        let layout = Layout::default_four_passages();
        let e = run_episode(&layout, &mut FixedPolicy(Err("boom".into())), 0, 1).expect("setup ok");
        assert_eq!(e.termination, Termination::PolicyError("boom".into()));
        let e = run_episode(&layout, &mut FixedPolicy(Ok(vec![f32::NAN; 4])), 0, 2).expect("setup ok");
        assert_eq!(e.termination, Termination::InvalidAction);
        let e = run_episode(&layout, &mut FixedPolicy(Ok(vec![1.0; 3])), 0, 1).expect("setup ok");
        assert!(matches!(e.termination, Termination::PolicyError(ref m) if m.contains("expected")));
        let e = run_episode(&layout, &mut FixedPolicy(Ok(vec![5.0, 4.0, 5.0, 4.0])), 0, 2).expect("setup ok");
        assert_eq!(e.termination, Termination::Collision, "walks into the entry wall");
        let e = run_episode(&layout, &mut FixedPolicy(Ok(vec![1.0, 4.0, 1.0, 4.0])), 0, 2).expect("setup ok");
        assert_eq!(e.termination, Termination::Timeout);
        assert_eq!(e.steps.len(), layout.agent.max_steps);
        assert!(run_episode(&layout, &mut FixedPolicy(Ok(vec![])), 0, 3).is_err(), "exec_horizon > chunk_len");
        let report = EvalReport::from_episodes(4, vec![e]);
        assert_eq!((report.timeouts, report.successes, report.modal_balance), (1, 0, 0.0));
    }
}
