//! Layer normalisation without learned affine (DiT's adaLN supplies scale and shift), built from basic ops
//! so that it has a backward pass.

use candle_core::{D, Result, Tensor};

pub fn layer_norm_no_affine(x: &Tensor, eps: f64) -> Result<Tensor> {
    let mean = x.mean_keepdim(D::Minus1)?;
    let centred = x.broadcast_sub(&mean)?;
    let var = centred.sqr()?.mean_keepdim(D::Minus1)?;
    centred.broadcast_div(&(var + eps)?.sqrt()?)
}

/// The 0/1 matrix [B·T, B] that repeats a per-sample row over T tokens (row r copies sample r / T). It depends
/// only on the shapes, so a forward pass builds it once and every modulation reuses it.
pub fn token_expansion(b: usize, tokens: usize, like: &Tensor) -> Result<Tensor> {
    let mut rows = vec![0f32; b * tokens * b];
    for r in 0..b * tokens {
        rows[r * b + r / tokens] = 1.0;
    }
    Tensor::from_vec(rows, (b * tokens, b), like.device())?.to_dtype(like.dtype())
}

/// Repeats a per-sample vector over the T tokens: [B, W] → [B, T, W], with `expand` from [`token_expansion`].
///
/// Written as a matmul with a 0/1 expansion matrix rather than a broadcast: the broadcast's backward sums over
/// the middle dimension with candle's slow strided reduction, the matmul's is one small gemm.
pub fn per_token(v: &Tensor, expand: &Tensor) -> Result<Tensor> {
    let (b, w) = v.dims2()?;
    let tokens = expand.dim(0)? / b.max(1);
    expand.matmul(v)?.reshape((b, tokens, w))
}

/// adaLN modulation: x · (1 + scale) + shift, with scale and shift per sample, the same for every token.
/// `x`: [B, T, W]; `shift`, `scale`: [B, W]; `expand`: [B·T, B] from [`token_expansion`].
pub fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor, expand: &Tensor) -> Result<Tensor> {
    (x * per_token(&(scale + 1.0)?, expand)?)? + per_token(shift, expand)?
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn per_token_repeats_each_sample_over_its_tokens() -> Result<()> {
        let v = Tensor::new(&[[1f32, 2.0], [3.0, 4.0]], &Device::Cpu)?;
        let out = per_token(&v, &token_expansion(2, 3, &v)?)?;
        let want = v.unsqueeze(1)?.broadcast_as((2, 3, 2))?.contiguous()?;
        assert_eq!(out.to_vec3::<f32>()?, want.to_vec3::<f32>()?);
        Ok(())
    }
}
