//! The vision encoder in a whole policy: it trains on camera images (random crops, every weight reached by the
//! gradient), its images stay unnormalised, and what it learns comes from the image — on forked demos where
//! only a marker's colour tells which way a demo forks, the trained policy forks the way the image says.

mod common;
mod gradients;

use candle_core::Device;
use candle_nn::{Optimizer, ParamsAdamW};
use common::{forked_image_demos, tiny_config, vision_encoder};
use mars_policy::config::{ConfigError, EncoderConfig, PolicyKind};
use mars_policy::dataset::{Dataset, history_window};
use mars_policy::inference::MarsPolicy;
use mars_policy::nn::resnet::ResNetHead;
use mars_policy::train::train;
use mars_policy::train::{Batch, batch_losses, init_model};
use mars_tasks::rollout::ChunkPolicy;
use rand::SeedableRng;
use rand::rngs::StdRng;

const SIDE: usize = 36;

/// Images of 36 px cropped to 32 (a 1 × 1 final feature map: the average-pool head), or of 52 px cropped to 48
/// (2 × 2: the smallest a spatial softmax can locate anything in).
fn vision_config(kind: PolicyKind, head: ResNetHead) -> mars_policy::config::PolicyConfig {
    let mut cfg = tiny_config(kind);
    let (side, crop) = match head {
        ResNetHead::AvgPool => (SIDE, 32),
        ResNetHead::SpatialSoftmax { .. } => (52, 48),
    };
    cfg.model.obs_dim = 2 + side * side * 3;
    cfg.model.encoder = vision_encoder(side, crop, head);
    cfg
}

fn side(cfg: &mars_policy::config::PolicyConfig) -> usize {
    let EncoderConfig::Vision(v) = &cfg.model.encoder else { unreachable!() };
    v.image_height
}

#[test]
fn the_trained_policy_forks_the_way_the_image_says() {
    let mut cfg = vision_config(PolicyKind::Fm, ResNetHead::AvgPool);
    cfg.train.epochs = 30;
    cfg.train.seed = 3;
    let demos = forked_image_demos(16, 16, SIDE);
    let trained = train(&cfg, &demos, false).unwrap();
    // The images were not normalised: mean 0, std 1 on every pixel value; the state was.
    let stats = &trained.normalizer.obs;
    assert!(stats.mean[2..].iter().all(|m| *m == 0.0) && stats.std[2..].iter().all(|s| *s == 1.0));
    assert!(stats.std[0] != 1.0 && stats.mean[0] != 0.0);
    let mut policy = MarsPolicy::from_trained(trained, 1);
    // From the fork's step (8 of 16), the chunk's last action: y > 0 for red (demo 0), y < 0 for blue (demo 1).
    let (d, c) = (2, cfg.model.chunk_len);
    let mut right = 0u64;
    let mut ys = [Vec::new(), Vec::new()];
    let trials = 10u64;
    for trial in 0..trials {
        for (i, demo) in demos.iter().take(2).enumerate() {
            policy.reseed(trial);
            let mut hist = Vec::new();
            history_window(&demo.actions, &demo.rest_action, 8, c, &mut hist);
            let p = policy.predict(&demo.observations[8], &hist).unwrap();
            let y = p.chunk[(c - 1) * d + 1];
            right += u64::from((i == 0 && y > 0.05) || (i == 1 && y < -0.05));
            ys[i].push(y);
        }
    }
    eprintln!(
        "forked the way the image says in {right} of {} predictions; final y, red marker {:?}, blue {:?}",
        2 * trials,
        ys[0],
        ys[1]
    );
    // Chance is 10 of 20 (an image-blind policy picks a side at random); `-- --nocapture` prints what it got.
    assert!(right >= 2 * trials * 8 / 10, "only {right} of {} predictions followed the image", 2 * trials);
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(mean(&ys[0]) > 0.2 && mean(&ys[1]) < -0.2, "means {} and {}", mean(&ys[0]), mean(&ys[1]));
}

#[test]
fn every_vision_weight_gets_a_gradient_through_the_random_crops() {
    for head in [ResNetHead::SpatialSoftmax { keypoints: 8 }, ResNetHead::AvgPool] {
        gradients_reach_every_weight(vision_config(PolicyKind::Mars, head));
    }
}

fn gradients_reach_every_weight(cfg: mars_policy::config::PolicyConfig) {
    let data = Dataset::from_demos(&forked_image_demos(8, 16, side(&cfg)), &cfg.model, cfg.train.knn_m).unwrap();
    let tensors = data.tensors(&cfg.model, &Device::Cpu).unwrap();
    let idx: Vec<u32> = (0..32).map(|i| i * 3 % data.len as u32).collect();
    let batch = Batch::gather(&tensors, &idx).unwrap();
    let (model, varmap) = init_model(&cfg, &Device::Cpu).unwrap();
    let mut opt = candle_nn::AdamW::new(varmap.all_vars(), ParamsAdamW { lr: 1e-3, ..Default::default() }).unwrap();
    let mut rng = StdRng::seed_from_u64(0);
    // adaLN-Zero's gates start at zero: two steps move them off it (as in training.rs).
    for _ in 0..2 {
        opt.backward_step(&batch_losses(&model, &batch, &cfg, &mut rng).unwrap().total).unwrap();
    }
    let grads = batch_losses(&model, &batch, &cfg, &mut rng).unwrap().total.backward().unwrap();
    let names: Vec<String> = varmap.data().lock().unwrap().keys().cloned().collect();
    assert!(names.iter().any(|n| n.starts_with("encoder.vision.camera0.layer4.1.conv2")), "{names:?}");
    gradients::assert_every_var_has_a_gradient(&varmap, &grads, &format!("{:?}", cfg.model.encoder));
    // The crops are random in training: the same batch encodes differently twice, and identically at inference.
    let (a, b) = (model.encode_train(&batch.obs, &mut rng).unwrap(), model.encode_train(&batch.obs, &mut rng).unwrap());
    assert!((a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap() > 1e-6);
    let (a, b) = (model.encode(&batch.obs).unwrap(), model.encode(&batch.obs).unwrap());
    assert_eq!((a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap(), 0.0);
}

#[test]
fn a_vision_config_that_cannot_work_is_refused_with_its_field() {
    let mut cfg = vision_config(PolicyKind::Mars, ResNetHead::AvgPool);
    let EncoderConfig::Vision(v) = &mut cfg.model.encoder else { unreachable!() };
    v.crop_height = SIDE + 1;
    let e = cfg.model.validate().unwrap_err();
    assert!(matches!(&e, ConfigError::Invalid { field: "model.encoder.crop_height", .. }), "{e}");
    assert!(e.to_string().contains("does not fit the 36×36 image"), "{e}");
    // A spatial softmax over a 1 × 1 feature map always says "the centre": its input would get no gradient.
    let mut cfg = vision_config(PolicyKind::Mars, ResNetHead::AvgPool);
    let EncoderConfig::Vision(v) = &mut cfg.model.encoder else { unreachable!() };
    v.resnet.head = ResNetHead::SpatialSoftmax { keypoints: 8 };
    let e = cfg.model.validate().unwrap_err();
    assert!(e.to_string().contains("1×1 feature map"), "{e}");
    let mut cfg = vision_config(PolicyKind::Mars, ResNetHead::AvgPool);
    cfg.model.obs_dim = 100;
    let e = cfg.model.validate().unwrap_err();
    assert!(matches!(&e, ConfigError::Invalid { field: "model.obs_dim", .. }), "{e}");
}
