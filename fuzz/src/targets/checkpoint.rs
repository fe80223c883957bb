//! Checkpoints: `policy.json` on its own, the policy's TOML configuration, and a whole checkpoint (`policy.json`
//! with `model.safetensors`, either one mutated) loaded by the engine, which loads it through mars-policy's checks
//! (the candle model) first. Seeds: every checkpoint in `assets/checkpoints` and every policy TOML in `configs`.

use std::path::Path;

use mars_engine::{Engine, EngineConfig};
use mars_policy::checkpoint::parse_meta;
use mars_policy::config::PolicyConfig;
use rand::rngs::StdRng;

use super::{Seeds, bundle_seeds, generate_bundle, read, split_bundle};
use crate::runner::Target;

const CHECKPOINTS: [&str; 7] = [
    "assets/checkpoints/fr3_pick_cup/mars",
    "assets/checkpoints/fr3_pick_cup/fm",
    "assets/checkpoints/fr3_pick_cup/a2a",
    "assets/checkpoints/r1_lite_pick_vegetable/mars",
    "assets/checkpoints/r1_lite_pick_vegetable/fm",
    "assets/checkpoints/r1_lite_pick_vegetable/a2a",
    "assets/checkpoints/fr3_push_t/mars",
];
const POLICY_TOML: [&str; 4] =
    ["configs/policy.toml", "configs/fr3_policy.toml", "configs/push_t_policy.toml", "configs/r1_lite_policy.toml"];

/// `policy.json`: parsed and validated as every loader does first.
pub struct PolicyJson {
    seeds: Seeds,
}

impl PolicyJson {
    pub fn new() -> Self {
        Self {
            seeds: Seeds { files: CHECKPOINTS.iter().map(|c| read(&format!("{c}/policy.json"))).collect(), text: true },
        }
    }
}

impl Target for PolicyJson {
    fn name(&self) -> &'static str {
        "policy-json"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        self.seeds.pick(rng).1
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        self.seeds.files.clone()
    }

    fn run(&self, input: &[u8]) -> bool {
        let Ok(text) = std::str::from_utf8(input) else { return false };
        let Ok(meta) = parse_meta(Path::new("checkpoint"), text) else { return false };
        let _ = (meta.model.steps_for(0.5), meta.model.steps_for(1.0));
        let cfg = PolicyConfig { kind: meta.kind, model: meta.model, train: meta.train };
        let _ = cfg.validate();
        true
    }
}

/// The policy's TOML configuration (`mars train --config`).
pub struct PolicyToml {
    seeds: Seeds,
}

impl PolicyToml {
    pub fn new() -> Self {
        Self { seeds: Seeds { files: POLICY_TOML.iter().map(|p| read(p)).collect(), text: true } }
    }
}

impl Target for PolicyToml {
    fn name(&self) -> &'static str {
        "policy-toml"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        self.seeds.pick(rng).1
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        self.seeds.files.clone()
    }

    fn run(&self, input: &[u8]) -> bool {
        let Ok(text) = std::str::from_utf8(input) else { return false };
        PolicyConfig::from_toml(text).map(|cfg| cfg.model.steps_for(1.0)).is_ok()
    }
}

/// A whole checkpoint loaded by the engine (and so by mars-policy's loader first), then one call.
pub struct Checkpoint {
    bundles: Vec<Vec<Vec<u8>>>,
}

impl Checkpoint {
    pub fn new() -> Self {
        let bundles = CHECKPOINTS
            .iter()
            .map(|c| vec![read(&format!("{c}/policy.json")), read(&format!("{c}/model.safetensors"))])
            .collect();
        Self { bundles }
    }
}

impl Target for Checkpoint {
    fn name(&self) -> &'static str {
        "checkpoint"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        generate_bundle(rng, &self.bundles, |f| f == 0)
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        bundle_seeds(&self.bundles)
    }

    fn run(&self, input: &[u8]) -> bool {
        let Some((b, f, bytes)) = split_bundle(input, self.bundles.len()) else { return false };
        let (meta, weights) = match f % 2 {
            0 => (bytes, self.bundles[b][1].as_slice()),
            _ => (self.bundles[b][0].as_slice(), bytes),
        };
        let Ok(meta) = std::str::from_utf8(meta) else { return false };
        let cfg = EngineConfig { warmup_calls: 1, ..EngineConfig::with_seed(0) };
        let Ok(mut engine) = Engine::load_from(Path::new("checkpoint"), meta, weights, cfg) else { return false };
        let obs = engine.meta().normalizer.obs.mean.clone();
        let history = engine.meta().normalizer.action.mean.repeat(engine.chunk_len());
        engine.infer(&obs, &history, std::time::Duration::from_millis(50)).is_ok()
    }
}
