//! Small statistics shared by training and the commands.

use serde::Serialize;

/// The nearest-rank q-quantile (q in [0, 1]) of `v`; 0 for an empty slice. Sorts `v`.
pub fn quantile(v: &mut [f32], q: f64) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    let rank = ((q.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

/// Mean and sample standard deviation (the curve and ablation tables still print these).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct MeanStd {
    pub mean: f32,
    /// Sample standard deviation (0 for a single seed).
    pub std: f32,
}

impl MeanStd {
    pub fn of(v: &[f32]) -> Self {
        let n = v.len().max(1) as f32;
        let mean = v.iter().sum::<f32>() / n;
        let var = if v.len() > 1 { v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / (n - 1.0) } else { 0.0 };
        Self { mean, std: var.sqrt() }
    }
}

impl std::fmt::Display for MeanStd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = f.precision().unwrap_or(2);
        write!(f, "{:.p$} ± {:.p$}", self.mean, self.std)
    }
}

/// Successful rollouts per passage as shares of all successful rollouts that used a passage.
pub fn proportions(counts: &[usize]) -> Vec<f32> {
    let total: usize = counts.iter().sum();
    counts.iter().map(|&c| if total == 0 { 0.0 } else { c as f32 / total as f32 }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_std_is_the_sample_deviation() {
        let m = MeanStd::of(&[1.0, 2.0, 3.0]);
        assert_eq!(m.mean, 2.0);
        assert!((m.std - 1.0).abs() < 1e-6);
        assert_eq!(MeanStd::of(&[5.0]).std, 0.0);
    }
}
