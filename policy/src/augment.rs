//! Image augmentation for training: a random crop per sample (diffusion_policy's, ~90 % of each side), so the
//! policy does not learn pixel positions by heart; evaluation takes the centre crop of the same size.

use candle_core::{Result, Tensor};
use rand::Rng;

/// [B, C, H, W] → [B, C, h, w]: each sample cropped at its own random offset.
pub fn random_crop(images: &Tensor, (h, w): (usize, usize), rng: &mut impl Rng) -> Result<Tensor> {
    let (b, _, ih, iw) = images.dims4()?;
    check(ih, iw, h, w)?;
    let crops = (0..b)
        .map(|i| {
            let (top, left) = (rng.random_range(0..=ih - h), rng.random_range(0..=iw - w));
            images.narrow(0, i, 1)?.narrow(2, top, h)?.narrow(3, left, w)
        })
        .collect::<Result<Vec<_>>>()?;
    Tensor::cat(&crops, 0)
}

/// [B, C, H, W] → [B, C, h, w]: the centre crop (what the policy sees at evaluation).
pub fn centre_crop(images: &Tensor, (h, w): (usize, usize)) -> Result<Tensor> {
    let (_, _, ih, iw) = images.dims4()?;
    check(ih, iw, h, w)?;
    images.narrow(2, (ih - h) / 2, h)?.narrow(3, (iw - w) / 2, w)
}

fn check(ih: usize, iw: usize, h: usize, w: usize) -> Result<()> {
    if h == 0 || w == 0 || h > ih || w > iw {
        candle_core::bail!("crop {h}×{w} does not fit a {ih}×{iw} image");
    }
    Ok(())
}
