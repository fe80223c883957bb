//! The ResNet-18 image encoder (GroupNorm, spatial-softmax or average-pool head) and its crop augmentation: the
//! shapes, every weight reached by the gradient (candle's fused ops would silently stop it), and the crops.

mod gradients;

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use mars_policy::augment::{centre_crop, random_crop};
use mars_policy::nn::resnet::{ResNet18, ResNetConfig, ResNetHead};
use rand::SeedableRng;
use rand::rngs::StdRng;

fn images(b: usize, size: usize, seed: u64) -> Tensor {
    let mut rng = StdRng::seed_from_u64(seed);
    let v: Vec<f32> = (0..b * 3 * size * size).map(|_| rand::Rng::random_range(&mut rng, -1.0..1.0)).collect();
    Tensor::from_vec(v, (b, 3, size, size), &Device::Cpu).unwrap()
}

fn net(cfg: &ResNetConfig) -> (ResNet18, VarMap) {
    let varmap = VarMap::new();
    let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
    (ResNet18::new(cfg, vb).unwrap(), varmap)
}

#[test]
fn both_heads_give_one_vector_per_image_that_depends_on_the_image() {
    for head in [ResNetHead::SpatialSoftmax { keypoints: 8 }, ResNetHead::AvgPool] {
        let cfg = ResNetConfig { width: 8, head };
        let (net, varmap) = net(&cfg);
        // The paper's network: 11.2 M weights at width 64 (torchvision's resnet18 without its fc: 11.18 M); here
        // width 8, 1/64 of the convolutions' weights.
        assert!(!varmap.all_vars().is_empty());
        for size in [64, 96] {
            let out = net.forward(&images(3, size, 1)).unwrap();
            assert_eq!(out.dims(), [3, cfg.out_dim()], "{head:?} at {size} px");
            let rows = out.to_vec2::<f32>().unwrap();
            assert!(rows.iter().flatten().all(|x| x.is_finite()));
            assert_ne!(rows[0], rows[1], "{head:?}: two images, one feature vector");
        }
    }
}

#[test]
fn the_paper_size_network_has_resnet18s_weights() {
    let (_, varmap) = net(&ResNetConfig { width: 64, head: ResNetHead::AvgPool });
    let n: usize = varmap.all_vars().iter().map(|v: &Var| v.elem_count()).sum();
    // torchvision's resnet18 has 11,689,512 weights: 11,176,512 in the backbone and 513,000 in its fc layer.
    // GroupNorm has the same per-channel weight and bias as BatchNorm (no running statistics).
    assert_eq!(n, 11_176_512);
}

#[test]
fn every_weight_of_the_encoder_gets_a_nonzero_gradient() {
    for head in [ResNetHead::SpatialSoftmax { keypoints: 4 }, ResNetHead::AvgPool] {
        let (net, varmap) = net(&ResNetConfig { width: 8, head });
        let x = images(2, 64, 2);
        let target = images(1, 2, 3).flatten_all().unwrap();
        let out = net.forward(&x).unwrap();
        let k = out.dim(1).unwrap();
        let t = target.narrow(0, 0, k.min(12)).unwrap();
        let loss = out.narrow(1, 0, k.min(12)).unwrap().broadcast_sub(&t).unwrap().sqr().unwrap().sum_all().unwrap();
        gradients::assert_every_var_has_a_gradient(&varmap, &loss.backward().unwrap(), &format!("{head:?}"));
    }
}

/// The pool written from basic ops (for its backward pass) equals candle's own pool on the same padded input,
/// for even and odd sizes.
#[test]
fn the_differentiable_max_pool_equals_candles() {
    for size in [8, 9, 32, 33] {
        let x = images(2, size, 4);
        let ours = mars_policy::nn::resnet::max_pool_3x3_stride_2(&x).unwrap();
        let theirs =
            x.pad_with_same(2, 1, 1).unwrap().pad_with_same(3, 1, 1).unwrap().max_pool2d_with_stride(3, 2).unwrap();
        assert_eq!(ours.dims(), theirs.dims(), "{size}");
        let d = (ours - theirs).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert_eq!(d, 0.0, "{size}");
    }
}

#[test]
fn random_crops_are_seeded_per_sample_and_the_centre_crop_is_the_middle() {
    let x = Tensor::arange(0f32, 2.0 * 3.0 * 10.0 * 10.0, &Device::Cpu).unwrap().reshape((2, 3, 10, 10)).unwrap();
    let a = random_crop(&x, (8, 8), &mut StdRng::seed_from_u64(5)).unwrap();
    let b = random_crop(&x, (8, 8), &mut StdRng::seed_from_u64(5)).unwrap();
    assert_eq!(a.dims(), [2, 3, 8, 8]);
    assert_eq!(a.flatten_all().unwrap().to_vec1::<f32>().unwrap(), b.flatten_all().unwrap().to_vec1::<f32>().unwrap());
    let c = centre_crop(&x, (8, 8)).unwrap();
    // The centre crop of a 10 × 10 image starts at (1, 1): pixel value 11 in the first channel of the first sample.
    assert_eq!(c.get(0).unwrap().get(0).unwrap().get(0).unwrap().get(0).unwrap().to_scalar::<f32>().unwrap(), 11.0);
    assert!(random_crop(&x, (11, 8), &mut StdRng::seed_from_u64(0)).is_err());
}
