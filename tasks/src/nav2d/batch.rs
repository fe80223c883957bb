//! The evaluation with its rollouts batched through the model: up to `batch` episodes run side by side, one
//! policy call serving all of them per re-plan, and a finished episode's slot taken by the next rollout. This is
//! what makes 1 000 rollouts per checkpoint routine.
//!
//! Episodes are the sequential evaluation's ([`EpisodeRun`]), so both score alike; what differs is the noise,
//! drawn per call from [`noise_key`]`(rollout seed, call)`, so a rollout's result does not depend on the batch.

use std::time::Instant;

use anyhow::Context;

use super::eval::{Episode, EpisodeRun, EvalReport, check_setup};
use super::layout::Layout;
use crate::rollout::{BatchPolicy, Prediction, noise_key};

/// One rollout in flight: its index among all rollouts, its episode, how many calls it made.
struct Slot<'a> {
    index: usize,
    run: EpisodeRun<'a>,
    calls: u64,
}

/// `n_rollouts` episodes with seeds `base_seed + i`, at most `batch` at a time. Latency percentiles are left
/// out of the report: a batched call's time is not one inference's (measure latency with [`super::evaluate`]).
pub fn evaluate_batched(
    layout: &Layout,
    policy: &mut dyn BatchPolicy,
    n_rollouts: usize,
    base_seed: u64,
    exec_horizon: usize,
    batch: usize,
) -> anyhow::Result<EvalReport> {
    check_setup(policy.action_dim(), policy.chunk_len(), exec_horizon)?;
    anyhow::ensure!(batch > 0, "the batch must hold at least one rollout");
    let (history_len, chunk_len) = (policy.history_len(), policy.chunk_len());
    let mut episodes: Vec<Option<Episode>> = (0..n_rollouts).map(|_| None).collect();
    let mut slots: Vec<Slot> = Vec::with_capacity(batch);
    let (mut next, mut obs, mut hist, mut keys) = (0, Vec::new(), Vec::new(), Vec::new());
    loop {
        while slots.len() < batch && next < n_rollouts {
            let run = EpisodeRun::start(layout, base_seed.wrapping_add(next as u64), history_len, chunk_len);
            slots.push(Slot { index: next, run, calls: 0 });
            next += 1;
        }
        if slots.is_empty() {
            break;
        }
        obs.clear();
        hist.clear();
        keys.clear();
        for s in &slots {
            obs.extend(s.run.observation());
            s.run.history_into(&mut hist);
            keys.push(noise_key(base_seed.wrapping_add(s.index as u64), s.calls));
        }
        let t0 = Instant::now();
        let predictions = split(policy.predict_batch(&obs, &hist, &keys), slots.len());
        let latency = t0.elapsed() / slots.len() as u32;
        let mut kept = Vec::with_capacity(batch);
        for (mut s, p) in slots.drain(..).zip(predictions) {
            s.calls += 1;
            match s.run.apply(p, latency, exec_horizon) {
                Some(end) => episodes[s.index] = Some(s.run.finish(end)),
                None => kept.push(s),
            }
        }
        slots = kept;
    }
    // Every rollout started ends: each call steps the env at least once, and an episode times out.
    let episodes = episodes.into_iter().collect::<Option<Vec<_>>>().context("a rollout did not end")?;
    let mut report = EvalReport::from_episodes(layout.n_passages(), episodes);
    (report.latency_p50_ms, report.latency_p99_ms) = (None, None);
    Ok(report)
}

/// One result per row: a failed call, or a wrong number of predictions, fails every row with the reason.
fn split(result: anyhow::Result<Vec<Prediction>>, rows: usize) -> Vec<anyhow::Result<Prediction>> {
    match result {
        Ok(v) if v.len() == rows => v.into_iter().map(Ok).collect(),
        Ok(v) => (0..rows).map(|_| Err(anyhow::anyhow!("{} predictions for a batch of {rows}", v.len()))).collect(),
        Err(e) => (0..rows).map(|_| Err(anyhow::anyhow!("{e:#}"))).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav2d::Termination;
    use crate::rollout::PolicyShape;
    use rand::{Rng, SeedableRng, rngs::StdRng};

    /// Heads right and up from where it is, by a step its noise key jitters: stateless, so any batching of
    /// the same rollouts must give the same episodes.
    struct Drift {
        calls: usize,
        rows: usize,
    }

    impl PolicyShape for Drift {
        fn action_dim(&self) -> usize {
            2
        }
        fn chunk_len(&self) -> usize {
            4
        }
        fn history_len(&self) -> usize {
            2
        }
    }

    impl BatchPolicy for Drift {
        fn predict_batch(&mut self, obs: &[f32], hist: &[f32], keys: &[u64]) -> anyhow::Result<Vec<Prediction>> {
            assert_eq!((obs.len(), hist.len()), (2 * keys.len(), 4 * keys.len()));
            self.calls += 1;
            self.rows += keys.len();
            let predict = |(o, &key): (&[f32], &u64)| {
                let mut rng = StdRng::seed_from_u64(key);
                let chunk = (1..=4)
                    .flat_map(|i| [o[0] + 0.3 * i as f32, o[1] + 0.2 * i as f32 * rng.random_range(-1.0..1.0)])
                    .collect();
                Prediction { chunk, w: vec![0.5, 0.5], k: 1 + (key % 3) as usize }
            };
            Ok(obs.chunks(2).zip(keys).map(predict).collect())
        }
    }

    #[test]
    fn rollouts_do_not_depend_on_the_batch_they_run_in() {
        let layout = Layout::default_four_passages();
        let one = evaluate_batched(&layout, &mut Drift { calls: 0, rows: 0 }, 23, 5, 3, 1).expect("batch 1");
        let mut wide = Drift { calls: 0, rows: 0 };
        let seven = evaluate_batched(&layout, &mut wide, 23, 5, 3, 7).expect("batch 7");
        // All but the latencies, which are the clock's.
        let seen = |r: &EvalReport| -> Vec<_> {
            let calls = |e: &Episode| e.calls.iter().map(|c| (c.k, c.w_inf)).collect::<Vec<_>>();
            r.episodes.iter().map(|e| (e.seed, e.start, e.steps.clone(), calls(e), e.termination.clone())).collect()
        };
        assert_eq!(seen(&one), seen(&seven));
        assert!(one.episodes.iter().any(|e| e.steps.len() > 3), "more than one call per rollout");
        assert!(wide.calls < wide.rows, "rows were batched: {} calls for {} rows", wide.calls, wide.rows);
        let seeds: Vec<u64> = seven.episodes.iter().map(|e| e.seed).collect();
        assert_eq!(seeds, (5..28).collect::<Vec<_>>(), "in rollout order");
        assert_eq!((seven.latency_p50_ms, seven.latency_p99_ms), (None, None));
        let later = evaluate_batched(&layout, &mut Drift { calls: 0, rows: 0 }, 3, 6, 3, 2).expect("from seed 6");
        assert_eq!(seen(&later)[..], seen(&seven)[1..4], "a rollout is its seed, whatever the evaluation's first");
        assert_ne!(seen(&seven)[0].2, seen(&seven)[1].2, "other seeds, other rollouts");
    }

    struct Failing(Option<usize>);

    impl PolicyShape for Failing {
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

    impl BatchPolicy for Failing {
        fn predict_batch(&mut self, _: &[f32], _: &[f32], keys: &[u64]) -> anyhow::Result<Vec<Prediction>> {
            match self.0 {
                None => anyhow::bail!("boom"),
                Some(n) => Ok(vec![Prediction { chunk: vec![1.0; 4], w: vec![0.0; 2], k: 1 }; n.min(keys.len() + 1)]),
            }
        }
    }

    #[test]
    fn a_failed_or_malformed_batch_ends_its_rollouts_with_the_reason() {
        let layout = Layout::default_four_passages();
        let r = evaluate_batched(&layout, &mut Failing(None), 5, 0, 1, 2).expect("setup ok");
        assert!(r.episodes.iter().all(|e| e.termination == Termination::PolicyError("boom".into())));
        let r = evaluate_batched(&layout, &mut Failing(Some(9)), 5, 0, 1, 2).expect("setup ok");
        let wrong = |e: &Episode| matches!(&e.termination, Termination::PolicyError(m) if m.contains("for a batch"));
        assert!(r.episodes.iter().all(wrong), "{:?}", r.episodes[0].termination);
        assert!(evaluate_batched(&layout, &mut Failing(None), 5, 0, 1, 0).is_err(), "batch 0");
        assert!(evaluate_batched(&layout, &mut Failing(None), 5, 0, 3, 2).is_err(), "exec_horizon > chunk_len");
    }
}
