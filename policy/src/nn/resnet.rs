//! ResNet-18 (He et al. 2016) as the paper's image encoder, with GroupNorm in place of BatchNorm: trained from
//! scratch on small batches, batch statistics are noise (diffusion_policy's practice: one group per 16 channels).
//! The width is a parameter (the paper's network is width 64: 64/128/256/512 channels), so CI and the
//! benchmark can train a narrow one; the head is a spatial softmax or an average pool.

use candle_core::{Module, Result, Tensor};
use candle_nn::{Conv2d, Conv2dConfig, GroupNorm, VarBuilder, conv2d_no_bias, group_norm};

use super::spatial_softmax::SpatialSoftmax;

pub use mars_policy_format::encoder::{ResNetConfig, ResNetHead};

/// GroupNorm with one group per 16 channels (at least one group).
fn norm(channels: usize, vb: VarBuilder) -> Result<GroupNorm> {
    group_norm((channels / 16).max(1), channels, 1e-5, vb)
}

fn conv(i: usize, o: usize, k: usize, stride: usize, vb: VarBuilder) -> Result<Conv2d> {
    conv2d_no_bias(i, o, k, Conv2dConfig { padding: k / 2, stride, ..Default::default() }, vb)
}

/// Two 3 × 3 convolutions and a skip connection (projected when the shape changes).
struct BasicBlock {
    conv1: Conv2d,
    norm1: GroupNorm,
    conv2: Conv2d,
    norm2: GroupNorm,
    shortcut: Option<(Conv2d, GroupNorm)>,
}

impl BasicBlock {
    fn new(i: usize, o: usize, stride: usize, vb: VarBuilder) -> Result<Self> {
        let shortcut = if stride != 1 || i != o {
            Some((conv(i, o, 1, stride, vb.pp("down.conv"))?, norm(o, vb.pp("down.norm"))?))
        } else {
            None
        };
        Ok(Self {
            conv1: conv(i, o, 3, stride, vb.pp("conv1"))?,
            norm1: norm(o, vb.pp("norm1"))?,
            conv2: conv(o, o, 3, 1, vb.pp("conv2"))?,
            norm2: norm(o, vb.pp("norm2"))?,
            shortcut,
        })
    }

    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let y = self.norm1.forward(&self.conv1.forward(x)?)?.relu()?;
        let y = self.norm2.forward(&self.conv2.forward(&y)?)?;
        let skip = match &self.shortcut {
            Some((c, n)) => n.forward(&c.forward(x)?)?,
            None => x.clone(),
        };
        (y + skip)?.relu()
    }
}

pub struct ResNet18 {
    stem: Conv2d,
    stem_norm: GroupNorm,
    /// Four stages of two blocks each.
    blocks: Vec<BasicBlock>,
    head: Option<SpatialSoftmax>,
}

impl ResNet18 {
    pub fn new(cfg: &ResNetConfig, vb: VarBuilder) -> Result<Self> {
        let w = cfg.width;
        let mut blocks = Vec::with_capacity(8);
        let mut channels = w;
        for (stage, mult) in [1, 2, 4, 8].into_iter().enumerate() {
            let o = w * mult;
            for block in 0..2 {
                let stride = if stage > 0 && block == 0 { 2 } else { 1 };
                blocks.push(BasicBlock::new(channels, o, stride, vb.pp(format!("layer{}.{block}", stage + 1)))?);
                channels = o;
            }
        }
        let head = match cfg.head {
            ResNetHead::SpatialSoftmax { keypoints } => Some(SpatialSoftmax::new(channels, keypoints, vb.pp("head"))?),
            ResNetHead::AvgPool => None,
        };
        Ok(Self { stem: conv(3, w, 7, 2, vb.pp("stem"))?, stem_norm: norm(w, vb.pp("stem_norm"))?, blocks, head })
    }

    /// `images`: [B, 3, H, W] (normalised) → [B, out_dim].
    pub fn forward(&self, images: &Tensor) -> Result<Tensor> {
        let x = self.stem_norm.forward(&self.stem.forward(images)?)?.relu()?;
        let mut x = max_pool_3x3_stride_2(&x)?;
        for b in &self.blocks {
            x = b.forward(&x)?;
        }
        match &self.head {
            Some(h) => h.forward(&x),
            None => x.mean((2, 3)),
        }
    }
}

/// ResNet's 3 × 3 max pool with stride 2 and padding 1, from basic ops: candle 0.11's pooling has no backward pass
/// unless the kernel equals the stride. The padding repeats the edge, which a max cannot pick over the real pixels
/// next to it.
pub fn max_pool_3x3_stride_2(x: &Tensor) -> Result<Tensor> {
    let (b, c, h, w) = x.dims4()?;
    let (ho, wo) = ((h - 1) / 2 + 1, (w - 1) / 2 + 1);
    // One more row and column than padding 1 needs, so every shifted view below has 2·out rows to fold.
    let x = x.pad_with_same(2, 1, 2)?.pad_with_same(3, 1, 2)?;
    // The pixel at (di, dj) of every 3 × 3 window: rows di, di + 2, … (2·ho rows folded into (ho, 2), the first of
    // each pair kept), then the same for the columns.
    let window_pixel = |di: usize, dj: usize| -> Result<Tensor> {
        let rows = x.narrow(2, di, 2 * ho)?.reshape((b, c, ho, 2, w + 3))?.narrow(3, 0, 1)?.squeeze(3)?;
        rows.narrow(3, dj, 2 * wo)?.reshape((b, c, ho, wo, 2))?.narrow(4, 0, 1)?.squeeze(4)
    };
    let mut out = window_pixel(0, 0)?;
    for k in 1..9 {
        out = out.maximum(&window_pixel(k / 3, k % 3)?)?;
    }
    Ok(out)
}
