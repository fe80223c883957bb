//! Observation encoders. The model holds a `Box<dyn ObsEncoder>`, so an image encoder (ResNet-18) can be
//! added as another `EncoderConfig` variant without touching the model.

use crate::config::EncoderConfig;
use crate::nn::mlp::{Activation, Mlp};
use candle_core::{Module, Result, Tensor};
use candle_nn::VarBuilder;

pub trait ObsEncoder: Send + Sync {
    /// `obs`: [B, obs_dim] (normalised) → [B, embed_dim].
    fn forward(&self, obs: &Tensor) -> Result<Tensor>;
}

/// A state vector through a two-layer MLP.
pub struct StateMlpEncoder {
    mlp: Mlp,
}

impl ObsEncoder for StateMlpEncoder {
    fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        self.mlp.forward(obs)
    }
}

pub fn build(cfg: &EncoderConfig, obs_dim: usize, embed_dim: usize, vb: VarBuilder) -> Result<Box<dyn ObsEncoder>> {
    match *cfg {
        EncoderConfig::StateMlp { hidden } => Ok(Box::new(StateMlpEncoder {
            mlp: Mlp::new(obs_dim, hidden, embed_dim, Activation::Silu, vb.pp("state_mlp"))?,
        })),
    }
}
