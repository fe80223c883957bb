//! The hand-written training step (`mars_policy::grad`) against candle's autograd on the same weights, batch and
//! random draws: every loss term and every parameter's gradient, for each policy kind and variant the trainer
//! has; and a training by hand that learns what one through autograd does.

mod common;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use mars_policy::config::{PolicyConfig, PolicyKind};
use mars_policy::dataset::{Dataset, DatasetTensors};
use mars_policy::grad::{HandStep, HostData};
use mars_policy::train::{Batch, batch_losses, init_model, randn};
use rand::rngs::StdRng;
use rand::{RngCore, SeedableRng};

/// A tiny config of `kind` with batches of 7 and chunks of 4 (the DiT's tokens).
fn config(kind: PolicyKind) -> PolicyConfig {
    let mut cfg = common::tiny_config(kind);
    cfg.model.chunk_len = 4;
    cfg.model.history_len = 4;
    cfg.train.batch_size = 7;
    cfg
}

fn data(cfg: &PolicyConfig) -> DatasetTensors {
    let demos = common::forked_demos(8, 12);
    let data = Dataset::from_demos_with(&demos, &cfg.model, cfg.train.knn_m, None).unwrap();
    data.tensors(&cfg.model, &Device::Cpu).unwrap()
}

/// Every weight drawn afresh (N(0, 0.3²)): the zero-initialised adaLN and output layers would otherwise hide
/// most paths of the gradient.
fn randomise(varmap: &VarMap, seed: u64) {
    let mut rng = StdRng::seed_from_u64(seed);
    let data = varmap.data().lock().unwrap();
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    for name in names {
        let var = &data[name];
        let t = randn(&mut rng, var.dims(), &Device::Cpu).unwrap().affine(0.3, 0.0).unwrap();
        var.set(&t).unwrap();
    }
}

fn close(a: f32, b: f32, what: &str) {
    assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{what}: by hand {a}, autograd {b}");
}

/// One batch by hand and by autograd: loss terms, every gradient, and the generator left in the same state.
fn check(cfg: &PolicyConfig, what: &str) {
    let tensors = data(cfg);
    let (model, varmap) = init_model(cfg, &Device::Cpu).unwrap();
    randomise(&varmap, 11);
    let idx: Vec<u32> = vec![3, 17, 5, 40, 22, 9, 31];
    let batch = Batch::gather(&tensors, &idx).unwrap();
    let mut rng_auto = StdRng::seed_from_u64(9);
    let terms = batch_losses(&model, &batch, cfg, &mut rng_auto).unwrap();
    let grads = terms.total.backward().unwrap();

    let mut hand = HandStep::new(cfg, &varmap).unwrap();
    let mut rng_hand = StdRng::seed_from_u64(9);
    let got = hand.gradients(&HostData::new(&tensors).unwrap(), &idx, &mut rng_hand);
    assert_eq!(rng_hand.next_u64(), rng_auto.next_u64(), "{what}: a different number of random draws");

    let scalar = |t: &Tensor| t.to_scalar::<f32>().unwrap();
    close(got.total, scalar(&terms.total), &format!("{what}: total loss"));
    close(got.fm, scalar(&terms.fm), &format!("{what}: L_fm"));
    assert_eq!(got.rec.is_some(), terms.rec.is_some(), "{what}: L_rec used");
    assert_eq!(got.div.is_some(), terms.div.is_some(), "{what}: L_div used");
    if let (Some(a), Some(b)) = (got.rec, &terms.rec) {
        close(a, scalar(b), &format!("{what}: L_rec"));
    }
    if let (Some(a), Some(b)) = (got.div, &terms.div) {
        assert!(a > 0.0, "{what}: L_div is 0 on this batch, so its gradient is not checked");
        close(a, scalar(b), &format!("{what}: L_div"));
    }
    // The same step on two threads (each a share of the DiT's rows, gradients summed): the same shares as on one
    // thread, so the same sums, bit for bit.
    let mut two = HandStep::new(cfg, &varmap).unwrap();
    two.set_threads(2);
    let again = two.gradients(&HostData::new(&tensors).unwrap(), &idx, &mut StdRng::seed_from_u64(9));
    assert_eq!(again, got, "{what}: loss terms on two threads");
    assert!(two.params.grad == hand.params.grad, "{what}: gradients on two threads");

    let data = varmap.data().lock().unwrap();
    let mut names: Vec<&str> = hand.params.names().collect();
    names.sort();
    assert_eq!(names.len(), data.len(), "{what}: parameters");
    for name in names {
        let want = grads.get(&data[name]).map(|g| g.flatten_all().unwrap().to_vec1::<f32>().unwrap());
        let got = hand.params.grad_of(name).unwrap();
        let want = want.unwrap_or_else(|| vec![0.0; got.len()]);
        let norm = want.iter().map(|v| v * v).sum::<f32>().sqrt();
        let err = got.iter().zip(&want).map(|(a, b)| (a - b) * (a - b)).sum::<f32>().sqrt();
        assert!(err <= 1e-4 * norm + 1e-6, "{what}: gradient of {name} off by {err} (norm {norm})");
    }
}

#[test]
fn mars_gradients_match_autograd() {
    check(&config(PolicyKind::Mars), "MARS");
}

#[test]
fn mars_with_the_history_in_the_scheduler_matches_autograd() {
    let mut cfg = config(PolicyKind::Mars);
    cfg.model.scheduler_uses_history = true;
    check(&cfg, "MARS, scheduler sees the history");
}

#[test]
fn a_velocity_field_that_sees_the_history_matches_autograd() {
    for kind in [PolicyKind::Mars, PolicyKind::Fm] {
        let mut cfg = config(kind);
        cfg.model.velocity_uses_history = true;
        check(&cfg, &format!("{kind}, velocity field sees the history"));
    }
    let mut cfg = config(PolicyKind::Mars);
    (cfg.model.velocity_uses_history, cfg.model.scheduler_uses_history) = (true, true);
    check(&cfg, "MARS, both see the history");
}

#[test]
fn baseline_gradients_match_autograd() {
    check(&config(PolicyKind::Fm), "FM");
    check(&config(PolicyKind::A2a), "A2A");
    check(&config(PolicyKind::NoiseA2a), "noise A2A");
    let mut cfg = config(PolicyKind::Fm);
    cfg.train.fm_lambda_rec = Some(0.5);
    check(&cfg, "FM with L_rec");
}
