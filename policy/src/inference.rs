//! A trained policy behind the `ChunkPolicy` interface: checks and normalises the inputs, samples a chunk with
//! K(w) Euler steps, and returns it in the task's units. Noise comes from the policy's own seeded generator.
//!
//! This path uses candle and allocates on every call; the real-time runtime uses the preallocated engine.

use crate::checkpoint::{self, CheckpointMeta};
use crate::model::MarsModel;
use crate::normalize::Normalizer;
use crate::train::{Trained, randn};
use anyhow::Context;
use candle_core::{Device, Tensor};
use mars_tasks::rollout::{BatchPolicy, ChunkPolicy, PolicyShape, Prediction, noise_key};
use rand::SeedableRng;
use rand::rngs::StdRng;
use std::path::Path;

pub struct MarsPolicy {
    model: MarsModel,
    normalizer: Normalizer,
    rng: StdRng,
    /// Mixed into every batched call's noise key (the batched path draws no noise from `rng`).
    seed: u64,
    /// Forces the ODE step count (an ablation); `None` uses K(w).
    steps: Option<usize>,
}

impl MarsPolicy {
    pub fn new(model: MarsModel, normalizer: Normalizer, seed: u64) -> Self {
        Self { model, normalizer, rng: StdRng::seed_from_u64(seed), seed, steps: None }
    }

    pub fn load(dir: &Path, seed: u64) -> anyhow::Result<(Self, CheckpointMeta)> {
        let loaded = checkpoint::load(dir, &Device::Cpu)?;
        let normalizer = loaded.meta.normalizer.clone();
        Ok((Self::new(loaded.model, normalizer, seed), loaded.meta))
    }

    pub fn from_trained(trained: Trained, seed: u64) -> Self {
        Self::new(trained.model, trained.normalizer, seed)
    }

    /// Re-seed the noise generator (one seed per rollout makes each rollout reproducible on its own).
    pub fn reseed(&mut self, seed: u64) {
        self.rng = StdRng::seed_from_u64(seed);
        self.seed = seed;
    }

    /// Integrate with exactly `steps` Euler steps instead of K(w) (`None`: back to K(w)).
    pub fn force_steps(&mut self, steps: Option<usize>) {
        self.steps = steps;
    }

    /// Ablation: evaluate a checkpoint with another K(w) scale (`model.k_full_w`).
    pub fn set_k_full_w(&mut self, k_full_w: f32) {
        self.model.cfg.k_full_w = k_full_w;
    }

    pub fn model(&self) -> &MarsModel {
        &self.model
    }
}

#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("{what} has {got} values, the policy expects {want}")]
    Length { what: &'static str, got: usize, want: usize },
    #[error("{what}[{index}] is {value}: inputs must be finite")]
    NonFinite { what: &'static str, index: usize, value: f32 },
}

fn check(what: &'static str, x: &[f32], want: usize) -> Result<(), InputError> {
    if x.len() != want {
        return Err(InputError::Length { what, got: x.len(), want });
    }
    match x.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(InputError::NonFinite { what, index, value: x[index] }),
        None => Ok(()),
    }
}

impl PolicyShape for MarsPolicy {
    fn action_dim(&self) -> usize {
        self.model.cfg.action_dim
    }

    fn chunk_len(&self) -> usize {
        self.model.cfg.chunk_len
    }

    fn history_len(&self) -> usize {
        self.model.cfg.history_len
    }
}

impl ChunkPolicy for MarsPolicy {
    fn predict(&mut self, observation: &[f32], history: &[f32]) -> anyhow::Result<Prediction> {
        let (obs, hist) = self.inputs(["observation", "history"], observation, history, 1)?;
        let cfg = &self.model.cfg;
        let dev = self.model.device().clone();
        let eps =
            randn(&mut self.rng, &[1, cfg.chunk_len, cfg.action_dim], &dev)?.affine(f64::from(cfg.source_std), 0.0)?;
        let (chunk, w, k) = self.model.sample_with_steps(&obs, &hist, &eps, self.steps)?;
        self.outputs(&chunk, &w, &[k])?.pop().context("the model answered no row")
    }
}

impl MarsPolicy {
    pub fn normalizer(&self) -> &Normalizer {
        &self.normalizer
    }

    /// `rows` rows of observations and histories, checked (named `what` in errors), normalised, as tensors.
    fn inputs(
        &self,
        what: [&'static str; 2],
        obs: &[f32],
        hist: &[f32],
        rows: usize,
    ) -> anyhow::Result<(Tensor, Tensor)> {
        let cfg = &self.model.cfg;
        let (d, h) = (cfg.action_dim, cfg.history_len);
        check(what[0], obs, rows * cfg.obs_dim)?;
        check(what[1], hist, rows * h * d)?;
        let (mut obs, mut hist) = (obs.to_vec(), hist.to_vec());
        self.normalizer.obs.normalize(&mut obs);
        self.normalizer.action.normalize(&mut hist);
        let dev = self.model.device();
        Ok((Tensor::from_vec(obs, (rows, cfg.obs_dim), dev)?, Tensor::from_vec(hist, (rows, h, d), dev)?))
    }

    /// One prediction per row of `chunks` [B, C, D] and `w` [B, D], in the task's units.
    fn outputs(&self, chunks: &Tensor, w: &Tensor, ks: &[usize]) -> anyhow::Result<Vec<Prediction>> {
        let (c, d) = (self.model.cfg.chunk_len, self.model.cfg.action_dim);
        let mut chunks = chunks.flatten_all()?.to_vec1::<f32>()?;
        self.normalizer.action.denormalize(&mut chunks);
        let w = w.flatten_all()?.to_vec1::<f32>()?;
        Ok(ks
            .iter()
            .enumerate()
            .map(|(i, &k)| Prediction { chunk: chunks[i * c * d..][..c * d].to_vec(), w: w[i * d..][..d].to_vec(), k })
            .collect())
    }
}

/// Many rollouts' calls in one pass: each row normalised, its noise drawn from its key, its own K(w). A forced
/// step count ([`MarsPolicy::force_steps`]) applies to every row.
impl BatchPolicy for MarsPolicy {
    fn predict_batch(
        &mut self,
        observations: &[f32],
        histories: &[f32],
        keys: &[u64],
    ) -> anyhow::Result<Vec<Prediction>> {
        let b = keys.len();
        if b == 0 {
            return Ok(Vec::new());
        }
        let (obs, hist) = self.inputs(["observations", "histories"], observations, histories, b)?;
        let cfg = &self.model.cfg;
        let dev = self.model.device().clone();
        let noise: Vec<Tensor> = keys
            .iter()
            .map(|&key| {
                let mut rng = StdRng::seed_from_u64(noise_key(self.seed, key));
                randn(&mut rng, &[1, cfg.chunk_len, cfg.action_dim], &dev)
            })
            .collect::<candle_core::Result<_>>()?;
        let eps = Tensor::cat(&noise, 0)?.affine(f64::from(cfg.source_std), 0.0)?;
        let (chunks, w, ks) = match self.steps {
            Some(k) => {
                let (chunk, w, _) = self.model.sample_with_steps(&obs, &hist, &eps, Some(k))?;
                (chunk, w, vec![k.max(1); b])
            }
            None => self.model.sample_each(&obs, &hist, &eps)?,
        };
        self.outputs(&chunks, &w, &ks)
    }
}
