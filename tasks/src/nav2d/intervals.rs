//! One nav2d evaluation's figures with their 95 % bootstrap intervals: success, each passage's share of the
//! successes, γ, and the total-variation distance from those shares to the demos'.

use serde::{Deserialize, Serialize};
use std::fmt;

use super::eval::{EvalReport, modal_balance};
use crate::stats::{Bootstrap, Estimate, modes};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalIntervals {
    pub rollouts: usize,
    /// Successful rollouts over all rollouts.
    pub success: Estimate,
    /// Each passage's share of the successful rollouts, in mode order. A resample without a success counts
    /// every share as 0 (no passage was reproduced), which widens these intervals downward when successes are few.
    pub shares: Vec<Estimate>,
    /// γ = k·min/Σ over the passages' success counts.
    pub gamma: Estimate,
    /// ½ Σ |share − demo share|: 0 when the policy picks passages as the demos do, 1 with no success.
    pub tv: Estimate,
}

/// Outcome categories the bootstrap resamples: failure, success through no passage (the agent reached the goal
/// without entering one; kept so the success rate stays right), then success through passage i.
const FAILED: usize = 0;
const NO_PASSAGE: usize = 1;
const FIRST_PASSAGE: usize = 2;

/// The rollouts' passages among a resample's category counts.
fn passages(c: &[usize]) -> Vec<usize> {
    c[FIRST_PASSAGE..].to_vec()
}

/// A resample's success rate.
fn success(c: &[usize]) -> f64 {
    let n: usize = c.iter().sum();
    (n - c[FAILED]) as f64 / n.max(1) as f64
}

/// A resample's γ.
fn gamma(c: &[usize]) -> f64 {
    f64::from(modal_balance(&passages(c)))
}

/// One policy's success and γ less another's, each with its 95 % interval (two independent bootstraps paired
/// resample by resample): what a claim comparing two policies of one run is judged by.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalDifference {
    pub success: Estimate,
    pub gamma: Estimate,
}

impl EvalReport {
    /// The bootstrap of this evaluation's outcome counts (failure, success through no passage, through passage i).
    fn bootstrap(&self, seed: u64) -> Bootstrap {
        let mut counts = vec![0; FIRST_PASSAGE + self.passage_counts.len()];
        for e in &self.episodes {
            let category = match (e.success(), e.mode) {
                (false, _) => FAILED,
                (true, Some(m)) if m < self.passage_counts.len() => FIRST_PASSAGE + m,
                (true, _) => NO_PASSAGE,
            };
            counts[category] += 1;
        }
        Bootstrap::new(&counts, crate::stats::bootstrap::RESAMPLES, seed)
    }

    /// The intervals of this evaluation, against `demo_shares` (the demos' passage shares), seeded by `seed`.
    pub fn intervals(&self, demo_shares: &[f64], seed: u64) -> EvalIntervals {
        let boot = self.bootstrap(seed);
        let share = |i: usize| move |c: &[usize]| modes::shares(&passages(c)).map_or(0.0, |s| s[i]);
        EvalIntervals {
            rollouts: self.episodes.len(),
            success: boot.estimate(success),
            shares: (0..self.passage_counts.len()).map(|i| boot.estimate(share(i))).collect(),
            gamma: boot.estimate(gamma),
            tv: boot.estimate(|c| modes::tv_to(&passages(c), demo_shares)),
        }
    }

    /// This evaluation's success and γ less `other`'s (`seed` and `seed + 1` draw the two bootstraps); `None` when
    /// either has no rollouts or they differ in passages.
    pub fn difference(&self, other: &EvalReport, seed: u64) -> Option<EvalDifference> {
        if self.passage_counts.len() != other.passage_counts.len() {
            return None;
        }
        let (a, b) = (self.bootstrap(seed), other.bootstrap(seed.wrapping_add(1)));
        Some(EvalDifference { success: a.difference(&b, success)?, gamma: a.difference(&b, gamma)? })
    }
}

/// `success 85.0 (82.2–88.0) %, shares 10/12/44/19 (…), γ 0.47 (0.28–0.63), TV 0.21 (0.15–0.27)`.
impl fmt::Display for EvalIntervals {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} rollouts: success {:.1} %, shares", self.rollouts, self.success.scaled(100.0))?;
        for (i, s) in self.shares.iter().enumerate() {
            write!(f, "{}{:.0}", if i == 0 { " " } else { " / " }, s.scaled(100.0))?;
        }
        write!(f, " %, γ {}, TV to the demos {}", self.gamma, self.tv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nav2d::{Episode, Termination};

    fn episode(termination: Termination, mode: Option<usize>) -> Episode {
        Episode { seed: 0, start: [0.0; 2], steps: vec![], calls: vec![], termination, mode }
    }

    /// 100 rollouts: 10 failed, one reached the goal through no passage, 89 split 9/20/30/30 over 4 passages.
    fn report() -> EvalReport {
        let mut e: Vec<Episode> = (0..10).map(|_| episode(Termination::Collision, Some(1))).collect();
        e.push(episode(Termination::Success, None));
        for (passage, n) in [9, 20, 30, 30].into_iter().enumerate() {
            e.extend((0..n).map(|_| episode(Termination::Success, Some(passage))));
        }
        EvalReport::from_episodes(4, e)
    }

    #[test]
    fn values_are_the_reports_and_intervals_hold_them() {
        let r = report().intervals(&[0.25; 4], 1);
        assert_eq!(r.rollouts, 100);
        assert!((r.success.value - 0.90).abs() < 1e-12, "the no-passage success counts: {}", r.success);
        let shares: Vec<f64> = r.shares.iter().map(|s| s.value).collect();
        assert_eq!(shares, [9.0 / 89.0, 20.0 / 89.0, 30.0 / 89.0, 30.0 / 89.0]);
        assert!((r.gamma.value - 4.0 * 9.0 / 89.0).abs() < 1e-6);
        // ½ (|9 − 22.25| + |20 − 22.25| + 2 |30 − 22.25|) / 89
        assert!((r.tv.value - 15.5 / 89.0).abs() < 1e-12, "{}", r.tv);
        for e in [r.success, r.gamma, r.tv].iter().chain(&r.shares) {
            assert!(e.lo <= e.value && e.value <= e.hi && e.lo < e.hi, "{e}");
        }
        // Success's interval is near the normal approximation 0.90 ± 1.96·0.03.
        assert!((r.success.lo - 0.841).abs() < 0.015 && (r.success.hi - 0.959).abs() < 0.015, "{}", r.success);
        assert_eq!(r, report().intervals(&[0.25; 4], 1), "seeded");
        let text = r.to_string();
        assert!(text.starts_with("100 rollouts: success 90.0 (") && text.contains(" %, γ 0.40 ("), "{text}");
    }

    #[test]
    fn a_difference_is_bounded_by_both_evaluations_spreads() {
        let a = report();
        let mut e: Vec<Episode> = (0..40).map(|_| episode(Termination::Timeout, None)).collect();
        e.extend((0..60).map(|i| episode(Termination::Success, Some(i % 2))));
        let b = EvalReport::from_episodes(4, e);
        let d = a.difference(&b, 3).unwrap();
        assert!((d.success.value - 0.30).abs() < 1e-12, "{}", d.success);
        // Wider than either alone: ±1.96·√(0.9·0.1/100 + 0.6·0.4/100) ≈ ±0.11.
        assert!(
            d.success.lo > 0.15 && d.success.lo < 0.22 && d.success.hi > 0.38 && d.success.hi < 0.45,
            "{}",
            d.success
        );
        // b uses two passages of four: γ 0, so the difference is a's γ and its interval a's.
        assert!((d.gamma.value - a.intervals(&[0.25; 4], 3).gamma.value).abs() < 1e-6);
        assert_eq!(a.difference(&b, 3), Some(d), "seeded");
        assert!(a.difference(&EvalReport::from_episodes(2, vec![]), 3).is_none(), "no pairing across layouts");
        assert!(EvalReport::from_episodes(4, vec![]).difference(&b, 3).is_none(), "no rollouts, no interval");
    }

    #[test]
    fn no_success_is_as_far_from_the_demos_as_shares_can_be() {
        let failed = EvalReport::from_episodes(2, vec![episode(Termination::Timeout, None); 5]);
        let r = failed.intervals(&[0.5, 0.5], 0);
        assert_eq!((r.success.value, r.gamma.value, r.tv.value), (0.0, 0.0, 1.0));
        let none = EvalReport::from_episodes(2, vec![]).intervals(&[0.5, 0.5], 0);
        assert_eq!((none.rollouts, none.success.value, none.tv.value), (0, 0.0, 1.0));
    }
}
