//! Layer normalisation without learned affine (DiT's adaLN supplies scale and shift), built from basic ops
//! so that it has a backward pass.

use candle_core::{D, Result, Tensor};

pub fn layer_norm_no_affine(x: &Tensor, eps: f64) -> Result<Tensor> {
    let mean = x.mean_keepdim(D::Minus1)?;
    let centred = x.broadcast_sub(&mean)?;
    let var = centred.sqr()?.mean_keepdim(D::Minus1)?;
    centred.broadcast_div(&(var + eps)?.sqrt()?)
}

/// adaLN modulation: x · (1 + scale) + shift, with scale and shift per sample broadcast over tokens.
/// `x`: [B, T, W]; `shift`, `scale`: [B, W].
pub fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor) -> Result<Tensor> {
    x.broadcast_mul(&(scale.unsqueeze(1)? + 1.0)?)?.broadcast_add(&shift.unsqueeze(1)?)
}
