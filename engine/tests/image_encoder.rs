//! The engine's allocation-free ResNet-18 equals the policy's candle ResNet-18 (`mars_policy::nn::resnet`) on the
//! same weights: each head, narrow and paper-size widths, square and non-square images, both matrix-product
//! paths. Weights are seeded (convolutions as initialised; GroupNorm's scale and shift drawn away from 1 and 0, so
//! they matter), saved to safetensors by candle's VarMap and read back by the engine.

use std::path::PathBuf;

use candle_core::{Device, Tensor};
use mars_engine::{EngineError, ImageEncoder, Input};
use mars_policy::nn::resnet::{ResNet18, ResNetConfig, ResNetHead};
use mars_policy::nn::seeded_init::SeededInit;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

struct Case {
    cfg: ResNetConfig,
    height: usize,
    width: usize,
    file: PathBuf,
    net: ResNet18,
}

fn case(name: &str, cfg: ResNetConfig, height: usize, width: usize, seed: u64) -> Case {
    let (varmap, vb) = SeededInit::var_builder(seed, &Device::Cpu);
    let net = ResNet18::new(&cfg, vb).unwrap();
    let mut rng = StdRng::seed_from_u64(seed + 1);
    {
        let vars = varmap.data().lock().unwrap();
        let mut names: Vec<&String> = vars.keys().collect();
        names.sort();
        for name in names {
            let var = &vars[name];
            if var.dims().len() == 1 {
                let (centre, spread) = if name.ends_with(".weight") { (1.0, 0.3) } else { (0.0, 0.2) };
                let v: Vec<f32> =
                    (0..var.elem_count()).map(|_| centre + spread * rng.random_range(-1.0f32..1.0)).collect();
                var.set(&Tensor::from_vec(v, var.dims(), &Device::Cpu).unwrap()).unwrap();
            }
        }
    }
    let file = std::env::temp_dir().join(format!("mars-engine-resnet-{}-{name}.safetensors", std::process::id()));
    varmap.save(&file).unwrap();
    Case { cfg, height, width, file, net }
}

/// A seeded image in [0, 1], channels last ([H·W, 3], the engine's input).
fn image(height: usize, width: usize, seed: u64) -> Vec<f32> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..height * width * 3).map(|_| rng.random_range(0.0..1.0)).collect()
}

fn candle_forward(c: &Case, hwc: &[f32]) -> Vec<f32> {
    let x = Tensor::from_slice(hwc, (c.height, c.width, 3), &Device::Cpu).unwrap();
    let x = x.permute((2, 0, 1)).unwrap().unsqueeze(0).unwrap().contiguous().unwrap();
    c.net.forward(&x).unwrap().squeeze(0).unwrap().to_vec1().unwrap()
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn the_engine_encoder_equals_candles_forward() {
    let cases = [
        case("ssm64", ResNetConfig { width: 8, head: ResNetHead::SpatialSoftmax { keypoints: 16 } }, 64, 64, 1),
        case("avg96x80", ResNetConfig { width: 16, head: ResNetHead::AvgPool }, 96, 80, 2),
        case("ssm-odd", ResNetConfig { width: 32, head: ResNetHead::SpatialSoftmax { keypoints: 8 } }, 75, 99, 3),
        // The paper's width (64/128/256/512 channels) at the default image size.
        case("paper96", ResNetConfig { width: 64, head: ResNetHead::SpatialSoftmax { keypoints: 32 } }, 96, 96, 4),
    ];
    for c in &cases {
        for portable in [false, true] {
            let mut enc = ImageEncoder::load(&c.file, "", &c.cfg, c.height, c.width, portable).unwrap();
            assert_eq!(enc.out_dim(), c.cfg.out_dim());
            for seed in 0..2 {
                let img = image(c.height, c.width, 10 + seed);
                let want = candle_forward(c, &img);
                let got = enc.encode(&img).unwrap().to_vec();
                let d = max_diff(&got, &want);
                let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                eprintln!(
                    "{:?} {}×{} portable={portable}: max |engine − candle| = {d:.2e} (outputs up to {scale:.2})",
                    c.cfg, c.height, c.width
                );
                assert!(d <= 1e-4, "{:?} {}×{}: max difference {d}", c.cfg, c.height, c.width);
                // Not a constant: different images give different features.
                assert!(max_diff(&got, &candle_forward(c, &image(c.height, c.width, 99))) > 1e-3);
            }
        }
        let _ = std::fs::remove_file(&c.file);
    }
}

#[test]
fn bad_images_and_bad_checkpoints_are_clear_errors() {
    let c = case("errors", ResNetConfig { width: 8, head: ResNetHead::AvgPool }, 64, 64, 5);
    let mut enc = ImageEncoder::load(&c.file, "", &c.cfg, 64, 64, false).unwrap();
    let mut img = image(64, 64, 1);
    assert_eq!(
        enc.encode(&img[1..]).err(),
        Some(EngineError::Length { what: Input::Image, got: 64 * 64 * 3 - 1, want: 64 * 64 * 3 })
    );
    img[77] = f32::NAN;
    let e = enc.encode(&img).unwrap_err();
    assert!(matches!(e, EngineError::NonFinite { what: Input::Image, index: 77, .. }), "{e}");
    // The next good image is encoded as if the bad ones never came.
    img[77] = 0.5;
    let want = candle_forward(&c, &img);
    assert!(max_diff(enc.encode(&img).unwrap(), &want) <= 1e-4);
    // Another width than the checkpoint's: the tensor named, both shapes given.
    let wide = ResNetConfig { width: 16, ..c.cfg };
    let e = ImageEncoder::load(&c.file, "", &wide, 64, 64, false).err().unwrap().to_string();
    assert!(e.contains("stem.weight") && e.contains("[8, 3, 7, 7]") && e.contains("[16, 3, 7, 7]"), "{e}");
    let e = ImageEncoder::load(&c.file, "", &c.cfg, 16, 64, false).err().unwrap().to_string();
    assert!(e.contains("at least 32 × 32"), "{e}");
    let _ = std::fs::remove_file(&c.file);
}
