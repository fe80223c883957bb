//! Spatial softmax (Levine et al. 2016; diffusion_policy's image head): each of K keypoint maps becomes a
//! probability over the feature map's pixels, and the head returns each map's expected (x, y) in [−1, 1]. It keeps
//! *where* things are, which average pooling throws away; a pushing policy needs where the block is.

use candle_core::{D, Module, Result, Tensor};
use candle_nn::{Conv2d, Conv2dConfig, VarBuilder, conv2d_no_bias};

pub struct SpatialSoftmax {
    /// 1 × 1 convolution from the backbone's channels to the K keypoint maps. No bias: a constant added to a
    /// whole map does not change its softmax, so a bias would get no gradient (exactly 0; robomimic's head has one).
    keypoints: Conv2d,
}

impl SpatialSoftmax {
    pub fn new(channels: usize, keypoints: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self { keypoints: conv2d_no_bias(channels, keypoints, 1, Conv2dConfig::default(), vb.pp("keypoints"))? })
    }

    /// `features`: [B, C, H, W] → [B, 2K]: (x, y) of each keypoint, x along W, y along H.
    pub fn forward(&self, features: &Tensor) -> Result<Tensor> {
        let maps = self.keypoints.forward(features)?;
        let (b, k, h, w) = maps.dims4()?;
        // Softmax over the pixels from basic ops (candle's fused softmax has no backward pass).
        let logits = maps.reshape((b, k, h * w))?;
        let p = candle_nn::ops::softmax(&logits, D::Minus1)?;
        let (xs, ys) = pixel_coordinates(h, w, features)?;
        let x = p.broadcast_mul(&xs)?.sum(D::Minus1)?;
        let y = p.broadcast_mul(&ys)?.sum(D::Minus1)?;
        Tensor::cat(&[x, y], 1)
    }
}

/// Each pixel's x and y in [−1, 1], as [1, 1, H·W] rows (row-major over H, W).
fn pixel_coordinates(h: usize, w: usize, like: &Tensor) -> Result<(Tensor, Tensor)> {
    let at = |i: usize, n: usize| if n > 1 { -1.0 + 2.0 * i as f32 / (n - 1) as f32 } else { 0.0 };
    let xs: Vec<f32> = (0..h * w).map(|p| at(p % w, w)).collect();
    let ys: Vec<f32> = (0..h * w).map(|p| at(p / w, h)).collect();
    let row = |v: Vec<f32>| Tensor::from_vec(v, (1, 1, h * w), like.device())?.to_dtype(like.dtype());
    Ok((row(xs)?, row(ys)?))
}
