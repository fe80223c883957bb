//! Bad input is an error value, never a panic, and leaves the engine as it was; a checkpoint the engine
//! cannot run is refused at load with an error that says why.

mod common;

use common::{inputs, perturbed_checkpoint, tiny_config, trained_checkpoint};
use mars_engine::{Engine, EngineConfig, EngineError, Input, LoadError};
use mars_policy::checkpoint::META_FILE;
use mars_policy::config::PolicyKind;
use rand::SeedableRng;
use rand::rngs::StdRng;
use std::path::Path;
use std::time::Duration;

fn load_err(dir: &Path, cfg: EngineConfig) -> String {
    match Engine::load(dir, cfg) {
        Ok(_) => panic!("{} loaded", dir.display()),
        Err(e) => {
            println!("refused: {e}");
            e.to_string()
        }
    }
}

fn edit_meta(dir: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = dir.join(META_FILE);
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut meta);
    std::fs::write(&path, serde_json::to_string(&meta).unwrap()).unwrap();
}

#[test]
fn bad_inputs_are_errors_and_change_nothing() {
    let dir = trained_checkpoint(PolicyKind::Mars, "err-inputs", |_| {});
    let mut engine = Engine::load(&dir, EngineConfig::with_seed(9)).unwrap();
    let mut fresh = Engine::load(&dir, EngineConfig::with_seed(9)).unwrap();
    let (o, cd) = (engine.obs_dim(), engine.chunk_len() * engine.action_dim());
    let (obs, hist) = inputs(&mut StdRng::seed_from_u64(1), o, cd);
    let with = |v: &[f32], i: usize, x: f32| {
        let mut v = v.to_vec();
        v[i] = x;
        v
    };
    let max = Duration::MAX;
    use EngineError::*;
    use Input::*;

    let e = engine.infer(&with(&obs, 1, f32::NAN), &hist, max).unwrap_err();
    assert!(matches!(e, NonFinite { what: Observation, index: 1, value } if value.is_nan()), "{e:?}");
    let e = engine.infer(&with(&obs, 0, f32::INFINITY), &hist, max).unwrap_err();
    assert_eq!(e, NonFinite { what: Observation, index: 0, value: f32::INFINITY });
    let e = engine.infer(&obs, &with(&hist, cd - 1, f32::NEG_INFINITY), max).unwrap_err();
    assert_eq!(e, NonFinite { what: History, index: cd - 1, value: f32::NEG_INFINITY });
    let e = engine.infer(&obs, &with(&hist, 3, f32::NAN), max).unwrap_err();
    assert!(matches!(e, NonFinite { what: History, index: 3, .. }));
    assert_eq!(engine.infer(&obs[1..], &hist, max).unwrap_err(), Length { what: Observation, got: o - 1, want: o });
    assert_eq!(engine.infer(&[], &hist, max).unwrap_err(), Length { what: Observation, got: 0, want: o });
    let long = [hist.as_slice(), &[0.0]].concat();
    assert_eq!(engine.infer(&obs, &long, max).unwrap_err(), Length { what: History, got: cd + 1, want: cd });
    let e = engine.infer_with(&obs, &hist, Some(&hist[..cd - 2]), None).unwrap_err();
    assert_eq!(e, Length { what: Noise, got: cd - 2, want: cd });
    let e = engine.infer_with(&obs, &hist, Some(&with(&hist, 0, f32::NAN)), None).unwrap_err();
    assert!(matches!(e, NonFinite { what: Noise, index: 0, .. }));
    assert_eq!(engine.infer_with(&obs, &hist, None, Some(0)).unwrap_err(), Steps { k: 0, k_max: 10 });
    assert_eq!(engine.infer_with(&obs, &hist, None, Some(11)).unwrap_err(), Steps { k: 11, k_max: 10 });
    // Both orders of a length and a non-finite problem report the length (checked first).
    let e = engine.infer(&with(&obs, 0, f32::NAN)[1..], &hist, max).unwrap_err();
    assert!(matches!(e, Length { .. }));
    assert!(e.to_string().contains("observation has 1 values, the engine expects 2"), "{e}");

    // Nothing was drawn from the generator: the next good call equals a fresh engine's first.
    let a = engine.infer(&obs, &hist, max).unwrap().chunk.to_vec();
    let b = fresh.infer(&obs, &hist, max).unwrap().chunk.to_vec();
    assert_eq!(a, b);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Finite inputs far outside the training range overflow inside the network: an error, not a NaN chunk.
#[test]
fn an_overflowing_network_reports_an_error_not_a_nan_chunk() {
    let dir = trained_checkpoint(PolicyKind::Mars, "err-overflow", |_| {});
    let mut engine = Engine::load(&dir, EngineConfig::default()).unwrap();
    let hist = vec![0.0; engine.chunk_len() * engine.action_dim()];
    let huge = [f32::MAX, -f32::MAX];
    assert_eq!(engine.infer(&huge, &hist, Duration::MAX).unwrap_err(), EngineError::NonFiniteOutput);
    let ok = engine.infer(&[0.1, 0.2], &hist, Duration::MAX).unwrap();
    assert!(ok.chunk.iter().all(|v| v.is_finite()));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn checkpoints_the_engine_cannot_run_are_refused_at_load() {
    let cfg = EngineConfig::default();
    let e = load_err(Path::new("/nonexistent/mars-engine-ckpt"), cfg);
    assert!(e.contains("cannot read") && e.contains(META_FILE), "{e}");

    // Another shape: the config says width 64, the weights are 32 wide.
    let dir = trained_checkpoint(PolicyKind::Fm, "err-shape", |_| {});
    edit_meta(&dir, |m| m["model"]["dit_width"] = 64.into());
    let e = load_err(&dir, cfg);
    assert!(e.contains("velocity.") && e.contains("shape"), "{e}");

    // An encoder type this build does not know (e.g. a future image encoder).
    edit_meta(&dir, |m| {
        m["model"]["dit_width"] = 32.into();
        m["model"]["encoder"] = serde_json::json!({ "type": "resnet18", "pretrained": true });
    });
    let e = load_err(&dir, cfg);
    assert!(e.contains("resnet18") && e.contains("encoder") || e.contains("unknown variant"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();

    // A valid checkpoint whose time embedding the model cannot evaluate (odd width > 32).
    let mut odd = tiny_config(PolicyKind::A2a);
    odd.model.dit_width = 33;
    odd.model.dit_heads = 3;
    let dir = perturbed_checkpoint(&odd, "err-odd");
    let e = Engine::load(&dir, cfg).err().expect("odd width loaded");
    assert!(matches!(e, LoadError::Unsupported { .. }), "{e}");
    assert!(e.to_string().contains("dit_width 33"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();

    // The Fig. S3 ablation's FM with a scaled source: the engine samples N(0, I) only, so it refuses.
    let mut wide = tiny_config(PolicyKind::Fm);
    wide.model.source_std = 2.0;
    let dir = perturbed_checkpoint(&wide, "err-source-std");
    let e = Engine::load(&dir, cfg).err().expect("scaled source loaded");
    assert!(matches!(e, LoadError::Unsupported { .. }) && e.to_string().contains("source_std"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn invalid_engine_settings_are_refused() {
    let dir = trained_checkpoint(PolicyKind::A2a, "err-settings", |_| {});
    let e = load_err(&dir, EngineConfig { threads: 0, ..EngineConfig::default() });
    assert!(e.contains("threads"), "{e}");
    let e = load_err(&dir, EngineConfig { warmup_calls: 0, ..EngineConfig::default() });
    assert!(e.contains("warmup_calls"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
