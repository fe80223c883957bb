//! Everything before the ODE: normalise the inputs, encode the observation, the modality weight w and K(w),
//! the flow source a0 = (1 − w)⊙history + w⊙ε, and the observation's (and history's) share of the DiT
//! conditioning.

use crate::buffers::Buffers;
use crate::cameras::Cameras;
use crate::dims::Dims;
use crate::kernels::{sigmoid_in_place, silu_in_place};
use crate::matmul::MatMul;
use crate::weights::{Modality, Weights};
use mars_policy_format::normalize::{Normalizer, Stats};
use mars_policy_format::steps::steps_for;

/// (x − mean) / std per dimension, as `Stats::normalize`, from `src` into `dst`.
fn normalize_into(stats: &Stats, src: &[f32], dst: &mut [f32]) {
    let d = stats.dim();
    for (i, (o, &v)) in dst.iter_mut().zip(src).enumerate() {
        *o = (v - stats.mean[i % d]) / stats.std[i % d];
    }
}

/// Normalises `obs` and `hist` (checked by the caller) into `b.obs`, `b.hist`; encodes the cameras' images,
/// if any; computes the embedding `b.emb`, w into `b.w` (the scheduler's, or a baseline's constant) and `b.cond`
/// = cond_in(emb), or cond_in(emb ‖ history) when the velocity field sees the history. Returns K(w).
#[allow(clippy::too_many_arguments)] // the call's state, as the other stages take it
pub fn observe(
    wt: &Weights,
    d: &Dims,
    norm: &Normalizer,
    obs: &[f32],
    hist: &[f32],
    cameras: Option<&mut Cameras>,
    b: &mut Buffers,
    mm: MatMul,
) -> usize {
    normalize_into(&norm.obs, obs, &mut b.obs);
    normalize_into(&norm.action, hist, &mut b.hist);

    let enc_in: &[f32] = match cameras {
        Some(c) => {
            c.encode(&b.obs, &mut b.enc_in);
            &b.enc_in
        }
        None => &b.obs,
    };
    mm.linear(enc_in, 1, &wt.enc_fc1, &mut b.enc_hidden);
    silu_in_place(&mut b.enc_hidden);
    mm.linear(&b.enc_hidden, 1, &wt.enc_fc2, &mut b.emb);

    match &wt.modality {
        Modality::Scheduler { fc1, fc2 } => {
            let input: &[f32] = if b.sched_in.is_empty() {
                &b.emb
            } else {
                let (e, h) = b.sched_in.split_at_mut(d.embed);
                e.copy_from_slice(&b.emb);
                h.copy_from_slice(&b.hist);
                &b.sched_in
            };
            mm.linear(input, 1, fc1, &mut b.sched_hidden);
            silu_in_place(&mut b.sched_hidden);
            mm.linear(&b.sched_hidden, 1, fc2, &mut b.w);
            sigmoid_in_place(&mut b.w);
        }
        Modality::Fixed(w) => b.w.fill(*w),
    }
    let cond_input: &[f32] = if b.cond_input.is_empty() {
        &b.emb
    } else {
        let (e, h) = b.cond_input.split_at_mut(d.embed);
        e.copy_from_slice(&b.emb);
        h.copy_from_slice(&b.hist);
        &b.cond_input
    };
    mm.linear(cond_input, 1, &wt.cond_in, &mut b.cond);
    steps_for(b.w.iter().copied().fold(f32::NEG_INFINITY, f32::max) / d.k_full_w, d.k_max)
}

/// a0 = (1 − w)⊙history + w⊙ε into `b.a`, w per action dimension, in the candle model's op order.
pub fn source(d: &Dims, b: &mut Buffers) {
    for (i, a) in b.a.iter_mut().enumerate() {
        let w = b.w[i % d.action];
        *a = b.hist[i] * (1.0 - w) + b.eps[i] * w;
    }
}
