//! The step budget: a running estimate of what a call costs, and the largest step count that fits a deadline.
//!
//! A call costs `fixed + K·step`: `fixed` is everything outside the Euler loop (checks, normalisation,
//! encoder, scheduler, noise, source, the observation's conditioning, unnormalisation), `step` one DiT
//! evaluation plus the update. Both are measured on every call with `Instant` and tracked as exponentially
//! weighted moving averages, with an EWMA of the absolute deviation next to each. The estimate used for
//! deadlines is `mean + MARGIN·deviation`: timing noise (an interrupt, a cache miss after the thread was
//! descheduled) is one-sided, and a plain mean would overrun the deadline about half the time.
//!
//! The first estimate comes from the warm-up calls the engine makes at load time (full K_max calls), so a
//! deadline is never decided without measurements.

use std::time::Duration;

/// Weight of a new measurement: about the last 10 calls dominate, so the estimate follows a change in
/// machine load within a few control periods without jumping on one outlier.
const ALPHA: f64 = 0.1;
/// Deviations added to the mean for the deadline estimate.
const MARGIN: f64 = 2.0;

#[derive(Debug, Clone, Copy, Default)]
struct Ewma {
    mean: f64,
    dev: f64,
    seeded: bool,
}

impl Ewma {
    fn update(&mut self, x: f64) {
        if !self.seeded {
            *self = Ewma { mean: x, dev: 0.0, seeded: true };
            return;
        }
        let err = x - self.mean;
        self.mean += ALPHA * err;
        self.dev += ALPHA * (err.abs() - self.dev);
    }

    fn estimate(&self) -> f64 {
        self.mean + MARGIN * self.dev
    }
}

/// The engine's current cost estimate (seconds as `Duration`s), for diagnostics and logging.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CostEstimate {
    /// Estimated cost outside the Euler loop.
    pub fixed: Duration,
    /// Estimated cost of one Euler step.
    pub per_step: Duration,
}

impl CostEstimate {
    /// Estimated cost of a call with `k` steps.
    pub fn call(&self, k: usize) -> Duration {
        self.fixed.saturating_add(self.per_step.saturating_mul(k.min(u32::MAX as usize) as u32))
    }
}

/// The step count chosen for a deadline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plan {
    pub k: usize,
    /// Even one step is estimated not to fit: the call still runs one step (a chunk is always produced) and
    /// the caller is told.
    pub over_budget: bool,
}

#[derive(Debug, Clone, Copy, Default)]
pub struct Estimator {
    /// Nanoseconds.
    fixed: Ewma,
    /// Nanoseconds per step.
    step: Ewma,
}

fn nanos(x: f64) -> Duration {
    // `as u64` saturates and maps NaN to 0; estimates are sums of measured durations, never NaN.
    Duration::from_nanos(x.max(0.0).round() as u64)
}

impl Estimator {
    /// Records one call: `fixed` outside the Euler loop, `steps` for its `k` steps.
    pub fn record(&mut self, fixed: Duration, steps: Duration, k: usize) {
        self.fixed.update(fixed.as_nanos() as f64);
        if k > 0 {
            self.step.update(steps.as_nanos() as f64 / k as f64);
        }
    }

    pub fn estimate(&self) -> CostEstimate {
        CostEstimate { fixed: nanos(self.fixed.estimate()), per_step: nanos(self.step.estimate()) }
    }

    /// The largest K ≤ `k_wanted` whose estimated cost fits `budget`, at least 1.
    pub fn plan(&self, budget: Duration, k_wanted: usize) -> Plan {
        let est = self.estimate();
        let fits = match budget.checked_sub(est.fixed) {
            None => 0,
            Some(_) if est.per_step.is_zero() => u128::MAX,
            Some(left) => left.as_nanos() / est.per_step.as_nanos(),
        };
        let k_deadline = usize::try_from(fits).unwrap_or(usize::MAX).max(1);
        Plan { k: k_wanted.min(k_deadline).max(1), over_budget: fits == 0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn steady(fixed_us: u64, step_us: u64) -> Estimator {
        let mut e = Estimator::default();
        for _ in 0..50 {
            e.record(Duration::from_micros(fixed_us), Duration::from_micros(step_us * 4), 4);
        }
        e
    }

    #[test]
    fn plan_takes_the_largest_k_that_fits() {
        let e = steady(100, 50);
        assert_eq!(e.plan(Duration::from_micros(100 + 3 * 50), 10), Plan { k: 3, over_budget: false });
        assert_eq!(e.plan(Duration::from_micros(100 + 3 * 50 + 49), 10), Plan { k: 3, over_budget: false });
        assert_eq!(e.plan(Duration::from_millis(10), 10), Plan { k: 10, over_budget: false });
        assert_eq!(e.plan(Duration::from_millis(10), 2), Plan { k: 2, over_budget: false });
    }

    #[test]
    fn a_budget_below_one_step_runs_one_step_and_says_so() {
        let e = steady(100, 50);
        assert_eq!(e.plan(Duration::from_micros(149), 10), Plan { k: 1, over_budget: true });
        assert_eq!(e.plan(Duration::ZERO, 10), Plan { k: 1, over_budget: true });
        assert_eq!(e.plan(Duration::from_micros(150), 10), Plan { k: 1, over_budget: false });
    }

    #[test]
    fn the_estimate_follows_a_slowdown_and_adds_a_margin_for_jitter() {
        let mut e = steady(100, 50);
        let before = e.estimate();
        assert_eq!(before.call(2), Duration::from_micros(200));
        for _ in 0..30 {
            e.record(Duration::from_micros(100), Duration::from_micros(100 * 4), 4);
        }
        let after = e.estimate().per_step;
        assert!(after > Duration::from_micros(95) && after < Duration::from_micros(120), "{after:?}");
        // Alternating 40/60 µs steps: mean 50, so the estimate sits above the mean.
        let mut j = Estimator::default();
        for i in 0..200 {
            j.record(Duration::ZERO, Duration::from_micros(if i % 2 == 0 { 40 } else { 60 }), 1);
        }
        let est = j.estimate().per_step;
        assert!(est > Duration::from_micros(60), "{est:?}");
    }
}
