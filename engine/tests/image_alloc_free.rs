//! After load and one warm-up call, the engine's image encoder performs zero heap allocations per call (also on
//! a refused image): counted with the counting global allocator, on this thread only, for both heads.

mod counting;

use candle_core::Device;
use counting::{Counting, count};
use mars_engine::ImageEncoder;
use mars_policy::nn::resnet::{ResNet18, ResNetConfig, ResNetHead};
use mars_policy::nn::seeded_init::SeededInit;

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn encoding_an_image_allocates_nothing() {
    for (i, head) in [ResNetHead::SpatialSoftmax { keypoints: 16 }, ResNetHead::AvgPool].into_iter().enumerate() {
        let cfg = ResNetConfig { width: 16, head };
        let (varmap, vb) = SeededInit::var_builder(i as u64, &Device::Cpu);
        ResNet18::new(&cfg, vb).unwrap();
        let file = std::env::temp_dir().join(format!("mars-engine-alloc-{}-{i}.safetensors", std::process::id()));
        varmap.save(&file).unwrap();
        for portable in [false, true] {
            let mut enc = ImageEncoder::load(&file, "", &cfg, 96, 96, portable).unwrap();
            let images: Vec<Vec<f32>> =
                (0..4).map(|s| (0..96 * 96 * 3).map(|p| ((p * 31 + s) % 255) as f32 / 255.0).collect()).collect();
            let mut bad = images[0].clone();
            bad[5] = f32::INFINITY;
            enc.encode(&images[0]).unwrap();
            let (sum, counts) = count(|| {
                let mut sum = 0.0;
                for k in 0..40 {
                    sum += enc.encode(&images[k % 4]).unwrap()[0];
                    assert!(enc.encode(&bad).is_err());
                    assert!(enc.encode(&images[0][1..]).is_err());
                }
                sum
            });
            assert!(sum.is_finite());
            assert_eq!(
                (counts.allocs, counts.reallocs, counts.deallocs),
                (0, 0, 0),
                "{head:?} portable={portable}: {counts:?}"
            );
        }
        let _ = std::fs::remove_file(&file);
    }
}
