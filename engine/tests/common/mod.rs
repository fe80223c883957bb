//! Shared helpers: checkpoints of trained-then-perturbed tiny models of every kind, and test inputs.
//!
//! Freshly initialised models prove nothing (adaLN-Zero makes their velocity exactly 0), and a few epochs
//! of training leave the zero-initialised layers small; so after training every weight gets Gaussian noise,
//! which makes every gate, shift and scale matter.

#![allow(dead_code)]

#[path = "../../../policy/tests/common.rs"]
mod policy_common;

use candle_core::{Device, Tensor};
use mars_policy::config::{PolicyConfig, PolicyKind};
use mars_policy::dataset::Dataset;
use mars_policy::train::{Trained, init_model, randn, train};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use std::path::PathBuf;

#[allow(unused_imports)] // each test binary uses some of them
pub use policy_common::{forked_demos, forked_image_demos, tiny_config, vision_encoder};

/// Adds N(0, σ²) to every weight, in place (the model shares its variables with the `VarMap`).
pub fn perturb(trained: &Trained, sigma: f64, seed: u64) {
    let mut rng = StdRng::seed_from_u64(seed);
    let data = trained.varmap.data().lock().unwrap();
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    for name in names {
        let var = &data[name];
        let noise = randn(&mut rng, var.dims(), &Device::Cpu).unwrap();
        var.set(&(var.as_tensor() + (noise * sigma).unwrap()).unwrap()).unwrap();
    }
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mars-engine-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A tiny `kind` model trained for 2 epochs on forked demos, perturbed, saved; `tweak` edits the config.
pub fn trained_checkpoint(kind: PolicyKind, name: &str, tweak: impl FnOnce(&mut PolicyConfig)) -> PathBuf {
    let mut cfg = tiny_config(kind);
    cfg.train.epochs = 2;
    tweak(&mut cfg);
    let trained = train(&cfg, &forked_demos(16, 16), false).unwrap();
    perturb(&trained, 0.05, 11);
    let dir = temp_dir(name);
    trained.save(&dir).unwrap();
    dir
}

/// An untrained model of any config (even one training could not run), perturbed, with the demos'
/// normalisation; for shapes that training would make slow or impossible.
pub fn perturbed_checkpoint(cfg: &PolicyConfig, name: &str) -> PathBuf {
    let (model, varmap) = init_model(cfg, &Device::Cpu).unwrap();
    let data = Dataset::from_demos(&forked_demos(8, 16), &cfg.model, 2).unwrap();
    let trained = Trained {
        cfg: cfg.clone(),
        model,
        varmap,
        normalizer: data.normalizer,
        log: Vec::new(),
        epoch_seconds: Vec::new(),
    };
    perturb(&trained, 0.05, 12);
    let dir = temp_dir(name);
    trained.save(&dir).unwrap();
    dir
}

/// [`perturbed_checkpoint`] for a vision config, normalised on image demos of `side` px.
pub fn perturbed_vision_checkpoint(cfg: &PolicyConfig, side: usize, name: &str) -> PathBuf {
    let (model, varmap) = init_model(cfg, &Device::Cpu).unwrap();
    let data = Dataset::from_demos(&forked_image_demos(8, 16, side), &cfg.model, 2).unwrap();
    let trained = Trained {
        cfg: cfg.clone(),
        model,
        varmap,
        normalizer: data.normalizer,
        log: Vec::new(),
        epoch_seconds: Vec::new(),
    };
    perturb(&trained, 0.05, 12);
    let dir = temp_dir(name);
    trained.save(&dir).unwrap();
    dir
}

/// A random observation and history in task units, near the demos' range.
pub fn inputs(rng: &mut StdRng, obs_dim: usize, history_values: usize) -> (Vec<f32>, Vec<f32>) {
    let obs = normal(rng, obs_dim).iter().map(|v| 0.5 * v).collect();
    let hist = normal(rng, history_values).iter().map(|v| 0.5 * v).collect();
    (obs, hist)
}

pub fn normal(rng: &mut StdRng, n: usize) -> Vec<f32> {
    (0..n).map(|_| <StandardNormal as Distribution<f32>>::sample(&StandardNormal, rng)).collect()
}

pub fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

pub fn to_vec(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
}
