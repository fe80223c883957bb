//! The vision encoder: each camera's image through its own ResNet-18, the features and the low-dimensional state
//! through an MLP. Images live in the observation vector after the state, channels last with values in [0, 1]
//! (what a camera's RGB8 bytes become, divided by 255: [`pixels_to_observation`]); the encoder reshapes them to
//! [B, 3, H, W], crops (random per sample in training, the centre at inference) and encodes.

use candle_core::{D, Module, Result, Tensor};
use candle_nn::VarBuilder;
use rand::rngs::StdRng;

use crate::augment::{centre_crop, random_crop};
use crate::config::VisionConfig;
use crate::nn::mlp::{Activation, Mlp};
use crate::nn::resnet::ResNet18;
use crate::obs_encoder::ObsEncoder;

pub struct VisionEncoder {
    cfg: VisionConfig,
    state_dim: usize,
    cameras: Vec<ResNet18>,
    mlp: Mlp,
}

impl VisionEncoder {
    pub fn new(cfg: &VisionConfig, obs_dim: usize, embed_dim: usize, vb: VarBuilder) -> Result<Self> {
        let state_dim = cfg.state_dim(obs_dim);
        let cameras =
            (0..cfg.cameras).map(|i| ResNet18::new(&cfg.resnet, vb.pp(format!("camera{i}")))).collect::<Result<_>>()?;
        let input = cfg.cameras * cfg.resnet.out_dim() + state_dim;
        let mlp = Mlp::new(input, cfg.hidden, embed_dim, Activation::Silu, vb.pp("mlp"))?;
        Ok(Self { cfg: cfg.clone(), state_dim, cameras, mlp })
    }

    fn encode(&self, obs: &Tensor, mut rng: Option<&mut StdRng>) -> Result<Tensor> {
        let b = obs.dim(0)?;
        let c = &self.cfg;
        let mut parts = Vec::with_capacity(c.cameras + 1);
        for (i, net) in self.cameras.iter().enumerate() {
            let flat = obs.narrow(1, self.state_dim + i * c.image_len(), c.image_len())?;
            let images = flat.reshape((b, c.image_height, c.image_width, 3))?.permute((0, 3, 1, 2))?;
            let crop = (c.crop_height, c.crop_width);
            let seen = match rng.as_deref_mut() {
                Some(r) => random_crop(&images, crop, r)?,
                None => centre_crop(&images, crop)?,
            };
            parts.push(net.forward(&seen.contiguous()?)?);
        }
        if self.state_dim > 0 {
            parts.push(obs.narrow(1, 0, self.state_dim)?);
        }
        self.mlp.forward(&Tensor::cat(&parts, D::Minus1)?)
    }
}

impl ObsEncoder for VisionEncoder {
    fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        self.encode(obs, None)
    }

    fn forward_train(&self, obs: &Tensor, rng: &mut StdRng) -> Result<Tensor> {
        self.encode(obs, Some(rng))
    }
}

pub use mars_policy_format::observation::pixels_to_observation;
