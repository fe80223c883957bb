//! A success rate's 95 % interval: Wilson's score interval, which stays inside [0, 1] and does not collapse to a
//! point at 0 or n successes (as the normal approximation does).

use super::Estimate;

/// z for a two-sided 95 % interval.
const Z: f64 = 1.959_963_984_540_054;

/// `successes` of `n` as a rate with its Wilson interval; `None` for no trials.
///
/// ```
/// use mars_tasks::stats::wilson;
/// let e = wilson(20, 20).unwrap();
/// assert_eq!(e.value, 1.0);
/// assert!(e.hi == 1.0 && (e.lo - 0.8389).abs() < 1e-4); // 20/20 is not proof of 100 %
/// let e = wilson(50, 100).unwrap();
/// assert!((e.lo - 0.4038).abs() < 1e-4 && (e.hi - 0.5962).abs() < 1e-4);
/// assert!(wilson(0, 0).is_none());
/// ```
pub fn wilson(successes: usize, n: usize) -> Option<Estimate> {
    if n == 0 || successes > n {
        return None;
    }
    let (k, n) = (successes as f64, n as f64);
    let p = k / n;
    let z2 = Z * Z;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = Z / (1.0 + z2 / n) * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    Some(Estimate::new(p, (centre - half).max(0.0), (centre + half).min(1.0)))
}
