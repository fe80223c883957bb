//! A second implementation no one here wrote agrees with the engine's image encoder: ONNX Runtime (PyPI
//! `onnxruntime`), running the same ResNet-18 built as an ONNX graph from the same safetensors weights
//! (`benches/onnx_resnet.py`), gives the same features within 1e-4, for both heads and the paper's width.

mod onnx;

use candle_core::Device;
use mars_engine::ImageEncoder;
use mars_policy::nn::resnet::{ResNet18, ResNetConfig, ResNetHead};
use mars_policy::nn::seeded_init::SeededInit;

#[test]
fn onnx_runtime_computes_the_same_features_as_the_engine() {
    let python = onnx::python().unwrap();
    let cases = [
        (ResNetConfig { width: 16, head: ResNetHead::SpatialSoftmax { keypoints: 32 } }, 96, 96),
        (ResNetConfig { width: 8, head: ResNetHead::AvgPool }, 64, 80),
        (ResNetConfig { width: 64, head: ResNetHead::SpatialSoftmax { keypoints: 32 } }, 96, 96),
    ];
    for (i, (cfg, h, w)) in cases.into_iter().enumerate() {
        let (varmap, vb) = SeededInit::var_builder(40 + i as u64, &Device::Cpu);
        ResNet18::new(&cfg, vb).unwrap();
        let file = std::env::temp_dir().join(format!("mars-onnx-peer-{}-{i}.safetensors", std::process::id()));
        varmap.save(&file).unwrap();
        let mut enc = ImageEncoder::load(&file, "", &cfg, h, w, false).unwrap();
        let image: Vec<f32> = (0..h * w * 3).map(|p| ((p * 7919) % 1000) as f32 / 1000.0).collect();
        let ours = enc.encode(&image).unwrap().to_vec();
        let ort = onnx::run(&python, &file, &cfg, h, w, &image, &ours, 1).unwrap();
        let _ = std::fs::remove_file(&file);
        eprintln!("{cfg:?} {h}×{w}: ONNX Runtime {}: max |ORT − engine| = {:?}", ort.ort_version, ort.max_abs_diff);
        assert_eq!(ort.out_len, ours.len());
        let d = ort.max_abs_diff.expect("same length");
        assert!(d <= 1e-4, "{cfg:?}: ONNX Runtime differs from the engine by {d}");
    }
}
