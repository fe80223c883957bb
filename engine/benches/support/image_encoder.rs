//! The image-encoder section of `cargo bench -p mars-engine` (included by `engine.rs`): the engine's ResNet-18
//! against candle's forward and ONNX Runtime on one thread, at each configured size, medians measured in one run.

use std::time::{Duration, Instant};

use candle_core::{Device, Tensor};
use mars_engine::ImageEncoder;
use mars_policy::nn::resnet::{ResNet18, ResNetConfig, ResNetHead};
use mars_policy::nn::seeded_init::SeededInit;

#[path = "../../tests/onnx/mod.rs"]
mod onnx;

/// Runs `f` until `calls` runs and at least 0.5 s have passed; the median of the runs.
fn median_of(calls: usize, mut f: impl FnMut()) -> Duration {
    f();
    let started = Instant::now();
    let mut times = Vec::new();
    while times.len() < calls || started.elapsed() < Duration::from_millis(500) {
        let t = Instant::now();
        f();
        times.push(t.elapsed());
    }
    times.sort();
    times[times.len() / 2]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// (label, config, image side): the narrow defaults the tests and CI train, and the paper's width.
fn sizes() -> Vec<(&'static str, ResNetConfig, usize)> {
    let ssm = ResNetHead::SpatialSoftmax { keypoints: 32 };
    vec![
        ("narrow w16, 64 px", ResNetConfig { width: 16, head: ssm }, 64),
        ("narrow w16, 96 px", ResNetConfig { width: 16, head: ssm }, 96),
        ("w32, 96 px", ResNetConfig { width: 32, head: ssm }, 96),
        ("paper w64, 96 px", ResNetConfig { width: 64, head: ssm }, 96),
    ]
}

pub fn encoder_table(peak: f64, counted: impl Fn(&mut dyn FnMut()) -> u64) {
    println!("\n## Image encoder (ResNet-18, GroupNorm, spatial softmax 32 keypoints; batch 1, one thread)\n");
    let python = onnx::python();
    match &python {
        Ok(p) => println!("   ONNX Runtime: {} running benches/onnx_resnet.py (intra-op threads 1)", p.display()),
        Err(e) => println!("   ONNX Runtime: not available ({e}); its columns are empty"),
    }
    println!(
        "\n| size | MFLOP | engine median | candle median | ONNX Runtime median | candle/engine | ORT/engine | engine GFLOP/s | % of gemm peak | allocs/call | max |ORT − engine| |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (i, (label, cfg, side)) in sizes().into_iter().enumerate() {
        let (varmap, vb) = SeededInit::var_builder(70 + i as u64, &Device::Cpu);
        let net = ResNet18::new(&cfg, vb).unwrap();
        let file = std::env::temp_dir().join(format!("mars-bench-resnet-{}-{i}.safetensors", std::process::id()));
        varmap.save(&file).unwrap();
        let mut enc = ImageEncoder::load(&file, "", &cfg, side, side, false).unwrap();
        let image: Vec<f32> = (0..side * side * 3).map(|p| ((p * 7919) % 1000) as f32 / 1000.0).collect();
        let flop = 2.0 * enc.macs() as f64;
        let ours = enc.encode(&image).unwrap().to_vec();
        let engine = median_of(30, || {
            std::hint::black_box(enc.encode(&image).unwrap());
        });
        let allocs = counted(&mut || {
            std::hint::black_box(enc.encode(&image).unwrap());
        });
        let x = Tensor::from_slice(&image, (side, side, 3), &Device::Cpu).unwrap();
        let x = x.permute((2, 0, 1)).unwrap().unsqueeze(0).unwrap().contiguous().unwrap();
        let candle = median_of(10, || {
            std::hint::black_box(net.forward(&x).unwrap());
        });
        let ort = python.as_ref().ok().map(|p| onnx::run(p, &file, &cfg, side, side, &image, &ours, 50));
        let _ = std::fs::remove_file(&file);
        let (ort_ms, ratio, diff) = match ort {
            Some(Ok(r)) => (
                format!("{:.2} ms", r.median_ms),
                format!("{:.2}", r.median_ms / ms(engine)),
                format!("{:.1e}", r.max_abs_diff.unwrap_or(f64::NAN)),
            ),
            Some(Err(e)) => {
                eprintln!("ONNX Runtime failed: {e}");
                ("failed".into(), "–".into(), "–".into())
            }
            None => ("–".into(), "–".into(), "–".into()),
        };
        let gflops = flop / engine.as_secs_f64() / 1e9;
        println!(
            "| {label} | {:.0} | {:.2} ms | {:.2} ms | {ort_ms} | {:.2} | {ratio} | {gflops:.1} | {:.0} % | {allocs} | {diff} |",
            flop / 1e6,
            ms(engine),
            ms(candle),
            ms(candle) / ms(engine),
            100.0 * gflops * 1e9 / peak,
        );
    }
    println!(
        "\n   FLOP: 2 × the convolutions' and keypoint maps' multiply-adds. Ratios > 1: the engine is faster. Medians \
         of ≥ 30 calls and ≥ 0.5 s (ONNX Runtime: 50 after 10 warm-up calls)."
    );
}
