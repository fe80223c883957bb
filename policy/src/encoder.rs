//! Observation encoders. The model holds a `Box<dyn ObsEncoder>`: a state MLP, or the vision encoder
//! (`crate::vision`: ResNet-18 per camera and the state).

use crate::config::EncoderConfig;
use crate::nn::mlp::{Activation, Mlp};
use candle_core::{Module, Result, Tensor};
use candle_nn::VarBuilder;

pub use crate::obs_encoder::ObsEncoder;

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
    match cfg {
        EncoderConfig::StateMlp { hidden } => Ok(Box::new(StateMlpEncoder {
            mlp: Mlp::new(obs_dim, *hidden, embed_dim, Activation::Silu, vb.pp("state_mlp"))?,
        })),
        EncoderConfig::Vision(v) => {
            Ok(Box::new(crate::vision::VisionEncoder::new(v, obs_dim, embed_dim, vb.pp("vision"))?))
        }
    }
}

/// The observation's dimensions that `cfg`'s encoder takes as they are (not normalised).
pub fn raw_dims(cfg: &EncoderConfig, obs_dim: usize) -> std::ops::Range<usize> {
    match cfg {
        EncoderConfig::StateMlp { .. } => obs_dim..obs_dim,
        EncoderConfig::Vision(v) => v.state_dim(obs_dim)..obs_dim,
    }
}
