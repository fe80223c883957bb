//! Shared helpers for the policy tests: a tiny config and synthetic demos with a two-way split.

#![allow(dead_code)]

use mars_policy::config::{PolicyConfig, PolicyKind};
use mars_tasks::demo::Demo;

/// The shipped config, shrunk so a test trains in seconds on 2 cores.
pub fn tiny_config(kind: PolicyKind) -> PolicyConfig {
    let mut cfg =
        PolicyConfig::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/policy.toml")))
            .expect("shipped config loads")
            .shrunk(32, 2);
    cfg.kind = kind;
    (cfg.model.dit_heads, cfg.model.dit_mlp_ratio) = (2, 2);
    (cfg.train.epochs, cfg.train.knn_m, cfg.train.lr) = (3, 5, 1e-3);
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

/// [`forked_demos`] seen by a camera: the observation is the 2-D position followed by a `side` × `side` RGB image
/// (channels last, values in [0, 1]) of a grey table with an 8 × 8 marker that moves right with the position.
/// The marker is red on the demos that fork up and blue on those that fork down, from the first step on: only
/// the image tells which way a demo will go.
pub fn forked_image_demos(n: usize, steps: usize, side: usize) -> Vec<Demo> {
    let mut demos = forked_demos(n, steps);
    for (i, d) in demos.iter_mut().enumerate() {
        let colour = if i % 2 == 0 { [1.0, 0.1, 0.1] } else { [0.1, 0.1, 1.0] };
        for (t, o) in d.observations.iter_mut().enumerate() {
            let mut image = vec![0.5f32; side * side * 3];
            let left = 2 + (t * (side - 12)) / steps.max(1);
            for y in side / 2 - 4..side / 2 + 4 {
                for x in left..left + 8 {
                    image[(y * side + x) * 3..][..3].copy_from_slice(&colour);
                }
            }
            o.extend_from_slice(&image);
        }
    }
    demos
}

/// The vision encoder for [`forked_image_demos`]: one camera, a narrow ResNet-18 (width 8) over a `crop` × `crop`
/// crop with `head`.
pub fn vision_encoder(
    side: usize,
    crop: usize,
    head: mars_policy::nn::resnet::ResNetHead,
) -> mars_policy::config::EncoderConfig {
    use mars_policy::nn::resnet::ResNetConfig;
    mars_policy::config::EncoderConfig::Vision(mars_policy::config::VisionConfig {
        cameras: 1,
        image_height: side,
        image_width: side,
        crop_height: crop,
        crop_width: crop,
        resnet: ResNetConfig { width: 8, head },
        hidden: 32,
    })
}
