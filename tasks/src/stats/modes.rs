//! How far a policy's choice of modes is from the demonstrations'.

/// Each count's share of the total; `None` when the total is 0 (no mode was reached, so there is no share).
///
/// ```
/// assert_eq!(mars_tasks::stats::shares(&[1, 3]), Some(vec![0.25, 0.75]));
/// assert_eq!(mars_tasks::stats::shares(&[0, 0]), None);
/// ```
pub fn shares(counts: &[usize]) -> Option<Vec<f64>> {
    let total: usize = counts.iter().sum();
    (total > 0).then(|| counts.iter().map(|&c| c as f64 / total as f64).collect())
}

/// Total-variation distance ½ Σ |pᵢ − qᵢ| between two share vectors: 0 for the same shares, 1 for shares on
/// disjoint modes. A mode missing from the shorter vector has share 0 there. Unlike γ = k·min/Σ, it weighs every mode, not the rarest alone, so one rollout
/// more or less moves it by at most 1/n.
///
/// ```
/// use mars_tasks::stats::tv_distance;
/// assert_eq!(tv_distance(&[0.5, 0.5], &[0.5, 0.5]), 0.0);
/// assert_eq!(tv_distance(&[1.0, 0.0], &[0.0, 1.0]), 1.0);
/// assert_eq!(tv_distance(&[1.0], &[0.0, 1.0]), 1.0);
/// assert!((tv_distance(&[0.2, 0.15, 0.35, 0.3], &[0.0, 0.0, 0.8, 0.2]) - 0.45).abs() < 1e-12);
/// ```
pub fn tv_distance(p: &[f64], q: &[f64]) -> f64 {
    let at = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(0.0);
    0.5 * (0..p.len().max(q.len())).map(|i| (at(p, i) - at(q, i)).abs()).sum::<f64>()
}

/// The total-variation distance from `counts`' shares to `reference`; 1 (as far as shares can be) when no
/// count is above 0, since then no mode of the reference was reproduced.
pub fn tv_to(counts: &[usize], reference: &[f64]) -> f64 {
    shares(counts).map_or(1.0, |s| tv_distance(&s, reference))
}
