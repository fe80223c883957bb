//! Sinusoidal embedding of the flow time τ ∈ [0, 1] followed by an MLP, as in DiT.

use super::mlp::{Activation, Mlp};
use candle_core::{DType, Module, Result, Tensor};
use candle_nn::VarBuilder;

#[derive(Debug, Clone)]
pub struct TimeEmbedding {
    freq_dim: usize,
    mlp: Mlp,
}

impl TimeEmbedding {
    pub fn new(freq_dim: usize, width: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self { freq_dim, mlp: Mlp::new(freq_dim, width, width, Activation::Silu, vb.pp("mlp"))? })
    }

    /// `tau`: [B] in [0, 1] → [B, width].
    pub fn forward(&self, tau: &Tensor) -> Result<Tensor> {
        // τ is scaled to DiT's 0..1000 range so the sinusoid frequencies cover it well.
        let half = self.freq_dim / 2;
        let freqs: Vec<f32> = (0..half).map(|i| (-(10_000f32.ln()) * i as f32 / half as f32).exp()).collect();
        let freqs = Tensor::from_vec(freqs, (1, half), tau.device())?;
        let args = (tau.to_dtype(DType::F32)?.unsqueeze(1)? * 1000.0)?.broadcast_mul(&freqs)?;
        let emb = Tensor::cat(&[args.cos()?, args.sin()?], 1)?;
        self.mlp.forward(&emb)
    }
}
