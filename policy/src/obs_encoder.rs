//! What the model sees of an observation: an encoder maps it to the embedding that conditions the scheduler and
//! the velocity field (`encoder::build` picks the state MLP or the vision encoder from the config).

use candle_core::{Result, Tensor};
use rand::rngs::StdRng;

pub trait ObsEncoder: Send + Sync {
    /// `obs`: [B, obs_dim] (normalised) → [B, embed_dim], as at inference.
    fn forward(&self, obs: &Tensor) -> Result<Tensor>;

    /// The same in training, where an encoder may augment (the vision encoder's random crops).
    fn forward_train(&self, obs: &Tensor, _rng: &mut StdRng) -> Result<Tensor> {
        self.forward(obs)
    }
}
