//! The velocity field v(a_τ, τ | obs): a DiT whose tokens are the chunk's time steps, conditioned through
//! adaLN-Zero on the flow time and the observation embedding.

use super::attention::SelfAttention;
use super::linear::Linear;
use super::mlp::{Activation, Mlp};
use super::norm::{layer_norm_no_affine, modulate, per_token, token_expansion};
use super::time_embed::TimeEmbedding;
use candle_core::{Module, Result, Tensor};
use candle_nn::{VarBuilder, init};

const LN_EPS: f64 = 1e-6;

#[derive(Debug, Clone)]
struct DitBlock {
    attn: SelfAttention,
    mlp: Mlp,
    /// c → (shift, scale, gate) for attention and for the MLP.
    ada: Linear,
}

impl DitBlock {
    fn new(width: usize, heads: usize, mlp_ratio: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            attn: SelfAttention::new(width, heads, vb.pp("attn"))?,
            mlp: Mlp::new(width, width * mlp_ratio, width, Activation::Silu, vb.pp("mlp"))?,
            ada: Linear::zeros(width, 6 * width, vb.pp("ada"))?,
        })
    }

    /// `x`: [B, T, W]; `c`: [B, W] (already passed through SiLU); `expand`: [B·T, B] from `token_expansion`.
    fn forward(&self, x: &Tensor, c: &Tensor, expand: &Tensor) -> Result<Tensor> {
        let m = self.ada.forward(c)?.chunk(6, 1)?;
        let h = modulate(&layer_norm_no_affine(x, LN_EPS)?, &m[0], &m[1], expand)?;
        let x = (x + (self.attn.forward(&h)? * per_token(&m[2], expand)?)?)?;
        let h = modulate(&layer_norm_no_affine(&x, LN_EPS)?, &m[3], &m[4], expand)?;
        x.clone() + (self.mlp.forward(&h)? * per_token(&m[5], expand)?)?
    }
}

#[derive(Debug, Clone)]
pub struct Dit {
    action_in: Linear,
    pos: Tensor,
    time: TimeEmbedding,
    cond_in: Linear,
    blocks: Vec<DitBlock>,
    final_ada: Linear,
    action_out: Linear,
}

pub struct DitDims {
    pub action_dim: usize,
    pub chunk_len: usize,
    pub cond_dim: usize,
    pub width: usize,
    pub depth: usize,
    pub heads: usize,
    pub mlp_ratio: usize,
}

impl Dit {
    pub fn new(d: &DitDims, vb: VarBuilder) -> Result<Self> {
        let blocks = (0..d.depth)
            .map(|i| DitBlock::new(d.width, d.heads, d.mlp_ratio, vb.pp(format!("blocks.{i}"))))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            action_in: Linear::new(d.action_dim, d.width, vb.pp("action_in"))?,
            pos: vb.get_with_hints(
                (d.chunk_len, d.width),
                "pos_embed",
                init::Init::Randn { mean: 0.0, stdev: 0.02 },
            )?,
            time: TimeEmbedding::new(d.width.max(32), d.width, vb.pp("time"))?,
            cond_in: Linear::new(d.cond_dim, d.width, vb.pp("cond_in"))?,
            blocks,
            final_ada: Linear::zeros(d.width, 2 * d.width, vb.pp("final_ada"))?,
            action_out: Linear::zeros(d.width, d.action_dim, vb.pp("action_out"))?,
        })
    }

    /// The conditioning vector for a batch: it depends on τ and the observation only, so an ODE solver can
    /// compute the observation part once. `tau`: [B]; `cond`: [B, cond_dim] (the observation embedding, and the
    /// history if the model feeds it) → [B, W] after SiLU.
    pub fn condition(&self, tau: &Tensor, cond: &Tensor) -> Result<Tensor> {
        (self.time.forward(tau)? + self.cond_in.forward(cond)?)?.silu()
    }

    /// `a`: [B, C, D] (normalised actions at flow time τ) → velocity [B, C, D].
    pub fn forward(&self, a: &Tensor, tau: &Tensor, cond: &Tensor) -> Result<Tensor> {
        let c = self.condition(tau, cond)?;
        let mut x = self.action_in.forward(a)?.broadcast_add(&self.pos)?;
        let (b, t, _) = x.dims3()?;
        let expand = token_expansion(b, t, &x)?;
        for block in &self.blocks {
            x = block.forward(&x, &c, &expand)?;
        }
        let m = self.final_ada.forward(&c)?.chunk(2, 1)?;
        let x = modulate(&layer_norm_no_affine(&x, LN_EPS)?, &m[0], &m[1], &expand)?;
        self.action_out.forward(&x)
    }
}

impl Dit {
    pub fn device(&self) -> &candle_core::Device {
        self.pos.device()
    }
}
