//! Each loss on small hand-computed cases, and the stop-gradients the paper prescribes.

mod common;

use candle_core::{Device, Tensor, Var};
use mars_policy::config::PolicyKind;
use mars_policy::losses;
use mars_policy::model::{MarsModel, steps_for};

fn t(v: &[f32], shape: &[usize]) -> Tensor {
    Tensor::from_slice(v, shape, &Device::Cpu).unwrap()
}

fn scalar(x: &Tensor) -> f32 {
    x.to_scalar::<f32>().unwrap()
}

#[test]
fn flow_matching_is_mse_to_the_straight_path_velocity() {
    // a1 − a0 = [2, -1, 0, 4]; v = [1, -1, 1, 4] → squared errors 1, 0, 1, 0 → mean 0.5
    let a0 = t(&[0., 1., 2., 0.], &[1, 2, 2]);
    let a1 = t(&[2., 0., 2., 4.], &[1, 2, 2]);
    let v = t(&[1., -1., 1., 4.], &[1, 2, 2]);
    assert!((scalar(&losses::flow_matching(&v, &a0, &a1).unwrap()) - 0.5).abs() < 1e-6);
}

#[test]
fn reconstruction_weights_each_dimension_by_one_minus_w() {
    // B=1, C=2, D=2. |â1 − a1| = [[1, 2], [3, 4]] → mean over C per dim = [2, 3].
    // w = [0.25, 1.0] → (1−w) = [0.75, 0] → (0.75·2 + 0·3) / 2 = 0.75
    let a1_hat = t(&[1., 2., 3., 4.], &[1, 2, 2]);
    let a1 = t(&[0., 0., 0., 0.], &[1, 2, 2]);
    let w = t(&[0.25, 1.0], &[1, 2]);
    assert!((scalar(&losses::reconstruction(&a1_hat, &a1, &w).unwrap()) - 0.75).abs() < 1e-6);
}

#[test]
fn dispersion_and_diversity_by_hand() {
    // One sample, C=1, D=2, two neighbours: centre [0, 0], neighbours [1, 4] and [3, 0]
    // S = mean |diff| = [(1+3)/2, (4+0)/2] = [2, 2]
    let centre = t(&[0., 0.], &[1, 1, 2]);
    let nb = t(&[1., 4., 3., 0.], &[1, 2, 1, 2]);
    let s = losses::dispersion(&centre, &nb).unwrap();
    assert_eq!(s.flatten_all().unwrap().to_vec1::<f32>().unwrap(), vec![2.0, 2.0]);
    // S_next = [3, 1]: ReLU([1, -1]) = [1, 0] → mean 0.5
    let s_next = t(&[3., 1.], &[1, 2]);
    assert!((scalar(&losses::diversity(&s_next, &s).unwrap()) - 0.5).abs() < 1e-6);
}

#[test]
fn neighbour_sources_use_the_samples_own_w() {
    // w = [0, 1]: dim 0 is pure history, dim 1 pure noise.
    let hist = t(&[5., 5., 7., 7.], &[1, 2, 1, 2]);
    let eps = t(&[0.1, 0.2, 0.3, 0.4], &[1, 2, 1, 2]);
    let w = t(&[0., 1.], &[1, 2]);
    let out = losses::neighbour_sources(&hist, &w, &eps).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(out, vec![5., 0.2, 7., 0.4]);
}

#[test]
fn source_interpolates_history_and_noise_per_dimension() {
    let hist = t(&[1., 1., 1., 1.], &[1, 2, 2]);
    let eps = t(&[3., 3., 3., 3.], &[1, 2, 2]);
    let w = t(&[0.5, 0.0], &[1, 2]);
    let a0 = MarsModel::source(&hist, &w, &eps).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(a0, vec![2., 1., 2., 1.]);
}

#[test]
fn reconstruction_gives_no_gradient_to_its_weight() {
    let w = Var::new(&[0.3f32, 0.6], &Device::Cpu).unwrap();
    let a1_hat = Var::new(&[[1f32, 2.], [3., 4.]], &Device::Cpu).unwrap();
    let a1 = Tensor::zeros((1, 2, 2), candle_core::DType::F32, &Device::Cpu).unwrap();
    let loss = losses::reconstruction(&a1_hat.unsqueeze(0).unwrap(), &a1, &w.unsqueeze(0).unwrap()).unwrap();
    let grads = loss.backward().unwrap();
    assert!(grads.get(&w).is_none(), "(1 − w) must be detached");
    assert!(grads.get(&a1_hat).is_some(), "the reconstruction itself must still be trained");
}

#[test]
fn k_of_w_rule() {
    assert_eq!(steps_for(0.0, 10), 1, "deterministic samples still take one step");
    assert_eq!(steps_for(0.05, 10), 1);
    assert_eq!(steps_for(0.1, 10), 1, "0.1·10 is one step despite float rounding");
    assert_eq!(steps_for(0.11, 10), 2, "rounded up");
    assert_eq!(steps_for(0.55, 10), 6);
    assert_eq!(steps_for(1.0, 10), 10);
    assert_eq!(steps_for(1.5, 10), 10, "clamped to K_max");
    assert_eq!(steps_for(f32::NAN, 10), 10, "a NaN weight takes the safe, full budget");
    assert_eq!(PolicyKind::Fm.fixed_w(&common::tiny_config(PolicyKind::Fm).model), Some(1.0));
}

#[test]
fn calibrated_k_gives_the_full_budget_from_k_full_w_on() {
    let mut m = common::tiny_config(PolicyKind::Mars).model;
    assert_eq!(m.k_full_w, 1.0, "the paper's K(w) unless calibrated");
    m.k_max = 10;
    m.k_full_w = 0.4;
    assert_eq!(m.steps_for(0.04), 1);
    assert_eq!(m.steps_for(0.2), 5);
    assert_eq!(m.steps_for(0.4), 10);
    assert_eq!(m.steps_for(0.9), 10, "clamped to K_max");
}

#[test]
fn quantile_is_nearest_rank() {
    let mut v = vec![0.5f32, 0.1, 0.4, 0.2, 0.3];
    assert_eq!(mars_policy::stats::quantile(&mut v, 1.0), 0.5);
    assert_eq!(mars_policy::stats::quantile(&mut v, 0.5), 0.3);
    assert_eq!(mars_policy::stats::quantile(&mut v, 0.01), 0.1);
    assert_eq!(mars_policy::stats::quantile(&mut [], 0.5), 0.0);
}
