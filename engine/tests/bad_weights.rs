//! The engine reads the weights itself (no candle model is built at load): every way `model.safetensors` can
//! disagree with `policy.json` is refused at load by an error that names the tensor, never run and never a panic.

mod common;

use candle_core::{DType, Device, Tensor};
use common::trained_checkpoint;
use mars_engine::{Engine, EngineConfig};
use mars_policy::checkpoint::{META_FILE, WEIGHTS_FILE};
use mars_policy::config::PolicyKind;
use std::collections::HashMap;
use std::path::Path;

fn load_err(dir: &Path) -> String {
    match Engine::load(dir, EngineConfig::default()) {
        Ok(_) => panic!("bad checkpoint {} loaded", dir.display()),
        Err(e) => {
            println!("refused: {e}");
            e.to_string()
        }
    }
}

type Edit = dyn Fn(&mut HashMap<String, Tensor>);

fn rewrite_weights(dir: &Path, edit: &Edit) {
    let path = dir.join(WEIGHTS_FILE);
    let mut tensors = candle_core::safetensors::load(&path, &Device::Cpu).unwrap();
    edit(&mut tensors);
    candle_core::safetensors::save(&tensors, &path).unwrap();
}

#[test]
fn truncated_or_garbage_weights_are_reported_as_corrupt() {
    let dir = trained_checkpoint(PolicyKind::Mars, "bw-trunc", |_| {});
    let path = dir.join(WEIGHTS_FILE);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let e = load_err(&dir);
    assert!(e.contains("corrupt or truncated") && e.contains(WEIGHTS_FILE), "{e}");
    std::fs::write(&path, b"\xff\xff\xff\xff\xff\xff\xff\x7fnot a safetensors file").unwrap();
    assert!(load_err(&dir).contains("corrupt or truncated"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_wrong_shape_a_missing_tensor_a_nan_or_a_wrong_dtype_is_named() {
    let dir = trained_checkpoint(PolicyKind::Mars, "bw-each", |_| {});
    let original = std::fs::read(dir.join(WEIGHTS_FILE)).unwrap();
    let cases: [(&str, &Edit, &str); 4] = [
        (
            "velocity.action_out.weight",
            &|t| {
                let zeros = Tensor::zeros((3, 5), DType::F32, &Device::Cpu).unwrap();
                t.insert("velocity.action_out.weight".into(), zeros);
            },
            "shape",
        ),
        (
            "scheduler.mlp.fc2.bias",
            &|t| {
                t.remove("scheduler.mlp.fc2.bias");
            },
            "missing",
        ),
        (
            "velocity.cond_in.bias",
            &|t| {
                let w = &t["velocity.cond_in.bias"];
                let nan = (w.ones_like().unwrap() * f64::NAN).unwrap();
                t.insert("velocity.cond_in.bias".into(), nan);
            },
            "NaN",
        ),
        (
            "encoder.state_mlp.fc1.weight",
            &|t| {
                let w = t["encoder.state_mlp.fc1.weight"].to_dtype(DType::F64).unwrap();
                t.insert("encoder.state_mlp.fc1.weight".into(), w);
            },
            "dtype",
        ),
    ];
    for (name, edit, problem) in cases {
        std::fs::write(dir.join(WEIGHTS_FILE), &original).unwrap();
        rewrite_weights(&dir, edit);
        let e = load_err(&dir);
        assert!(e.contains(name) && e.contains(problem), "{name}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn weights_of_another_kind_are_refused_not_run_as_this_one() {
    // A MARS checkpoint relabelled FM has every tensor FM reads, and a scheduler FM does not have: run as FM it
    // would sample something no one trained, so the extra tensor is refused by name.
    let dir = trained_checkpoint(PolicyKind::Mars, "bw-kind", |_| {});
    let meta = std::fs::read_to_string(dir.join(META_FILE)).unwrap().replace("\"kind\": \"mars\"", "\"kind\": \"fm\"");
    std::fs::write(dir.join(META_FILE), meta).unwrap();
    let e = load_err(&dir);
    assert!(e.contains("scheduler.") && e.contains("not part of a `fm` model"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
    // And FM relabelled MARS lacks the scheduler.
    let dir = trained_checkpoint(PolicyKind::Fm, "bw-kind-fm", |_| {});
    let meta = std::fs::read_to_string(dir.join(META_FILE)).unwrap().replace("\"kind\": \"fm\"", "\"kind\": \"mars\"");
    std::fs::write(dir.join(META_FILE), meta).unwrap();
    let e = load_err(&dir);
    assert!(e.contains("scheduler.") && e.contains("missing"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
