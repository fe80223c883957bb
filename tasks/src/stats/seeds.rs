//! A mean over training seeds and its 95 % Student-t interval.
//!
//! Seeds are few (5 is the floor the method's comparisons use), so the interval is Student's t, not the normal
//! one: with 5 seeds the half-width is 2.78 standard errors, not 1.96.

use super::Estimate;

/// t₀.₉₇₅ for 1–30 degrees of freedom (rounded to 3 places as printed in every table).
const T_975: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131, 2.120,
    2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
];

/// The 97.5 % quantile of Student's t with `df` degrees of freedom: the table up to 30, past it the
/// Cornish–Fisher expansion around the normal quantile (within 2·10⁻⁴ of the exact value from 31 on).
/// `df` 0 has no quantile: infinity.
///
/// ```
/// use mars_tasks::stats::t_quantile_975;
/// assert_eq!(t_quantile_975(4), 2.776);
/// assert!((t_quantile_975(120) - 1.980).abs() < 1e-3);
/// assert!(t_quantile_975(0).is_infinite());
/// ```
pub fn t_quantile_975(df: usize) -> f64 {
    const Z: f64 = 1.959_963_984_540_054;
    match df {
        0 => f64::INFINITY,
        1..=30 => T_975[df - 1],
        _ => {
            let v = df as f64;
            let (z3, z5) = (Z.powi(3), Z.powi(5));
            Z + (z3 + Z) / (4.0 * v) + (5.0 * z5 + 16.0 * z3 + 3.0 * Z) / (96.0 * v * v)
        }
    }
}

/// The mean of `values` (one per seed) with its 95 % t interval; a single value has an infinite interval (one
/// seed says nothing of the spread between seeds). `None` for no values or a non-finite one.
///
/// ```
/// use mars_tasks::stats::mean_over_seeds;
/// let e = mean_over_seeds(&[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
/// assert_eq!(e.value, 3.0);
/// // s = √2.5, half-width = 2.776 · s / √5
/// assert!((e.hi - 3.0 - 2.776 * (2.5f64 / 5.0).sqrt()).abs() < 1e-12);
/// ```
pub fn mean_over_seeds(values: &[f64]) -> Option<Estimate> {
    if values.is_empty() || values.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    if values.len() == 1 {
        return Some(Estimate::new(mean, f64::NEG_INFINITY, f64::INFINITY));
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let half = t_quantile_975(values.len() - 1) * (var / n).sqrt();
    Some(Estimate::new(mean, mean - half, mean + half))
}
