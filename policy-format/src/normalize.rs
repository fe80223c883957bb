//! Dataset statistics that map observations and actions to zero mean, unit variance per dimension. They are
//! saved with the checkpoint: a policy is only meaningful with the statistics it was trained with.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
}

/// A constant dimension has std 0; dividing by it would blow up, so it is left unscaled.
const MIN_STD: f32 = 1e-6;

impl Stats {
    /// Per-dimension mean and std of `rows` (each of length `dim`).
    pub fn fit<'a>(rows: impl Iterator<Item = &'a [f32]>, dim: usize) -> Self {
        let mut n = 0f64;
        let mut sum = vec![0f64; dim];
        let mut sq = vec![0f64; dim];
        for r in rows {
            n += 1.0;
            for d in 0..dim {
                sum[d] += r[d] as f64;
                sq[d] += (r[d] as f64).powi(2);
            }
        }
        let n = n.max(1.0);
        let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
        let std = sq.iter().zip(&mean).map(|(q, m)| ((q / n - m * m).max(0.0)).sqrt() as f32);
        Self {
            mean: mean.iter().map(|&m| m as f32).collect(),
            std: std.map(|s| if s < MIN_STD { 1.0 } else { s }).collect(),
        }
    }

    /// Statistics given from elsewhere (a dataset's stats.json), with the same floor on std as [`Stats::fit`].
    pub fn given(mean: Vec<f32>, std: Vec<f32>) -> Self {
        Self { mean, std: std.into_iter().map(|s| if s < MIN_STD { 1.0 } else { s }).collect() }
    }

    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Normalise in place; `x.len()` is a multiple of the dimension (a chunk of rows).
    pub fn normalize(&self, x: &mut [f32]) {
        let d = self.dim();
        for (i, v) in x.iter_mut().enumerate() {
            *v = (*v - self.mean[i % d]) / self.std[i % d];
        }
    }

    pub fn denormalize(&self, x: &mut [f32]) {
        let d = self.dim();
        for (i, v) in x.iter_mut().enumerate() {
            *v = *v * self.std[i % d] + self.mean[i % d];
        }
    }

    pub fn is_valid(&self) -> bool {
        self.mean.len() == self.std.len()
            && self.mean.iter().all(|m| m.is_finite())
            && self.std.iter().all(|s| s.is_finite() && *s > 0.0)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Normalizer {
    pub obs: Stats,
    pub action: Stats,
}
