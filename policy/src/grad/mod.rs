//! Training gradients by hand, for state policies: the model and losses `crate::train` trains through candle's
//! autograd, computed forward and backward on preallocated buffers with `gemm` (the kernels candle itself
//! calls), then AdamW. A training step builds no graph and allocates nothing.
//!
//! Data flow of one step ([`HandStep::step`]): the batch's rows → `step` (encoder, scheduler w, source a0) →
//! `dit` (the velocity field on a_τ and a0, forward then backward; `attention`, `layers`, `linear` are its parts,
//! `exp` the e^x they share) → `step` (L_fm, L_rec, L_div and their backward to w and the encoder) → `params`
//! (AdamW). Checked against candle's autograd on the same weights and draws: `policy/tests/hand_gradients.rs`.

// Kernels index several arrays by the same row, token or element: plain index loops read as the formulas do.
#![allow(clippy::needless_range_loop)]

mod attention;
mod dit;
mod exp;
mod layers;
mod linear;
mod params;
mod step;

pub use step::{HandStep, HostData, StepTerms, supports};
