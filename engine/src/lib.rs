//! Allocation-free MARS inference engine.
//!
//! [`Engine::load`] reads a checkpoint `mars train` wrote (any policy kind: mars, fm, a2a, noise-a2a) through
//! the checkpoint format's crate (`mars_policy_format`; the engine links neither the trainer nor candle), checks
//! and lays the weights out for the kernels and allocates every buffer a call will ever need. After that,
//! [`Engine::infer`] — normalise the observation → encode → modality weight w → K(w) → K Euler steps of the
//! DiT velocity field → unnormalise the chunk — performs no heap allocation, so it can run on a pinned
//! real-time thread. Its results equal the candle model's (`mars_policy::model::MarsModel`) up to float
//! summation order.
//!
//! The caller gives each call a time budget: the engine keeps a running estimate of its own cost and runs
//! min(K(w), the most steps that fit), saying in the [`Output`] when the deadline cut the steps or when even
//! one step does not fit.
//!
//! ```no_run
//! use mars_engine::{Engine, EngineConfig};
//! use std::time::Duration;
//!
//! let mut engine = Engine::load("runs/nav2d/mars".as_ref(), EngineConfig::with_seed(0))?;
//! let observation = vec![0.0; engine.obs_dim()];
//! let history = vec![0.0; engine.chunk_len() * engine.action_dim()]; // the last C actions, oldest first
//! // On the control thread, every period: no allocation in here.
//! let out = engine.infer(&observation, &history, Duration::from_micros(2500))?;
//! if out.over_budget {
//!     // Not even one step fits the budget: the chunk (one step) is still valid, but late.
//! }
//! let first_action: &[f32] = out.actions().next().unwrap();
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Layout: `weights` (loading, kernel layout) → `matmul` (linear layers through gemm, allocation-free) and
//! `kernels` (norms, activations, attention on slices) → `observe` (inputs → embedding, w, K(w), source) and
//! `velocity` (the DiT) → `engine` (the call), `continuity` (guidance toward committed actions, for a chunk that arrives
//! late); `budget` (cost estimate and step cap), `buffers`, `dims`,
//! `config`, `error`.

mod budget;
mod buffers;
mod cameras;
mod config;
pub mod continuity;
mod conv;
mod dims;
mod engine;
mod error;
mod kernels;
mod matmul;
mod observe;
mod resnet;
mod velocity;
mod weights;

pub use budget::CostEstimate;
pub use config::EngineConfig;
pub use engine::{Engine, Output};
pub use error::{EngineError, Input, LoadError};
pub use resnet::ImageEncoder;

/// An engine is built on one thread and moved to the real-time thread that owns it.
const _: () = {
    const fn assert_send<T: Send>() {}
    assert_send::<Engine>()
};
