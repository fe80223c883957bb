//! Demos → training samples. Sample t of a demo is (observation_t, the H actions before t, the C actions from
//! t on), normalised; plus its m nearest neighbours in history space and the target spread S_next, both fixed
//! for the whole training run.

use crate::config::ModelConfig;
use crate::knn;
use crate::losses;
use crate::normalize::{Normalizer, Stats};
use candle_core::{Device, Tensor};
use mars_tasks::demo::Demo;

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("no demos to train on")]
    Empty,
    #[error("demo {demo}: {problem}")]
    BadDemo { demo: usize, problem: String },
    #[error("normalisation: {0}")]
    Stats(String),
    #[error(transparent)]
    Knn(#[from] knn::KnnError),
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// All samples, normalised, as flat row-major arrays.
pub struct Dataset {
    pub len: usize,
    pub normalizer: Normalizer,
    pub obs: Vec<f32>,
    pub history: Vec<f32>,
    pub next: Vec<f32>,
    /// `len × m` indices of each sample's nearest neighbours in (normalised) history space.
    pub neighbours: Vec<u32>,
    pub m: usize,
    /// `len × D`: S_next, the spread of the neighbours' next chunks around this sample's.
    pub s_next: Vec<f32>,
}

/// The same data as tensors, for batching with `index_select`.
pub struct DatasetTensors {
    pub obs: Tensor,
    pub history: Tensor,
    pub next: Tensor,
    pub neighbours: Tensor,
    pub s_next: Tensor,
}

fn validate(demos: &[Demo], cfg: &ModelConfig) -> Result<(), DatasetError> {
    if demos.is_empty() {
        return Err(DatasetError::Empty);
    }
    for (i, d) in demos.iter().enumerate() {
        let bad = |problem: String| DatasetError::BadDemo { demo: i, problem };
        if d.is_empty() {
            return Err(bad("has no steps".into()));
        }
        if d.observations.len() != d.actions.len() {
            return Err(bad(format!("{} observations but {} actions", d.observations.len(), d.actions.len())));
        }
        if d.rest_action.len() != cfg.action_dim {
            return Err(bad(format!(
                "rest_action has {} values, the config says action_dim = {}",
                d.rest_action.len(),
                cfg.action_dim
            )));
        }
        for (t, (o, a)) in d.observations.iter().zip(&d.actions).enumerate() {
            if o.len() != cfg.obs_dim {
                return Err(bad(format!(
                    "step {t}: observation has {} values, config obs_dim = {}",
                    o.len(),
                    cfg.obs_dim
                )));
            }
            if a.len() != cfg.action_dim {
                return Err(bad(format!(
                    "step {t}: action has {} values, config action_dim = {}",
                    a.len(),
                    cfg.action_dim
                )));
            }
            if o.iter().chain(a).any(|v| !v.is_finite()) {
                return Err(bad(format!("step {t}: non-finite value")));
            }
        }
    }
    Ok(())
}

/// The H actions before step t (padded with the rest action before the demo starts), oldest first.
pub fn history_window(actions: &[Vec<f32>], rest: &[f32], t: usize, h: usize, out: &mut Vec<f32>) {
    for k in 0..h {
        let idx = t as isize - h as isize + k as isize;
        out.extend_from_slice(if idx < 0 { rest } else { &actions[idx as usize] });
    }
}

/// The C actions from step t on (the last action repeated past the end: the expert holds its final target).
pub fn future_window(actions: &[Vec<f32>], t: usize, c: usize, out: &mut Vec<f32>) {
    for k in 0..c {
        out.extend_from_slice(&actions[(t + k).min(actions.len() - 1)]);
    }
}

impl Dataset {
    pub fn from_demos(demos: &[Demo], cfg: &ModelConfig, m: usize) -> Result<Self, DatasetError> {
        Self::from_demos_with(demos, cfg, m, None)
    }

    /// [`Dataset::from_demos`] normalised with `given` statistics (a dataset's own stats.json) instead of those of
    /// `demos`; the camera dimensions stay raw either way.
    pub fn from_demos_with(
        demos: &[Demo],
        cfg: &ModelConfig,
        m: usize,
        given: Option<&Normalizer>,
    ) -> Result<Self, DatasetError> {
        validate(demos, cfg)?;
        let mut normalizer = match given {
            Some(n) => n.clone(),
            None => Normalizer {
                obs: Stats::fit(demos.iter().flat_map(|d| d.observations.iter().map(|o| o.as_slice())), cfg.obs_dim),
                action: Stats::fit(demos.iter().flat_map(|d| d.actions.iter().map(|a| a.as_slice())), cfg.action_dim),
            },
        };
        if normalizer.obs.dim() != cfg.obs_dim
            || normalizer.action.dim() != cfg.action_dim
            || !normalizer.obs.is_valid()
            || !normalizer.action.is_valid()
        {
            return Err(DatasetError::Stats(format!(
                "statistics for {} observation and {} action values (finite, std > 0) are needed, got {} and {}",
                cfg.obs_dim,
                cfg.action_dim,
                normalizer.obs.dim(),
                normalizer.action.dim()
            )));
        }
        // Camera images are the encoder's input as they are (values in [0, 1]): per-pixel statistics would make
        // a pixel's meaning depend on where the block usually sits.
        for d in crate::encoder::raw_dims(&cfg.encoder, cfg.obs_dim) {
            (normalizer.obs.mean[d], normalizer.obs.std[d]) = (0.0, 1.0);
        }
        let (mut obs, mut history, mut next) = (Vec::new(), Vec::new(), Vec::new());
        for d in demos {
            for t in 0..d.len() {
                obs.extend_from_slice(&d.observations[t]);
                history_window(&d.actions, &d.rest_action, t, cfg.history_len, &mut history);
                future_window(&d.actions, t, cfg.chunk_len, &mut next);
            }
        }
        normalizer.obs.normalize(&mut obs);
        normalizer.action.normalize(&mut history);
        normalizer.action.normalize(&mut next);
        let len = obs.len() / cfg.obs_dim;
        let neighbours = knn::nearest_neighbours(&history, cfg.history_len * cfg.action_dim, m)?;
        let s_next = target_spread(&next, &neighbours, len, m, cfg.chunk_len, cfg.action_dim)?;
        Ok(Self { len, normalizer, obs, history, next, neighbours, m, s_next })
    }

    /// Scales S_next by one factor ≥ 1 so that the q-quantile of the samples' ‖S_next‖∞ becomes 2/√π, the
    /// mean |ε_i − ε_j| of two standard normals: the spread a source of pure noise (w = 1) gives. Returns the
    /// factor. Why: see `TrainConfig::div_target_quantile`.
    pub fn rescale_target_spread(&mut self, q: f64) -> f32 {
        let d = self.s_next.len() / self.len.max(1);
        let mut peaks: Vec<f32> = self.s_next.chunks(d.max(1)).map(|s| s.iter().copied().fold(0.0, f32::max)).collect();
        let at_q = crate::stats::quantile(&mut peaks, q);
        let noise_spread = 2.0 / std::f32::consts::PI.sqrt();
        let factor = if at_q > 0.0 { (noise_spread / at_q).max(1.0) } else { 1.0 };
        self.s_next.iter_mut().for_each(|s| *s *= factor);
        factor
    }

    pub fn tensors(&self, cfg: &ModelConfig, device: &Device) -> Result<DatasetTensors, DatasetError> {
        let (n, c, d) = (self.len, cfg.chunk_len, cfg.action_dim);
        Ok(DatasetTensors {
            obs: Tensor::from_slice(&self.obs, (n, cfg.obs_dim), device)?,
            history: Tensor::from_slice(&self.history, (n, cfg.history_len, d), device)?,
            next: Tensor::from_slice(&self.next, (n, c, d), device)?,
            neighbours: Tensor::from_slice(&self.neighbours, (n, self.m), device)?,
            s_next: Tensor::from_slice(&self.s_next, (n, d), device)?,
        })
    }
}

/// S_next for every sample, through the same `losses::dispersion` that computes S_curr during training.
fn target_spread(next: &[f32], nbrs: &[u32], n: usize, m: usize, c: usize, d: usize) -> Result<Vec<f32>, DatasetError> {
    let dev = Device::Cpu;
    let next_t = Tensor::from_slice(next, (n, c, d), &dev)?;
    let mut out = Vec::with_capacity(n * d);
    // In blocks, so the [block, m, C, D] gather stays small for large datasets.
    for start in (0..n).step_by(4096) {
        let end = (start + 4096).min(n);
        let idx = Tensor::from_slice(&nbrs[start * m..end * m], (end - start) * m, &dev)?;
        let neighbours = next_t.index_select(&idx, 0)?.reshape((end - start, m, c, d))?;
        let centre = next_t.narrow(0, start, end - start)?;
        out.extend(losses::dispersion(&centre, &neighbours)?.flatten_all()?.to_vec1::<f32>()?);
    }
    Ok(out)
}
