//! Shared helpers for the policy tests: a tiny config and synthetic demos with a two-way split.

#![allow(dead_code)]

use mars_policy::config::{PolicyConfig, PolicyKind};
use mars_policy::demo::Demo;

/// The shipped config, shrunk so a test trains in seconds on 2 cores.
pub fn tiny_config(kind: PolicyKind) -> PolicyConfig {
    let mut cfg =
        PolicyConfig::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/policy.toml")))
            .expect("shipped config loads");
    cfg.kind = kind;
    cfg.model.encoder = mars_policy::config::EncoderConfig::StateMlp { hidden: 32 };
    cfg.model.obs_embed_dim = 32;
    cfg.model.scheduler_hidden = 32;
    cfg.model.dit_width = 32;
    cfg.model.dit_depth = 2;
    cfg.model.dit_heads = 2;
    cfg.model.dit_mlp_ratio = 2;
    cfg.train.epochs = 3;
    cfg.train.knn_m = 5;
    cfg.train.lr = 1e-3;
    cfg
}

/// Straight-line 2-D demos from the origin that go up-right or down-right: unimodal at first, then a fork.
pub fn forked_demos(n: usize, steps: usize) -> Vec<Demo> {
    (0..n)
        .map(|i| {
            let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
            let jitter = (i as f32 * 0.37).sin() * 0.01;
            let mut pos = [0.0f32, 0.0];
            let (mut observations, mut actions) = (Vec::new(), Vec::new());
            for t in 0..steps {
                observations.push(pos.to_vec());
                let y = if t < steps / 2 { jitter } else { sign * 0.1 * (t - steps / 2) as f32 + jitter };
                let target = [0.1 * (t + 1) as f32, y];
                actions.push(target.to_vec());
                pos = target;
            }
            Demo { observations, actions, rest_action: vec![0.0, 0.0], mode: Some(i % 2) }
        })
        .collect()
}
