//! Multi-head self-attention over the chunk's time steps, with the differentiable `ops::softmax`.

use super::linear::Linear;
use candle_core::{D, Module, Result, Tensor};
use candle_nn::VarBuilder;

#[derive(Debug, Clone)]
pub struct SelfAttention {
    qkv: Linear,
    out: Linear,
    heads: usize,
}

impl SelfAttention {
    pub fn new(width: usize, heads: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            qkv: Linear::new(width, 3 * width, vb.pp("qkv"))?,
            out: Linear::new(width, width, vb.pp("out"))?,
            heads,
        })
    }
}

impl Module for SelfAttention {
    /// `x`: [B, T, W] → [B, T, W].
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let (b, t, w) = x.dims3()?;
        let dh = w / self.heads;
        // [B, T, 3, heads, dh] → three [B, heads, T, dh]
        let qkv = self.qkv.forward(x)?.reshape((b, t, 3, self.heads, dh))?.permute((2, 0, 3, 1, 4))?;
        let q = qkv.get(0)?.contiguous()?;
        let k = qkv.get(1)?.contiguous()?;
        let v = qkv.get(2)?.contiguous()?;
        let scores = (q.matmul(&k.t()?)? / (dh as f64).sqrt())?;
        let attn = candle_nn::ops::softmax(&scores, D::Minus1)?;
        let y = attn.matmul(&v)?.transpose(1, 2)?.reshape((b, t, w))?;
        self.out.forward(&y)
    }
}
