//! A point value with its 95 % interval.

use serde::{Deserialize, Serialize};
use std::fmt;

/// A value and the 95 % interval around it (`lo ≤ hi`; the value need not be centred).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub value: f64,
    pub lo: f64,
    pub hi: f64,
}

impl Estimate {
    pub fn new(value: f64, lo: f64, hi: f64) -> Self {
        Self { value, lo, hi }
    }

    /// The same estimate in other units (e.g. × 100 for percent).
    pub fn scaled(self, by: f64) -> Self {
        Self { value: self.value * by, lo: self.lo * by, hi: self.hi * by }
    }

    pub fn contains(&self, x: f64) -> bool {
        self.lo <= x && x <= self.hi
    }
}

/// `0.85 (0.82–0.88)`, at the formatter's precision (2 places by default).
///
/// ```
/// use mars_tasks::stats::Estimate;
/// assert_eq!(format!("{:.1}", Estimate::new(85.0, 82.25, 88.0)), "85.0 (82.2–88.0)");
/// assert_eq!(Estimate::new(0.5, 0.25, 0.75).to_string(), "0.50 (0.25–0.75)");
/// ```
impl fmt::Display for Estimate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let p = f.precision().unwrap_or(2);
        write!(f, "{:.p$} ({:.p$}–{:.p$})", self.value, self.lo, self.hi)
    }
}
