//! Checkpoints: `policy.json` on its own, the policy's TOML configuration, and a whole checkpoint (`policy.json`
//! with `model.safetensors`, either one mutated) loaded by both readers of the weights: the engine's own (what
//! marsd runs) and the trainer's candle model (what `mars eval` runs). Seeds: every checkpoint in
//! `assets/checkpoints` and every policy TOML in `configs`.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use mars_engine::{Engine, EngineConfig};
use mars_policy_format::checkpoint::parse_meta;
use mars_policy_format::config::PolicyConfig;

use super::{Bundles, read, text};
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
pub fn policy_json() -> Arc<dyn Target> {
    let files = CHECKPOINTS.iter().map(|c| read(&format!("{c}/policy.json"))).collect();
    Bundles::of_files("policy-json", files, true, |_, bytes| {
        let Some(Ok(meta)) = text(bytes).map(|t| parse_meta(Path::new("checkpoint"), t)) else { return false };
        let _ = (meta.model.steps_for(0.5), meta.model.steps_for(1.0));
        PolicyConfig { kind: meta.kind, model: meta.model, train: meta.train }.validate().is_ok()
    })
}

/// The policy's TOML configuration (`mars train --config`).
pub fn policy_toml() -> Arc<dyn Target> {
    let files = POLICY_TOML.iter().map(|p| read(p)).collect();
    Bundles::of_files("policy-toml", files, true, |_, bytes| {
        let Some(Ok(cfg)) = text(bytes).map(PolicyConfig::from_toml) else { return false };
        cfg.model.steps_for(1.0) > 0
    })
}

/// A whole checkpoint loaded by the trainer's loader, then by the engine, then one call.
pub fn checkpoint() -> Arc<dyn Target> {
    let bundles: Vec<Vec<Vec<u8>>> = CHECKPOINTS
        .iter()
        .map(|c| vec![read(&format!("{c}/policy.json")), read(&format!("{c}/model.safetensors"))])
        .collect();
    let seeds = bundles.clone();
    let decode = move |b: usize, f: usize, bytes: &[u8]| {
        let (meta, weights) = if f == 0 { (bytes, seeds[b][1].as_slice()) } else { (seeds[b][0].as_slice(), bytes) };
        let Some(meta) = text(meta) else { return false };
        let _ = mars_policy::checkpoint::load_from(Path::new("checkpoint"), meta, weights, &candle_core::Device::Cpu);
        let cfg = EngineConfig { warmup_calls: 1, ..EngineConfig::with_seed(0) };
        let Ok(mut engine) = Engine::load_from(Path::new("checkpoint"), meta, weights, cfg) else { return false };
        let obs = engine.meta().normalizer.obs.mean.clone();
        let history = engine.meta().normalizer.action.mean.repeat(engine.chunk_len());
        engine.infer(&obs, &history, Duration::from_millis(50)).is_ok()
    };
    Arc::new(Bundles { name: "checkpoint", bundles, text: |f| f == 0, decode: Box::new(decode) })
}
