//! Running `benches/onnx_resnet.py` (the policy's ResNet-18 as an ONNX graph in ONNX Runtime, one thread) on a
//! weights file and an image. Shared by `tests/onnx_peer.rs` and the benchmark.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use mars_policy::nn::resnet::{ResNetConfig, ResNetHead};

pub fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().unwrap()
}

/// The Python of `.ci/franka-sim-venv` (onnx, onnxruntime and safetensors are among the peers it installs), or
/// `MARS_ONNX_PYTHON`.
pub fn python() -> Result<PathBuf, String> {
    if let Some(p) = std::env::var_os("MARS_ONNX_PYTHON") {
        return Ok(p.into());
    }
    let status = Command::new(root().join(".ci/franka-sim-venv")).current_dir(root()).status();
    match status {
        Ok(s) if s.success() => Ok(root().join(".venv-sim/bin/python")),
        other => Err(format!(".ci/franka-sim-venv failed: {other:?}")),
    }
}

#[derive(Debug, Clone, serde::Deserialize)]
pub struct OrtRun {
    pub ort_version: String,
    pub median_ms: f64,
    pub p10_ms: f64,
    pub p90_ms: f64,
    pub out_len: usize,
    pub max_abs_diff: Option<f64>,
}

fn write_f32(path: &Path, v: &[f32]) {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

/// ONNX Runtime on `weights` (a safetensors file, no prefix) and `image` ([H·W, 3]); `expect`: the output to
/// compare with. `iters` timed runs after up to 10 warm-up runs.
#[allow(clippy::too_many_arguments)]
pub fn run(
    python: &Path,
    weights: &Path,
    cfg: &ResNetConfig,
    height: usize,
    width: usize,
    image: &[f32],
    expect: &[f32],
    iters: usize,
) -> Result<OrtRun, String> {
    let tag = weights.file_stem().unwrap().to_string_lossy();
    let dir = weights.parent().unwrap();
    let (img, exp) = (dir.join(format!("{tag}.image.f32")), dir.join(format!("{tag}.expect.f32")));
    write_f32(&img, image);
    write_f32(&exp, expect);
    let head = match cfg.head {
        ResNetHead::SpatialSoftmax { keypoints } => format!("ssm:{keypoints}"),
        ResNetHead::AvgPool => "avg".into(),
    };
    let out = Command::new(python)
        .arg(root().join("engine/benches/onnx_resnet.py"))
        .arg("--weights")
        .arg(weights)
        .args(["--net-width", &cfg.width.to_string(), "--head", &head])
        .args(["--height", &height.to_string(), "--width", &width.to_string()])
        .arg("--image")
        .arg(&img)
        .arg("--expect")
        .arg(&exp)
        .args(["--iters", &iters.to_string()])
        .output()
        .map_err(|e| format!("running {}: {e}", python.display()))?;
    let _ = (std::fs::remove_file(&img), std::fs::remove_file(&exp));
    if !out.status.success() {
        return Err(format!("onnx_resnet.py failed: {}", String::from_utf8_lossy(&out.stderr)));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.trim()).map_err(|e| format!("onnx_resnet.py printed {text:?}: {e}"))
}
