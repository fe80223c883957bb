//! Errors. [`EngineError`] is what the hot call returns: a `Copy` enum with no heap data, so reporting bad
//! input costs no allocation and the caller can keep it, log it later or compare it. [`LoadError`] happens
//! once, before any real-time work, and may carry text.

use mars_policy_format::checkpoint::CheckpointError;
use std::path::PathBuf;

/// Which argument of a call was wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Input {
    Observation,
    History,
    /// The explicit noise of [`crate::Engine::infer_with`].
    Noise,
    /// A camera image ([`crate::ImageEncoder::encode`]).
    Image,
    /// The committed actions of [`crate::Engine::infer_after`].
    Committed,
}

impl std::fmt::Display for Input {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Input::Observation => "observation",
            Input::History => "history",
            Input::Noise => "noise",
            Input::Image => "image",
            Input::Committed => "committed actions",
        })
    }
}

/// A failed inference call. Bad input is reported before anything runs, so such a call leaves the engine as
/// it was: the next good call behaves as if the bad one never happened (no noise is drawn).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum EngineError {
    #[error("{what} has {got} values, the engine expects {want}")]
    Length { what: Input, got: usize, want: usize },
    #[error("{what}[{index}] is {value}: inputs must be finite")]
    NonFinite { what: Input, index: usize, value: f32 },
    /// The network overflowed (finite inputs far outside the training range): the chunk is not returned.
    #[error("the chunk is not finite: the inputs are far outside what the policy was trained on")]
    NonFiniteOutput,
    /// Committed actions must be whole rows of the action dimension, fewer than the chunk's rows.
    #[error("committed actions: {got} values are not fewer than {chunk} whole rows of {action}")]
    CommittedRows { got: usize, chunk: usize, action: usize },
    /// Buffers are sized for K_max steps at load time, so a forced K must lie in 1..=K_max.
    #[error("a forced step count must lie in 1..={k_max}, got {k}")]
    Steps { k: usize, k_max: usize },
}

#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The checkpoint cannot be read or its `policy.json` is not valid (`mars_policy_format::checkpoint`'s checks).
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// A valid checkpoint that this engine cannot run.
    #[error("checkpoint {path}: the engine cannot run it: {problem}")]
    Unsupported { path: PathBuf, problem: String },
    /// A tensor the config's network needs is missing, not F32, of another size than the config says or not
    /// finite; or the file holds a tensor that network does not have.
    #[error("checkpoint {path}: tensor `{name}`: {problem}")]
    Tensor { path: PathBuf, name: String, problem: String },
    /// The engine's own settings are invalid.
    #[error("engine config: {0}")]
    Config(String),
}
