//! Checkpoint round trip, and every way a checkpoint can be bad gives an error naming what is wrong.

mod common;

use candle_core::{Device, Tensor};
use mars_policy::checkpoint::{self, META_FILE, WEIGHTS_FILE};
use mars_policy::config::PolicyKind;
use mars_policy::inference::MarsPolicy;
use mars_policy::train::train;
use mars_tasks::rollout::ChunkPolicy;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn trained_dir(kind: PolicyKind, name: &str) -> PathBuf {
    let mut cfg = common::tiny_config(kind);
    cfg.train.epochs = 1;
    let trained = train(&cfg, &common::forked_demos(8, 12), false).unwrap();
    let dir = std::env::temp_dir().join(format!("mars-ckpt-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    trained.save(&dir).unwrap();
    dir
}

fn load_err(dir: &Path) -> String {
    match checkpoint::load(dir, &Device::Cpu) {
        Ok(_) => panic!("bad checkpoint {} loaded", dir.display()),
        Err(e) => e.to_string(),
    }
}

fn rewrite_weights(dir: &Path, edit: impl Fn(&mut HashMap<String, Tensor>)) {
    let path = dir.join(WEIGHTS_FILE);
    let mut tensors = candle_core::safetensors::load(&path, &Device::Cpu).unwrap();
    edit(&mut tensors);
    candle_core::safetensors::save(&tensors, &path).unwrap();
}

#[test]
fn round_trip_gives_identical_predictions() {
    for kind in PolicyKind::ALL {
        let mut cfg = common::tiny_config(kind);
        cfg.train.epochs = 1;
        let demos = common::forked_demos(8, 12);
        let trained = train(&cfg, &demos, false).unwrap();
        let dir = std::env::temp_dir().join(format!("mars-ckpt-{}-rt-{kind}", std::process::id()));
        trained.save(&dir).unwrap();
        let mut original = MarsPolicy::from_trained(trained, 3);
        let (mut loaded, meta) = MarsPolicy::load(&dir, 3).unwrap();
        assert_eq!(meta.kind, kind);
        assert_eq!(meta.log.len(), 1);
        let hist: Vec<f32> = demos[0].actions[..8].iter().flatten().copied().collect();
        let a = original.predict(&demos[0].observations[8], &hist).unwrap();
        let b = loaded.predict(&demos[0].observations[8], &hist).unwrap();
        assert_eq!(a, b, "{kind}: loaded checkpoint predicts differently");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[test]
fn truncated_weights_are_reported_as_corrupt() {
    let dir = trained_dir(PolicyKind::Mars, "trunc");
    let path = dir.join(WEIGHTS_FILE);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let e = load_err(&dir);
    assert!(e.contains("corrupt or truncated") && e.contains(WEIGHTS_FILE), "{e}");
}

#[test]
fn garbage_weights_are_reported_as_corrupt() {
    let dir = trained_dir(PolicyKind::Mars, "garbage");
    std::fs::write(dir.join(WEIGHTS_FILE), b"\xff\xff\xff\xff\xff\xff\xff\x7fnot a safetensors file").unwrap();
    assert!(load_err(&dir).contains("corrupt or truncated"));
}

#[test]
fn wrong_shape_names_the_tensor() {
    let dir = trained_dir(PolicyKind::Mars, "shape");
    rewrite_weights(&dir, |t| {
        t.insert(
            "velocity.action_out.weight".into(),
            Tensor::zeros((3, 5), candle_core::DType::F32, &Device::Cpu).unwrap(),
        );
    });
    let e = load_err(&dir);
    assert!(e.contains("velocity.action_out.weight") && e.contains("shape"), "{e}");
}

#[test]
fn missing_tensor_is_named() {
    let dir = trained_dir(PolicyKind::Mars, "missing");
    rewrite_weights(&dir, |t| {
        t.remove("scheduler.mlp.fc2.bias");
    });
    let e = load_err(&dir);
    assert!(e.contains("scheduler.mlp.fc2.bias") && e.contains("missing"), "{e}");
}

#[test]
fn extra_tensor_from_another_kind_is_named() {
    // An FM checkpoint has no scheduler; claiming it is MARS (or vice versa) must not load silently.
    let dir = trained_dir(PolicyKind::Mars, "kind");
    let meta = std::fs::read_to_string(dir.join(META_FILE)).unwrap().replace("\"kind\": \"mars\"", "\"kind\": \"fm\"");
    std::fs::write(dir.join(META_FILE), meta).unwrap();
    let e = load_err(&dir);
    assert!(e.contains("scheduler.") && e.contains("not part of"), "{e}");
}

#[test]
fn nan_weights_and_wrong_dtype_are_named() {
    let dir = trained_dir(PolicyKind::A2a, "nan");
    rewrite_weights(&dir, |t| {
        let w = t["velocity.cond_in.bias"].clone();
        let nan = (w.ones_like().unwrap() * f64::NAN).unwrap();
        t.insert("velocity.cond_in.bias".into(), nan);
    });
    let e = load_err(&dir);
    assert!(e.contains("velocity.cond_in.bias") && e.contains("NaN"), "{e}");
    let dir = trained_dir(PolicyKind::A2a, "dtype");
    rewrite_weights(&dir, |t| {
        let w = t["velocity.cond_in.bias"].to_dtype(candle_core::DType::F64).unwrap();
        t.insert("velocity.cond_in.bias".into(), w);
    });
    let e = load_err(&dir);
    assert!(e.contains("velocity.cond_in.bias") && e.contains("dtype"), "{e}");
}

#[test]
fn bad_or_missing_meta_is_reported() {
    let dir = trained_dir(PolicyKind::Fm, "meta");
    let good = std::fs::read_to_string(dir.join(META_FILE)).unwrap();
    std::fs::write(dir.join(META_FILE), &good[..good.len() / 3]).unwrap();
    assert!(load_err(&dir).contains(META_FILE));
    let bad_std = good.replacen("\"std\": [", "\"std\": [-1.0, ", 1);
    std::fs::write(dir.join(META_FILE), bad_std).unwrap();
    assert!(load_err(&dir).contains("statistics"));
    std::fs::remove_file(dir.join(META_FILE)).unwrap();
    assert!(load_err(&dir).contains("cannot read"));
    assert!(load_err(Path::new("/nonexistent/ckpt")).contains("/nonexistent/ckpt"));
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let dir = trained_dir(PolicyKind::Mars, "inputs");
    let (mut p, _) = MarsPolicy::load(&dir, 0).unwrap();
    let hist = vec![0.0f32; 16];
    assert!(p.predict(&[0.0], &hist).unwrap_err().to_string().contains("observation has 1 values"));
    assert!(p.predict(&[0.0, 0.0], &hist[..10]).unwrap_err().to_string().contains("history has 10 values"));
    assert!(p.predict(&[f32::NAN, 0.0], &hist).unwrap_err().to_string().contains("finite"));
    let mut inf_hist = hist.clone();
    inf_hist[3] = f32::INFINITY;
    assert!(p.predict(&[0.0, 0.0], &inf_hist).unwrap_err().to_string().contains("history[3]"));
}
