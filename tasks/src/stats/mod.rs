//! The numbers a method verdict rests on, each with its interval: a percentile bootstrap over one evaluation's
//! rollouts ([`bootstrap`]), a success rate's Wilson interval ([`proportion`]), a Student-t interval over training seeds ([`seeds`]), the distance between mode
//! shares ([`modes`]), and the three-way verdict an interval allows ([`verdict`]).
//!
//! Why intervals at all: one checkpoint's γ over 100 rollouts moves by up to 0.5 between evaluations, and
//! between training seeds by as much again, so a single number cannot tell two policies apart.

pub mod bootstrap;
pub mod estimate;
pub mod modes;
pub mod proportion;
pub mod seeds;
pub mod verdict;

pub use bootstrap::Bootstrap;
pub use estimate::Estimate;
pub use modes::{shares, tv_distance};
pub use proportion::wilson;
pub use seeds::{mean_over_seeds, t_quantile_975};
pub use verdict::Verdict;
