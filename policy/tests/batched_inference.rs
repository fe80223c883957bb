//! Many rollouts through the model at once must sample what one rollout at a time would: each row its own
//! K(w) and its own noise, whatever batch it runs in.

mod common;

use candle_core::{Device, Tensor};
use mars_policy::config::PolicyKind;
use mars_policy::inference::MarsPolicy;
use mars_policy::train::{randn, train};
use mars_tasks::nav2d::{Layout, evaluate_batched};
use rand::SeedableRng;
use rand::rngs::StdRng;

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f32 {
    (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
}

#[test]
fn each_row_integrates_with_its_own_step_count() {
    let cfg = common::tiny_config(PolicyKind::Mars);
    // Trained, not fresh: the DiT's output layer starts at zero, and a zero field would make any order agree.
    let model = train(&cfg, &common::forked_demos(8, 12), false).unwrap().model;
    let (c, d) = (cfg.model.chunk_len, cfg.model.action_dim);
    let ks = [3, 1, 10, 2, 10, 7, 1];
    let mut rng = StdRng::seed_from_u64(4);
    let a0 = randn(&mut rng, &[ks.len(), c, d], &Device::Cpu).unwrap();
    let emb = randn(&mut rng, &[ks.len(), cfg.model.obs_embed_dim], &Device::Cpu).unwrap();
    let all = model.integrate_each(&a0, &emb, &ks).unwrap();
    for (i, &k) in ks.iter().enumerate() {
        let row = |t: &Tensor| t.narrow(0, i, 1).unwrap();
        let alone = model.integrate(&row(&a0), &row(&emb), k).unwrap();
        let diff = max_abs_diff(&row(&all), &alone);
        assert!(diff < 1e-5, "row {i} (K = {k}) is {diff} from a batch of one");
    }
    assert!(max_abs_diff(&all.narrow(0, 0, 1).unwrap(), &a0.narrow(0, 0, 1).unwrap()) > 1e-3, "the rows moved");
}

#[test]
fn a_sampled_row_matches_the_same_row_sampled_alone() {
    let cfg = common::tiny_config(PolicyKind::Mars);
    let trained = train(&cfg, &common::forked_demos(8, 12), false).unwrap();
    let (model, m) = (&trained.model, &cfg.model);
    let b = 12;
    let mut rng = StdRng::seed_from_u64(5);
    let obs = randn(&mut rng, &[b, m.obs_dim], &Device::Cpu).unwrap().affine(2.0, 0.0).unwrap();
    let hist = randn(&mut rng, &[b, m.history_len, m.action_dim], &Device::Cpu).unwrap();
    let eps = randn(&mut rng, &[b, m.chunk_len, m.action_dim], &Device::Cpu).unwrap();
    let (chunks, w, ks) = model.sample_each(&obs, &hist, &eps).unwrap();
    for (i, &k_batched) in ks.iter().enumerate() {
        let row = |t: &Tensor| t.narrow(0, i, 1).unwrap();
        let (alone, w_alone, k) = model.sample(&row(&obs), &row(&hist), &row(&eps)).unwrap();
        assert_eq!(k_batched, k, "row {i}'s K");
        assert!(max_abs_diff(&row(&w), &w_alone) < 1e-6);
        assert!(max_abs_diff(&row(&chunks), &alone) < 1e-5, "row {i}");
    }
}

#[test]
fn a_rollout_samples_the_same_chunks_in_any_batch() {
    let cfg = common::tiny_config(PolicyKind::Mars);
    let trained = train(&cfg, &common::forked_demos(8, 12), false).unwrap();
    let layout = Layout::default_four_passages();
    let mut policy = MarsPolicy::from_trained(trained, 3);
    let one = evaluate_batched(&layout, &mut policy, 6, 40, 4, 1).unwrap();
    let six = evaluate_batched(&layout, &mut policy, 6, 40, 4, 6).unwrap();
    for (a, b) in one.episodes.iter().zip(&six.episodes) {
        assert_eq!((&a.termination, a.steps.len()), (&b.termination, b.steps.len()), "rollout {}", a.seed);
        for (x, y) in a.steps.iter().zip(&b.steps) {
            let d = (x.position[0] - y.position[0]).abs().max((x.position[1] - y.position[1]).abs());
            assert!(d < 1e-4 && x.k == y.k, "rollout {}: {x:?} vs {y:?}", a.seed);
        }
    }
}
