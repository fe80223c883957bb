//! The step budget: K = min(K(w), the most steps whose estimated cost fits), at least 1, and the output says
//! when the deadline cut the steps or when not even one step fits.

mod common;

use common::{inputs, trained_checkpoint};
use mars_engine::{Engine, EngineConfig};
use mars_policy::config::PolicyKind;
use rand::SeedableRng;
use rand::rngs::StdRng;
use std::time::{Duration, Instant};

#[test]
fn the_deadline_caps_k_and_reports_it() {
    // FM asks for K_max = 10 steps on every input, so every cap shows.
    let dir = trained_checkpoint(PolicyKind::Fm, "budget-cap", |_| {});
    let mut engine = Engine::load(&dir, EngineConfig::default()).unwrap();
    let (obs, hist) = inputs(&mut StdRng::seed_from_u64(2), engine.obs_dim(), engine.chunk_len() * 2);

    // The first estimate exists right after load (from the warm-up calls).
    let est = engine.cost_estimate();
    assert!(est.fixed > Duration::ZERO && est.per_step > Duration::ZERO, "{est:?}");

    let out = engine.infer(&obs, &hist, Duration::MAX).unwrap();
    assert_eq!((out.k_requested, out.k_used, out.capped, out.over_budget), (10, 10, false, false));

    for k in [1, 3, 7] {
        let est = engine.cost_estimate();
        let budget = est.call(k) + est.per_step / 2;
        let out = engine.infer(&obs, &hist, budget).unwrap();
        assert_eq!((out.k_requested, out.k_used, out.capped, out.over_budget), (10, k, true, false), "{budget:?}");
        assert_eq!(out.estimated, est.call(k));
    }

    let out = engine.infer(&obs, &hist, Duration::ZERO).unwrap();
    assert_eq!((out.k_requested, out.k_used, out.capped, out.over_budget), (10, 1, true, true));
    assert!(out.chunk.iter().all(|v| v.is_finite()), "a chunk is produced even over budget");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_model_asking_for_one_step_is_over_budget_but_not_capped() {
    let dir = trained_checkpoint(PolicyKind::A2a, "budget-a2a", |_| {});
    let mut engine = Engine::load(&dir, EngineConfig::default()).unwrap();
    let (obs, hist) = inputs(&mut StdRng::seed_from_u64(2), engine.obs_dim(), engine.chunk_len() * 2);
    let out = engine.infer(&obs, &hist, Duration::ZERO).unwrap();
    assert_eq!((out.k_requested, out.k_used, out.capped, out.over_budget), (1, 1, false, true));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// With a budget of a few steps, calls mostly finish within it: the estimate is measured, not guessed.
/// Loose bounds (the median, 2× slack) so a loaded test machine does not make it flaky.
#[test]
fn capped_calls_take_about_the_budget() {
    let dir = trained_checkpoint(PolicyKind::Fm, "budget-time", |_| {});
    let mut engine = Engine::load(&dir, EngineConfig::default()).unwrap();
    let (obs, hist) = inputs(&mut StdRng::seed_from_u64(4), engine.obs_dim(), engine.chunk_len() * 2);
    for _ in 0..20 {
        engine.infer(&obs, &hist, Duration::MAX).unwrap();
    }
    let budget = engine.cost_estimate().call(4);
    let mut times: Vec<Duration> = (0..200)
        .map(|_| {
            let t = Instant::now();
            let out = engine.infer(&obs, &hist, budget).unwrap();
            assert!(out.k_used >= 1 && out.k_used <= 10);
            t.elapsed()
        })
        .collect();
    times.sort();
    let median = times[times.len() / 2];
    assert!(median <= budget * 2, "median {median:?} vs budget {budget:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Injected slowness (HIL fault injection) is measured like real compute: the estimate grows by the delay per
/// step, and a budget of 40 ms then fits only a few of FM's 10 steps.
#[test]
fn an_injected_step_delay_is_measured_and_caps_k() {
    let dir = trained_checkpoint(PolicyKind::Fm, "budget-injected", |_| {});
    let delay = Duration::from_millis(10);
    let cfg = EngineConfig { injected_step_delay: delay, ..EngineConfig::default() };
    let mut engine = Engine::load(&dir, cfg).unwrap();
    let est = engine.cost_estimate();
    assert!(est.per_step >= delay, "the warm-up measured the delay: {est:?}");
    let (obs, hist) = inputs(&mut StdRng::seed_from_u64(5), engine.obs_dim(), engine.chunk_len() * 2);
    let out = engine.infer(&obs, &hist, Duration::from_millis(40)).unwrap();
    assert!(out.capped && (1..=3).contains(&out.k_used), "k_used {}", out.k_used);
    std::fs::remove_dir_all(&dir).unwrap();
}
