//! What an interval allows one to say of a claim "x ≤ bound": met, not met, or undecided.

use super::Estimate;
use serde::{Deserialize, Serialize};
use std::fmt;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Verdict {
    /// The whole interval satisfies the claim.
    Met,
    /// The whole interval violates it.
    NotMet,
    /// The interval straddles the bound: these measurements cannot tell.
    Undecided,
}

impl Verdict {
    /// The claim "the estimated quantity ≤ `bound`".
    ///
    /// ```
    /// use mars_tasks::stats::{Estimate, Verdict};
    /// assert_eq!(Verdict::at_most(Estimate::new(0.02, -0.01, 0.04), 0.05), Verdict::Met);
    /// assert_eq!(Verdict::at_most(Estimate::new(0.09, 0.06, 0.12), 0.05), Verdict::NotMet);
    /// assert_eq!(Verdict::at_most(Estimate::new(0.04, 0.01, 0.07), 0.05), Verdict::Undecided);
    /// ```
    pub fn at_most(e: Estimate, bound: f64) -> Self {
        if e.hi <= bound {
            Self::Met
        } else if e.lo > bound {
            Self::NotMet
        } else {
            Self::Undecided
        }
    }

    /// The claim "the estimated quantity ≥ `bound`".
    pub fn at_least(e: Estimate, bound: f64) -> Self {
        Self::at_most(Estimate::new(-e.value, -e.hi, -e.lo), -bound)
    }
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Met => "met",
            Self::NotMet => "not met",
            Self::Undecided => "undecided",
        })
    }
}
