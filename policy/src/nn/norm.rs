//! Layer normalisation without learned affine (DiT's adaLN supplies scale and shift), built from basic ops
//! so that it has a backward pass.

use candle_core::{D, Result, Tensor};

pub fn layer_norm_no_affine(x: &Tensor, eps: f64) -> Result<Tensor> {
    let mean = x.mean_keepdim(D::Minus1)?;
    let centred = x.broadcast_sub(&mean)?;
    let var = centred.sqr()?.mean_keepdim(D::Minus1)?;
    centred.broadcast_div(&(var + eps)?.sqrt()?)
}

/// Repeats a per-sample vector over the T tokens: [B, W] → [B, T, W].
///
/// Written as a matmul with a 0/1 expansion matrix rather than a broadcast: the broadcast's backward sums over
/// the middle dimension with candle's slow strided reduction, the matmul's is one small gemm.
pub fn per_token(v: &Tensor, tokens: usize) -> Result<Tensor> {
    let (b, w) = v.dims2()?;
    let rows: Vec<f32> =
        (0..b * tokens).flat_map(|r| (0..b).map(move |c| if r / tokens == c { 1.0 } else { 0.0 })).collect();
    let expand = Tensor::from_vec(rows, (b * tokens, b), v.device())?.to_dtype(v.dtype())?;
    expand.matmul(v)?.reshape((b, tokens, w))
}

/// adaLN modulation: x · (1 + scale) + shift, with scale and shift per sample, the same for every token.
/// `x`: [B, T, W]; `shift`, `scale`: [B, W].
pub fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor) -> Result<Tensor> {
    let t = x.dim(1)?;
    (x * per_token(&(scale + 1.0)?, t)?)? + per_token(shift, t)?
}
