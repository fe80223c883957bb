//! A percentile bootstrap over one evaluation's rollouts, each rollout one outcome among a few categories
//! (failure, or success through passage i).
//!
//! Each resample draws n rollouts with replacement, so it is a multinomial draw of the category counts; a
//! statistic of the counts (success rate, a share, γ, a distance to the demos' shares) is computed on each
//! resample, and the 2.5th and 97.5th percentiles of those values bound it.

use super::Estimate;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Resamples per interval: the percentiles' own sampling error is then well under the intervals' widths.
pub const RESAMPLES: usize = 2000;

/// The resampled count vectors of one evaluation, drawn once so that every statistic of it (success, each
/// share, γ, the distance to the demos) is bounded on the same resamples.
pub struct Bootstrap {
    counts: Vec<usize>,
    resamples: Vec<Vec<usize>>,
}

impl Bootstrap {
    /// `resamples` multinomial redraws of `counts` (`counts[c]`: rollouts with outcome `c`), seeded by `seed`.
    pub fn new(counts: &[usize], resamples: usize, seed: u64) -> Self {
        let n: usize = counts.iter().sum();
        // Cumulative counts: a uniform draw in 0..n falls in category c with probability counts[c] / n.
        let ends: Vec<usize> = counts
            .iter()
            .scan(0, |acc, &c| {
                *acc += c;
                Some(*acc)
            })
            .collect();
        let mut rng = StdRng::seed_from_u64(seed);
        let resamples = (0..if n == 0 { 0 } else { resamples })
            .map(|_| {
                let mut draw = vec![0usize; counts.len()];
                for _ in 0..n {
                    let u = rng.random_range(0..n);
                    draw[ends.partition_point(|&e| e <= u)] += 1;
                }
                draw
            })
            .collect();
        Self { counts: counts.to_vec(), resamples }
    }

    /// `stat(counts)` with its 95 % percentile interval; with no rollouts the interval is the value itself.
    ///
    /// ```
    /// use mars_tasks::stats::Bootstrap;
    /// // 80 successes of 100: near the normal approximation 0.8 ± 1.96·√(0.8·0.2/100) = 0.72–0.88.
    /// let e = Bootstrap::new(&[20, 80], 2000, 7).estimate(|c| c[1] as f64 / (c[0] + c[1]) as f64);
    /// assert_eq!(e.value, 0.8);
    /// assert!((e.lo - 0.7216).abs() < 0.01 && (e.hi - 0.8784).abs() < 0.01, "{e}");
    /// ```
    pub fn estimate(&self, stat: impl Fn(&[usize]) -> f64) -> Estimate {
        let value = stat(&self.counts);
        if self.resamples.is_empty() {
            return Estimate::new(value, value, value);
        }
        let mut values: Vec<f64> = self.resamples.iter().map(|r| stat(r)).collect();
        values.sort_by(f64::total_cmp);
        Estimate::new(value, percentile(&values, 0.025), percentile(&values, 0.975))
    }
}

impl Bootstrap {
    /// `stat` of this evaluation less `stat` of `other` (another policy's, rolled out independently), with its 95 %
    /// percentile interval: the i-th resample of each paired, as two independent bootstraps are. `None` when the
    /// two were not drawn as many times (they could not pair) or either has no rollouts.
    ///
    /// ```
    /// use mars_tasks::stats::Bootstrap;
    /// let rate = |c: &[usize]| c[1] as f64 / (c[0] + c[1]) as f64;
    /// // 90 % against 80 % of 500 rollouts each: 0.10 ± 1.96·√(0.9·0.1/500 + 0.8·0.2/500) ≈ 0.10 ± 0.044.
    /// let d = Bootstrap::new(&[50, 450], 2000, 1).difference(&Bootstrap::new(&[100, 400], 2000, 2), rate).unwrap();
    /// assert!((d.value - 0.1).abs() < 1e-12);
    /// assert!((d.lo - 0.056).abs() < 0.01 && (d.hi - 0.144).abs() < 0.01, "{d}");
    /// ```
    pub fn difference(&self, other: &Bootstrap, stat: impl Fn(&[usize]) -> f64) -> Option<Estimate> {
        if self.resamples.is_empty() || self.resamples.len() != other.resamples.len() {
            return None;
        }
        let value = stat(&self.counts) - stat(&other.counts);
        let mut values: Vec<f64> =
            self.resamples.iter().zip(&other.resamples).map(|(a, b)| stat(a) - stat(b)).collect();
        values.sort_by(f64::total_cmp);
        Some(Estimate::new(value, percentile(&values, 0.025), percentile(&values, 0.975)))
    }
}

/// Linear interpolation between the closest ranks of sorted `v` (NumPy's default method).
fn percentile(v: &[f64], q: f64) -> f64 {
    let pos = q * (v.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, pos.fract());
    match v.get(i + 1) {
        Some(next) => v[i] + frac * (next - v[i]),
        None => v[i],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_matches_numpys_linear_method() {
        // numpy.percentile([1, 2, 3, 4], [2.5, 50, 97.5]) = [1.075, 2.5, 3.925]
        let v = [1.0, 2.0, 3.0, 4.0];
        for (q, want) in [(0.025, 1.075), (0.5, 2.5), (0.975, 3.925)] {
            assert!((percentile(&v, q) - want).abs() < 1e-12, "q {q}: {} vs {want}", percentile(&v, q));
        }
    }

    #[test]
    fn resamples_draw_each_category_at_its_rate() {
        // The mean of a share over resamples is the share itself (the bootstrap is unbiased for a proportion).
        let counts = [100, 300, 600];
        let share = |c: &[usize]| c[2] as f64 / 1000.0;
        let e = Bootstrap::new(&counts, 4000, 3).estimate(share);
        let mid = (e.lo + e.hi) / 2.0;
        assert!((mid - 0.6).abs() < 0.005, "{e}");
        // Binomial sd √(0.6·0.4/1000) = 0.0155: the 95 % interval is ≈ ±1.96 sd.
        let half = (e.hi - e.lo) / 2.0;
        assert!((half - 1.96 * 0.0155).abs() < 0.003, "half-width {half}");
    }

    #[test]
    fn the_same_seed_gives_the_same_interval_and_no_rollouts_give_the_value() {
        let stat = |c: &[usize]| c[0] as f64;
        assert_eq!(Bootstrap::new(&[3, 4], 100, 9).estimate(stat), Bootstrap::new(&[3, 4], 100, 9).estimate(stat));
        assert_eq!(Bootstrap::new(&[0, 0], 100, 9).estimate(stat), Estimate::new(0.0, 0.0, 0.0));
    }
}
