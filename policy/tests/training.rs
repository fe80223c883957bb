//! Gradients reach every weight (candle's fused norms/softmax would silently stop them), the stop-gradients
//! hold, training is seeded, and a short run measurably lowers the loss.

mod common;
mod gradients;

use candle_core::Device;
use candle_nn::{Optimizer, ParamsAdamW};
use mars_policy::config::PolicyKind;
use mars_policy::dataset::{Dataset, future_window, history_window};
use mars_policy::train::{Batch, batch_losses, init_model, train};
use rand::SeedableRng;
use rand::rngs::StdRng;

fn first_batch(kind: PolicyKind) -> (mars_policy::config::PolicyConfig, Batch) {
    let cfg = common::tiny_config(kind);
    let data = Dataset::from_demos(&common::forked_demos(8, 12), &cfg.model, cfg.train.knn_m).unwrap();
    let tensors = data.tensors(&cfg.model, &Device::Cpu).unwrap();
    let idx: Vec<u32> = (0..32).map(|i| i * 3 % data.len as u32).collect();
    (cfg, Batch::gather(&tensors, &idx).unwrap())
}

#[test]
fn every_trainable_tensor_gets_a_nonzero_gradient() {
    for (kind, scheduler_sees_history) in [(PolicyKind::Mars, false), (PolicyKind::Mars, true), (PolicyKind::Fm, false)]
    {
        let (mut cfg, batch) = first_batch(kind);
        cfg.model.scheduler_uses_history = scheduler_sees_history;
        let (model, varmap) = init_model(&cfg, &Device::Cpu).unwrap();
        let mut opt = candle_nn::AdamW::new(varmap.all_vars(), ParamsAdamW { lr: 1e-3, ..Default::default() }).unwrap();
        let mut rng = StdRng::seed_from_u64(0);
        // adaLN-Zero starts the gates and output layer at zero, which blocks gradients to the layers behind them
        // until the first update; two steps move them off zero.
        for _ in 0..2 {
            let loss = batch_losses(&model, &batch, &cfg, &mut rng).unwrap().total;
            opt.backward_step(&loss).unwrap();
        }
        let grads = batch_losses(&model, &batch, &cfg, &mut rng).unwrap().total.backward().unwrap();
        let vars = varmap.data().lock().unwrap().len();
        assert!(vars > 20, "{kind}: suspiciously few variables ({vars})");
        gradients::assert_every_var_has_a_gradient(&varmap, &grads, &kind.to_string());
    }
}

#[test]
fn reconstruction_loss_gives_the_scheduler_no_gradient_but_diversity_does() {
    let (cfg, batch) = first_batch(PolicyKind::Mars);
    let (model, varmap) = init_model(&cfg, &Device::Cpu).unwrap();
    let terms = batch_losses(&model, &batch, &cfg, &mut StdRng::seed_from_u64(1)).unwrap();
    let data = varmap.data().lock().unwrap();
    let sched: Vec<_> = data.iter().filter(|(n, _)| n.starts_with("scheduler.")).collect();
    assert!(!sched.is_empty());
    let g_norm = |loss: &candle_core::Tensor, var: &candle_core::Var| -> f32 {
        let grads = loss.backward().unwrap();
        grads.get(var).map(|g| g.abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap()).unwrap_or(0.0)
    };
    let rec = terms.rec.as_ref().unwrap();
    let div = terms.div.as_ref().unwrap();
    let mut div_total = 0.0;
    for (name, var) in &sched {
        assert_eq!(g_norm(rec, var), 0.0, "L_rec reached {name}");
        div_total += g_norm(div, var);
    }
    assert!(div_total > 0.0, "L_div must train the scheduler");
}

#[test]
fn same_seed_same_result_other_seed_other_result() {
    let demos = common::forked_demos(8, 12);
    let cfg = common::tiny_config(PolicyKind::Mars);
    let a = train(&cfg, &demos, false).unwrap();
    let b = train(&cfg, &demos, false).unwrap();
    assert_eq!(a.log, b.log);
    let weights = |t: &mars_policy::train::Trained| -> Vec<f32> {
        let data = t.varmap.data().lock().unwrap();
        let mut names: Vec<_> = data.keys().cloned().collect();
        names.sort();
        names.iter().flat_map(|n| data[n].flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect()
    };
    assert_eq!(weights(&a), weights(&b));
    let mut other = cfg.clone();
    other.train.seed = 1;
    assert_ne!(train(&other, &demos, false).unwrap().log, a.log);
}

#[test]
fn short_training_lowers_the_loss() {
    let mut cfg = common::tiny_config(PolicyKind::Mars);
    cfg.train.epochs = 15;
    let log = train(&cfg, &common::forked_demos(16, 16), false).unwrap().log;
    let (first, last) = (log[0].total, log[log.len() - 1].total);
    assert!(last < 0.6 * first, "loss went {first} → {last}");
    for kind in [PolicyKind::Fm, PolicyKind::A2a, PolicyKind::NoiseA2a] {
        let mut c = common::tiny_config(kind);
        c.train.epochs = 8;
        let log = train(&c, &common::forked_demos(16, 16), false).unwrap().log;
        assert!(log.last().unwrap().total < log[0].total, "{kind} did not learn: {log:?}");
    }
}

#[test]
fn windows_pad_with_rest_action_and_last_action() {
    let actions = vec![vec![1.0], vec![2.0], vec![3.0]];
    let mut h = Vec::new();
    history_window(&actions, &[0.0], 1, 3, &mut h);
    assert_eq!(h, vec![0.0, 0.0, 1.0]);
    let mut f = Vec::new();
    future_window(&actions, 1, 4, &mut f);
    assert_eq!(f, vec![2.0, 3.0, 3.0, 3.0]);
}

#[test]
fn s_next_is_high_after_the_fork_and_low_before() {
    let cfg = common::tiny_config(PolicyKind::Mars);
    let demos = common::forked_demos(20, 16);
    let data = Dataset::from_demos(&demos, &cfg.model, cfg.train.knn_m).unwrap();
    let d = cfg.model.action_dim;
    // Sample t of demo 0 is row t. Early (chunk entirely before the fork at t = 8): y spread ≈ 0.
    // At t = 6 the chunk covers the fork: neighbours (other demos at t = 6) split up/down.
    let y_spread = |t: usize| data.s_next[t * d + 1];
    assert!(y_spread(6) > 5.0 * y_spread(0).max(1e-3), "S_next(y): t=0 {} vs t=6 {}", y_spread(0), y_spread(6));
}

#[test]
fn rescaled_target_puts_the_quantile_at_the_noise_spread_and_never_shrinks() {
    let cfg = common::tiny_config(PolicyKind::Mars);
    let demos = common::forked_demos(20, 16);
    let mut data = Dataset::from_demos(&demos, &cfg.model, cfg.train.knn_m).unwrap();
    // These demos fork wider than noise spreads; shrunk, they stand for a task whose target is below it.
    data.s_next.iter_mut().for_each(|s| *s *= 0.1);
    let before = data.s_next.clone();
    let d = cfg.model.action_dim;
    let factor = data.rescale_target_spread(0.9);
    let mut peaks: Vec<f32> = data.s_next.chunks(d).map(|s| s.iter().copied().fold(0.0, f32::max)).collect();
    let at_q = mars_policy::stats::quantile(&mut peaks, 0.9);
    let noise_spread = 2.0 / std::f32::consts::PI.sqrt();
    assert!(factor > 1.0 && (at_q - noise_spread).abs() < 1e-4, "factor {factor}, q90 {at_q}");
    // One factor for every sample and dimension: the target's shape over the task is kept.
    for (a, b) in before.iter().zip(&data.s_next) {
        assert!((a * factor - b).abs() <= 1e-5 * b.abs().max(1.0), "{a} × {factor} ≠ {b}");
    }
    // A target already above the noise spread is left alone (factor ≥ 1).
    data.s_next.iter_mut().for_each(|s| *s *= 10.0);
    let big = data.s_next.clone();
    assert_eq!(data.rescale_target_spread(0.9), 1.0);
    assert_eq!(data.s_next, big);
}

#[test]
fn snapshots_are_complete_checkpoints_and_the_last_one_is_the_final_model() {
    let mut cfg = common::tiny_config(PolicyKind::Mars);
    cfg.train.epochs = 5;
    cfg.train.k_full_quantile = Some(0.9);
    let dir = std::env::temp_dir().join(format!("mars-snapshots-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let snaps = mars_policy::train::Snapshots { every: 2, dir: dir.join("snapshots") };
    let demos = common::forked_demos(8, 12);
    let t =
        mars_policy::train::train_with_snapshots(&cfg, &demos, indicatif::ProgressBar::hidden(), Some(&snaps)).unwrap();
    t.save(&dir.join("final")).unwrap();
    let found: Vec<usize> =
        mars_policy::curve::snapshot_dirs(&snaps.dir).unwrap().into_iter().map(|(e, _)| e).collect();
    assert_eq!(found, [2, 4, 5], "every 2 epochs and the last");
    for (epoch, snap) in mars_policy::curve::snapshot_dirs(&snaps.dir).unwrap() {
        let meta = mars_policy::checkpoint::load_meta(&snap).unwrap();
        assert_eq!((meta.train.epochs, meta.log.len()), (epoch, epoch), "{}", snap.display());
        assert!(meta.model.k_full_w > 0.0 && meta.model.k_full_w <= 1.0);
    }
    let bytes = |p: std::path::PathBuf| std::fs::read(p.join(mars_policy::checkpoint::WEIGHTS_FILE)).unwrap();
    assert_eq!(bytes(snaps.path(5)), bytes(dir.join("final")), "the last snapshot is the trained model");
    assert_ne!(bytes(snaps.path(2)), bytes(dir.join("final")), "an early snapshot is an earlier model");
    let last = mars_policy::checkpoint::load_meta(&snaps.path(5)).unwrap();
    assert_eq!(last.model.k_full_w, t.cfg.model.k_full_w, "calibrated like the final checkpoint");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_demos_are_refused_with_the_demo_named() {
    let cfg = common::tiny_config(PolicyKind::Mars);
    let mut demos = common::forked_demos(8, 12);
    demos[3].actions[2] = vec![f32::NAN, 0.0];
    let e = Dataset::from_demos(&demos, &cfg.model, 5).err().unwrap().to_string();
    assert!(e.contains("demo 3") && e.contains("step 2"), "{e}");
    let mut demos = common::forked_demos(8, 12);
    demos[1].observations[0] = vec![0.0];
    assert!(Dataset::from_demos(&demos, &cfg.model, 5).err().unwrap().to_string().contains("demo 1"));
    assert!(Dataset::from_demos(&[], &cfg.model, 5).is_err());
}
