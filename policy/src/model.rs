//! The MARS model: observation encoder → modal scheduler w → flow source a0 = (1−w)⊙a≤t + w⊙ε → DiT velocity
//! field, conditioned on the observation embedding (and the history, with `velocity_uses_history`), integrated
//! with K(w) Euler steps. The baselines are the same model with w fixed.

use crate::config::{ModelConfig, PolicyKind};
use crate::encoder::{self, ObsEncoder};
use crate::nn::dit::{Dit, DitDims};
use crate::scheduler::ModalScheduler;
use candle_core::{Device, Result, Tensor};
use candle_nn::VarBuilder;

pub struct MarsModel {
    pub cfg: ModelConfig,
    pub kind: PolicyKind,
    encoder: Box<dyn ObsEncoder>,
    /// `None` for the baselines, whose w is a constant.
    scheduler: Option<ModalScheduler>,
    velocity: Dit,
}

pub use mars_policy_format::steps::steps_for;

impl MarsModel {
    pub fn new(cfg: &ModelConfig, kind: PolicyKind, vb: VarBuilder) -> Result<Self> {
        let encoder = encoder::build(&cfg.encoder, cfg.obs_dim, cfg.obs_embed_dim, vb.pp("encoder"))?;
        let scheduler = match kind.fixed_w(cfg) {
            Some(_) => None,
            None => Some(ModalScheduler::new(
                cfg.obs_embed_dim,
                cfg.scheduler_uses_history.then_some(cfg.history_len * cfg.action_dim),
                cfg.scheduler_hidden,
                cfg.action_dim,
                vb.pp("scheduler"),
            )?),
        };
        let dims = DitDims {
            action_dim: cfg.action_dim,
            chunk_len: cfg.chunk_len,
            cond_dim: cfg.velocity_cond_dim(),
            width: cfg.dit_width,
            depth: cfg.dit_depth,
            heads: cfg.dit_heads,
            mlp_ratio: cfg.dit_mlp_ratio,
        };
        Ok(Self { cfg: cfg.clone(), kind, encoder, scheduler, velocity: Dit::new(&dims, vb.pp("velocity"))? })
    }

    pub fn encode(&self, obs: &Tensor) -> Result<Tensor> {
        self.encoder.forward(obs)
    }

    /// [`Self::encode`] in training: the encoder may augment its input (random crops of camera images).
    pub fn encode_train(&self, obs: &Tensor, rng: &mut rand::rngs::StdRng) -> Result<Tensor> {
        self.encoder.forward_train(obs, rng)
    }

    /// The modality weight w: [B, D]. Learned for MARS, a constant for the baselines.
    pub fn weights(&self, obs_emb: &Tensor, history: &Tensor) -> Result<Tensor> {
        match (&self.scheduler, self.kind.fixed_w(&self.cfg)) {
            (Some(s), _) => s.forward(obs_emb, history),
            (None, Some(w)) => Tensor::full(w, (obs_emb.dim(0)?, self.cfg.action_dim), obs_emb.device()),
            (None, None) => candle_core::bail!("policy {} has neither a scheduler nor a fixed w", self.kind),
        }
    }

    /// The flow source a0 = (1 − w) ⊙ history + w ⊙ ε, with w: [B, D] broadcast over the chunk's steps.
    pub fn source(history: &Tensor, w: &Tensor, eps: &Tensor) -> Result<Tensor> {
        let w = w.unsqueeze(1)?;
        let keep = w.affine(-1.0, 1.0)?;
        history.broadcast_mul(&keep)? + eps.broadcast_mul(&w)?
    }

    /// The velocity field's conditioning input: `obs_emb` [B, E], or [obs_emb ‖ history] [B, E + H·D] when the
    /// field sees the history (`history`: [B, H, D]).
    pub fn conditioning(&self, obs_emb: &Tensor, history: &Tensor) -> Result<Tensor> {
        if self.cfg.velocity_uses_history {
            Tensor::cat(&[obs_emb, &history.flatten_from(1)?], 1)
        } else {
            Ok(obs_emb.clone())
        }
    }

    /// v(a, τ | cond), `cond` from [`Self::conditioning`].
    pub fn velocity(&self, a: &Tensor, tau: &Tensor, cond: &Tensor) -> Result<Tensor> {
        self.velocity.forward(a, tau, cond)
    }

    /// Euler integration of the learned ODE from τ = 0 to 1 in `k` equal steps. `a0`: [B, C, D]; `cond` from
    /// [`Self::conditioning`].
    pub fn integrate(&self, a0: &Tensor, cond: &Tensor, k: usize) -> Result<Tensor> {
        let b = a0.dim(0)?;
        let dt = 1.0 / k as f64;
        let mut a = a0.clone();
        for step in 0..k {
            let tau = Tensor::full((step as f64 * dt) as f32, b, a0.device())?;
            a = (&a + (self.velocity(&a, &tau, cond)? * dt)?)?;
        }
        Ok(a)
    }

    /// Euler integration where row i takes `ks[i]` equal steps, each row on the τ and dt sequence a batch of
    /// one with its K would take. Rows are sorted by K (descending), so the rows still integrating at step j
    /// are a prefix: the batch costs Σ K_i rows of the field, as many as one row at a time.
    pub fn integrate_each(&self, a0: &Tensor, cond: &Tensor, ks: &[usize]) -> Result<Tensor> {
        let (b, dev) = (ks.len(), a0.device());
        let mut order: Vec<usize> = (0..b).collect();
        order.sort_by_key(|&i| std::cmp::Reverse(ks[i]));
        let sorted: Vec<usize> = order.iter().map(|&i| ks[i]).collect();
        let rows = |v: &[usize]| Tensor::from_vec(v.iter().map(|&i| i as u32).collect::<Vec<_>>(), v.len(), dev);
        let (mut a, cond) = (a0.index_select(&rows(&order)?, 0)?, cond.index_select(&rows(&order)?, 0)?);
        for step in 0..sorted.first().copied().unwrap_or(0) {
            let active = sorted.partition_point(|&k| k > step);
            let dt: Vec<f64> = sorted[..active].iter().map(|&k| 1.0 / k as f64).collect();
            let tau: Vec<f32> = dt.iter().map(|dt| (step as f64 * dt) as f32).collect();
            let dt: Vec<f32> = dt.iter().map(|&dt| dt as f32).collect();
            let head = a.narrow(0, 0, active)?;
            let v = self.velocity(&head, &Tensor::from_vec(tau, active, dev)?, &cond.narrow(0, 0, active)?)?;
            let head = (&head + v.broadcast_mul(&Tensor::from_vec(dt, (active, 1, 1), dev)?)?)?;
            a = if active == b { head } else { Tensor::cat(&[&head, &a.narrow(0, active, b - active)?], 0)? };
        }
        let mut inverse = vec![0; b];
        for (at, &i) in order.iter().enumerate() {
            inverse[i] = at;
        }
        a.index_select(&rows(&inverse)?, 0)
    }

    /// One inference for a batch of independent rollouts on normalised inputs: (chunk [B, C, D], w [B, D],
    /// K per row), each row with its own K(w) — what [`Self::sample`] gives each row as a batch of one.
    pub fn sample_each(&self, obs: &Tensor, history: &Tensor, eps: &Tensor) -> Result<(Tensor, Tensor, Vec<usize>)> {
        let emb = self.encode(obs)?;
        let w = self.weights(&emb, history)?;
        let w_inf = w.max(1)?.to_vec1::<f32>()?;
        let ks: Vec<usize> = w_inf.iter().map(|&w| self.cfg.steps_for(w).max(1)).collect();
        let a0 = Self::source(history, &w, eps)?;
        Ok((self.integrate_each(&a0, &self.conditioning(&emb, history)?, &ks)?, w, ks))
    }

    /// One inference on normalised inputs: returns (chunk [B, C, D], w [B, D], K). `eps`: [B, C, D] ~ N(0, I).
    /// K follows the most multimodal sample in the batch (batch 1 at run time).
    pub fn sample(&self, obs: &Tensor, history: &Tensor, eps: &Tensor) -> Result<(Tensor, Tensor, usize)> {
        self.sample_with_steps(obs, history, eps, None)
    }

    /// `sample` with the step count forced to `steps` instead of K(w): an ablation that separates what the
    /// learned field does from what few Euler steps do to it.
    pub fn sample_with_steps(
        &self,
        obs: &Tensor,
        history: &Tensor,
        eps: &Tensor,
        steps: Option<usize>,
    ) -> Result<(Tensor, Tensor, usize)> {
        let emb = self.encode(obs)?;
        let w = self.weights(&emb, history)?;
        let w_inf = w.flatten_all()?.max(0)?.to_scalar::<f32>()?;
        let k = steps.unwrap_or_else(|| self.cfg.steps_for(w_inf)).max(1);
        let a0 = Self::source(history, &w, eps)?;
        Ok((self.integrate(&a0, &self.conditioning(&emb, history)?, k)?, w, k))
    }

    pub fn device(&self) -> &Device {
        self.velocity.device()
    }
}
