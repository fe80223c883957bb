//! A linear layer that folds all leading dimensions into one before the matmul.
//!
//! candle-nn's `Linear` broadcasts its weight over the batch for 3-D inputs, so the backward pass builds a
//! [B, out, in] weight gradient and sums it with candle's slow strided reduction: that was over a third of a
//! training step here. One 2-D matmul gives the same result and a plain [out, in] gradient. The bias is added
//! through a rank-1 matmul for the same reason: its gradient is then a gemm, not candle's strided sum over rows.

use candle_core::{Module, Result, Tensor};
use candle_nn::{VarBuilder, init};

#[derive(Debug, Clone)]
pub struct Linear {
    weight: Tensor,
    bias: Tensor,
}

impl Linear {
    /// PyTorch-style initialisation, as `candle_nn::linear`.
    pub fn new(input: usize, output: usize, vb: VarBuilder) -> Result<Self> {
        let bound = 1.0 / (input as f64).sqrt();
        let weight = vb.get_with_hints((output, input), "weight", init::DEFAULT_KAIMING_NORMAL)?;
        let bias = vb.get_with_hints(output, "bias", init::Init::Uniform { lo: -bound, up: bound })?;
        Ok(Self { weight, bias })
    }

    /// Zero weights and bias: adaLN-Zero and output layers that must start neutral.
    pub fn zeros(input: usize, output: usize, vb: VarBuilder) -> Result<Self> {
        let weight = vb.get_with_hints((output, input), "weight", init::ZERO)?;
        let bias = vb.get_with_hints(output, "bias", init::ZERO)?;
        Ok(Self { weight, bias })
    }
}

impl Module for Linear {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let dims = x.dims();
        let (lead, last) = dims.split_at(dims.len() - 1);
        let rows = lead.iter().product::<usize>();
        let x2 = x.reshape((rows, last[0]))?;
        let ones = Tensor::ones((rows, 1), x.dtype(), x.device())?;
        let y = (x2.matmul(&self.weight.t()?)? + ones.matmul(&self.bias.unsqueeze(0)?)?)?;
        let mut out = lead.to_vec();
        out.push(self.weight.dim(0)?);
        y.reshape(out)
    }
}
