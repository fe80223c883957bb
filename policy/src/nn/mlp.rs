//! Two linear layers with a non-linearity between them: the encoder, the scheduler and the DiT feed-forward.

use candle_core::{Module, Result, Tensor};
use candle_nn::{Linear, VarBuilder, linear};

#[derive(Debug, Clone, Copy)]
pub enum Activation {
    Silu,
    /// tanh-approximated GELU, as in DiT.
    Gelu,
}

#[derive(Debug, Clone)]
pub struct Mlp {
    fc1: Linear,
    fc2: Linear,
    act: Activation,
}

impl Mlp {
    pub fn new(input: usize, hidden: usize, output: usize, act: Activation, vb: VarBuilder) -> Result<Self> {
        Ok(Self { fc1: linear(input, hidden, vb.pp("fc1"))?, fc2: linear(hidden, output, vb.pp("fc2"))?, act })
    }

    /// Like `new`, but the output layer starts at zero weights and bias (used where the output is a residual
    /// or a logit that should start neutral).
    pub fn new_zero_out(input: usize, hidden: usize, output: usize, act: Activation, vb: VarBuilder) -> Result<Self> {
        let fc2 = Linear::new(
            vb.pp("fc2").get_with_hints((output, hidden), "weight", candle_nn::init::ZERO)?,
            Some(vb.pp("fc2").get_with_hints(output, "bias", candle_nn::init::ZERO)?),
        );
        Ok(Self { fc1: linear(input, hidden, vb.pp("fc1"))?, fc2, act })
    }
}

impl Module for Mlp {
    fn forward(&self, xs: &Tensor) -> Result<Tensor> {
        let h = self.fc1.forward(xs)?;
        let h = match self.act {
            Activation::Silu => h.silu()?,
            Activation::Gelu => h.gelu()?,
        };
        self.fc2.forward(&h)
    }
}
