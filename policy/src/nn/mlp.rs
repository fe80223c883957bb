//! Two linear layers with a non-linearity between them: the encoder, the scheduler and the DiT feed-forward.

use super::linear::Linear;
use candle_core::{Module, Result, Tensor};
use candle_nn::VarBuilder;

#[derive(Debug, Clone, Copy)]
pub enum Activation {
    Silu,
}

#[derive(Debug, Clone)]
pub struct Mlp {
    fc1: Linear,
    fc2: Linear,
    act: Activation,
}

impl Mlp {
    pub fn new(input: usize, hidden: usize, output: usize, act: Activation, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            fc1: Linear::new(input, hidden, vb.pp("fc1"))?,
            fc2: Linear::new(hidden, output, vb.pp("fc2"))?,
            act,
        })
    }
}

impl Module for Mlp {
    fn forward(&self, xs: &Tensor) -> Result<Tensor> {
        let h = self.fc1.forward(xs)?;
        let h = match self.act {
            Activation::Silu => h.silu()?,
        };
        self.fc2.forward(&h)
    }
}
