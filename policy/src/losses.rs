//! The three MARS losses as plain functions of tensors (all in normalised action units), so each can be
//! checked on hand-computed cases. Shapes: B batch, C chunk steps, D action dims, m neighbours.

use candle_core::{Result, Tensor};

/// L_fm: mean squared error between the predicted velocity and a1 − a0.
pub fn flow_matching(v_pred: &Tensor, a0: &Tensor, a1: &Tensor) -> Result<Tensor> {
    (v_pred - (a1 - a0)?)?.sqr()?.mean_all()
}

/// L_rec: the one-step Euler reconstruction â1 = a0 + v(a0, 0) against a1, L1 per dimension (averaged over
/// the chunk's steps), weighted by (1 − w) and averaged over D and the batch. The weight is detached: it only
/// decides where reconstruction matters and must not teach the scheduler to raise w to escape the penalty.
/// `a1_hat`, `a1`: [B, C, D]; `w`: [B, D].
pub fn reconstruction(a1_hat: &Tensor, a1: &Tensor, w: &Tensor) -> Result<Tensor> {
    let per_dim = (a1_hat - a1)?.abs()?.mean(1)?; // [B, D]
    let keep = w.detach().affine(-1.0, 1.0)?;
    (per_dim * keep)?.mean_all()
}

/// Dispersion S: the mean absolute difference between a sample and each of its neighbours, averaged over the
/// chunk's steps, per action dimension. `centre`: [B, C, D]; `neighbours`: [B, m, C, D] → [B, D].
pub fn dispersion(centre: &Tensor, neighbours: &Tensor) -> Result<Tensor> {
    neighbours.broadcast_sub(&centre.unsqueeze(1)?)?.abs()?.mean(1)?.mean(1)
}

/// L_div = mean over D (and the batch) of ReLU(S_next − S_curr): it only acts when the source spreads less than
/// the demonstrations do after similar histories. `s_next`, `s_curr`: [B, D].
pub fn diversity(s_next: &Tensor, s_curr: &Tensor) -> Result<Tensor> {
    (s_next - s_curr)?.relu()?.mean_all()
}

/// The sources of a sample's neighbours built with *the sample's own* w (so w(i) alone controls the spread it
/// is judged on) and fresh noise. `neighbour_history`: [B, m, H, D]; `w`: [B, D]; `eps`: [B, m, C, D].
pub fn neighbour_sources(neighbour_history: &Tensor, w: &Tensor, eps: &Tensor) -> Result<Tensor> {
    let w = w.unsqueeze(1)?.unsqueeze(1)?; // [B, 1, 1, D]
    neighbour_history.broadcast_mul(&w.affine(-1.0, 1.0)?)? + eps.broadcast_mul(&w)?
}
