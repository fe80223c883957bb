//! The velocity field v(a, τ | obs): the DiT forward pass of `mars_policy::nn::dit`, on the engine's buffers,
//! split into the conditioning of all steps of a call (which does not depend on the ODE state) and the
//! per-step token pass. The observation's share of the conditioning, `cond`, comes from the engine.

use crate::buffers::Buffers;
use crate::dims::Dims;
use crate::kernels::{add_gated, attention, layer_norm_modulate, silu, silu_in_place};
use crate::matmul::MatMul;
use crate::weights::Weights;

/// The DiT conditioning of all `k` Euler steps at once: c_s = silu(time_emb(τ_s) + cond) for τ_s = s/k, then
/// every block's (shift, scale, gate)×2 and the final (shift, scale), into `b.mods` [k, (6·depth + 2)·W].
///
/// c depends on τ and the observation only, never on the ODE state, so the k steps' conditioning is known
/// before the first step. Computing it as [k, ·] products reads the adaLN and time-MLP weights (most of the
/// model's bytes) once per call instead of once per step, and turns k matrix-vector products into one
/// matrix product.
pub fn conditioning(wt: &Weights, d: &Dims, b: &mut Buffers, k: usize, mm: MatMul) {
    let (w, f) = (d.width, d.freq);
    let half = wt.freqs.len();
    let dt = 1.0 / k as f64;
    for (step, row) in b.freq[..k * f].chunks_exact_mut(f).enumerate() {
        // τ exactly as the candle model computes it (in f64, then rounded), scaled to DiT's 0..1000 range;
        // features [cos ‖ sin] of τ·1000·freqs.
        let t = (step as f64 * dt) as f32 * 1000.0;
        for (i, &fr) in wt.freqs.iter().enumerate() {
            let arg = t * fr;
            row[i] = arg.cos();
            row[half + i] = arg.sin();
        }
    }
    mm.linear(&b.freq, k, &wt.time_fc1, &mut b.time_hidden);
    silu_in_place(&mut b.time_hidden[..k * w]);
    mm.linear(&b.time_hidden, k, &wt.time_fc2, &mut b.time_emb);
    for (crow, trow) in b.c[..k * w].chunks_exact_mut(w).zip(b.time_emb.chunks_exact(w)) {
        for ((cv, &te), &co) in crow.iter_mut().zip(trow).zip(b.cond.iter()) {
            *cv = silu(te + co);
        }
    }
    mm.linear(&b.c, k, &wt.ada, &mut b.mods);
}

/// One evaluation of the velocity at Euler step `step` (its conditioning from [`conditioning`]): reads `b.a`,
/// writes `b.v`.
pub fn velocity(wt: &Weights, d: &Dims, b: &mut Buffers, step: usize, mm: MatMul) {
    let (c, w) = (d.chunk, d.width);
    let rows = d.ada_rows();
    let mods = &b.mods[step * rows..(step + 1) * rows];

    // Tokens: one per chunk step.
    mm.linear(&b.a, c, &wt.action_in, &mut b.x);
    for (xv, &p) in b.x.iter_mut().zip(wt.pos.iter()) {
        *xv += p;
    }

    for (i, blk) in wt.blocks.iter().enumerate() {
        let m = &mods[i * 6 * w..(i + 1) * 6 * w];
        let (shift1, scale1, gate1) = (&m[..w], &m[w..2 * w], &m[2 * w..3 * w]);
        let (shift2, scale2, gate2) = (&m[3 * w..4 * w], &m[4 * w..5 * w], &m[5 * w..]);

        layer_norm_modulate(&b.x, shift1, scale1, &mut b.h);
        mm.linear(&b.h, c, &blk.qkv, &mut b.qkv);
        attention(&b.qkv, c, w, d.heads, &mut b.scores, &mut b.attn);
        mm.linear(&b.attn, c, &blk.attn_out, &mut b.proj);
        add_gated(&mut b.x, &b.proj, gate1);

        layer_norm_modulate(&b.x, shift2, scale2, &mut b.h);
        mm.linear(&b.h, c, &blk.fc1, &mut b.mlp_hidden);
        silu_in_place(&mut b.mlp_hidden);
        mm.linear(&b.mlp_hidden, c, &blk.fc2, &mut b.proj);
        add_gated(&mut b.x, &b.proj, gate2);
    }

    let m = &mods[d.depth * 6 * w..];
    layer_norm_modulate(&b.x, &m[..w], &m[w..2 * w], &mut b.h);
    mm.linear(&b.h, c, &wt.action_out, &mut b.v);
}
