//! 2-D navigation benchmark (paper Fig. 1, Appendix A): a point agent passes an entry gate, picks one of
//! several passages (the modes), and leaves through an exit gate to a goal.
//!
//! [`layout`] reads and validates the world, [`env`] simulates it, [`expert`] writes balanced demos,
//! [`eval`] runs a [`crate::rollout::ChunkPolicy`] in closed loop and scores it, [`batch`] runs many rollouts
//! through a [`crate::rollout::BatchPolicy`] at once, [`intervals`] bounds the scores.

pub mod batch;
pub mod env;
pub mod eval;
pub mod expert;
pub mod intervals;
pub mod layout;

pub use batch::evaluate_batched;
pub use env::{Nav2dEnv, StepOutcome};
pub use eval::{Episode, EpisodeRun, EvalReport, Termination, evaluate, modal_balance, run_episode};
pub use expert::generate_demos;
pub use intervals::{EvalDifference, EvalIntervals};
pub use layout::{Layout, LayoutError, Rect};
