//! The modal scheduling network: an MLP ending in a sigmoid, giving one weight w_d ∈ (0, 1) per action
//! dimension — how much Gaussian noise (vs. the history prior) the flow source gets in that dimension.

use crate::nn::mlp::{Activation, Mlp};
use candle_core::{Module, Result, Tensor};
use candle_nn::VarBuilder;

pub struct ModalScheduler {
    mlp: Mlp,
    uses_history: bool,
}

impl ModalScheduler {
    pub fn new(
        embed_dim: usize,
        history_numel: Option<usize>,
        hidden: usize,
        action_dim: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        let input = embed_dim + history_numel.unwrap_or(0);
        Ok(Self {
            mlp: Mlp::new(input, hidden, action_dim, Activation::Silu, vb.pp("mlp"))?,
            uses_history: history_numel.is_some(),
        })
    }

    /// `obs_emb`: [B, E]; `history`: [B, H, D] → w: [B, D].
    pub fn forward(&self, obs_emb: &Tensor, history: &Tensor) -> Result<Tensor> {
        let input =
            if self.uses_history { Tensor::cat(&[obs_emb, &history.flatten_from(1)?], 1)? } else { obs_emb.clone() };
        candle_nn::ops::sigmoid(&self.mlp.forward(&input)?)
    }
}
