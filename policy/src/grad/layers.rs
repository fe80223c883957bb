//! The element-wise and per-row pieces of the model, forward and backward: SiLU, the sigmoid, LayerNorm without
//! affine parameters, adaLN's modulation and gated residual (one vector per sample, shared by its tokens), and
//! the flow time's sinusoidal features. Each backward returns or accumulates exactly what candle's autograd does
//! for the same expression (`crate::nn`).
//!
//! The loops are compiled for the CPU's widest vectors and chosen at run time (`multiversion`): the crate is
//! built for baseline x86-64, and these were a third of a training step in scalar and SSE code. Only the
//! instructions change, not the order of operations, so every variant gives the same bits.

use multiversion::multiversion;

use super::exp::exp;

/// Σ a_i·b_i over eight running sums, so the compiler can keep them in one vector register (a single running
/// sum is a chain of dependent adds it may not reorder).
#[inline(always)]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// Σ a_i, as [`dot`] does it.
#[inline(always)]
pub fn sum(a: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let c = a.chunks_exact(8);
    let tail: f32 = c.remainder().iter().sum();
    for x in c {
        for i in 0..8 {
            acc[i] += x[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

#[inline(always)]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// y = x·σ(x).
#[multiversion(targets = "simd")]
pub fn silu(x: &[f32], y: &mut [f32]) {
    for (y, &x) in y.iter_mut().zip(x) {
        *y = x * sigmoid(x);
    }
}

/// dx = dy·(σ(x) + x·σ(x)·(1 − σ(x))); in place over `d` (dy in, dx out).
#[multiversion(targets = "simd")]
pub fn silu_backward(x: &[f32], d: &mut [f32]) {
    for (d, &x) in d.iter_mut().zip(x) {
        let s = sigmoid(x);
        *d *= s + x * s * (1.0 - s);
    }
}

/// y = σ(x) in place.
#[multiversion(targets = "simd")]
pub fn sigmoid_in_place(x: &mut [f32]) {
    for x in x {
        *x = sigmoid(*x);
    }
}

/// Per row of `width`: n = (x − mean) / √(var + eps); keeps 1/√(var + eps) per row for the backward.
#[multiversion(targets = "simd")]
pub fn layer_norm(x: &[f32], width: usize, eps: f32, n: &mut [f32], inv_std: &mut [f32]) {
    for ((x, n), inv) in x.chunks_exact(width).zip(n.chunks_exact_mut(width)).zip(inv_std.iter_mut()) {
        let mean = sum(x) / width as f32;
        for (n, v) in n.iter_mut().zip(x) {
            *n = v - mean;
        }
        let var = dot(n, n) / width as f32;
        *inv = 1.0 / (var + eps).sqrt();
        for n in n.iter_mut() {
            *n *= *inv;
        }
    }
}

/// dx += (dn − mean(dn) − n·mean(dn·n)) / √(var + eps), per row.
#[multiversion(targets = "simd")]
pub fn layer_norm_backward(dn: &[f32], n: &[f32], inv_std: &[f32], width: usize, dx: &mut [f32]) {
    let rows = dn.chunks_exact(width).zip(n.chunks_exact(width)).zip(dx.chunks_exact_mut(width));
    for (((dn, n), dx), inv) in rows.zip(inv_std) {
        let mean_dn = sum(dn) / width as f32;
        let mean_dn_n = dot(dn, n) / width as f32;
        for ((dx, dn), n) in dx.iter_mut().zip(dn).zip(n) {
            *dx += (dn - mean_dn - n * mean_dn_n) * inv;
        }
    }
}

/// adaLN: h = n·(1 + scale) + shift, with the sample's `scale` and `shift` (rows of `m` at column offsets
/// `scale_at`, `shift_at`, row stride `m_width`) for each of its `tokens` rows.
pub struct Modulation {
    pub tokens: usize,
    pub width: usize,
    pub m_width: usize,
    pub shift_at: usize,
    pub scale_at: usize,
}

impl Modulation {
    pub fn forward(&self, n: &[f32], m: &[f32], h: &mut [f32]) {
        modulate(self, n, m, h)
    }

    /// dn = dh·(1 + scale); dscale += Σ_tokens dh·n and dshift += Σ_tokens dh into `dm` (same layout as `m`).
    pub fn backward(&self, dh: &[f32], n: &[f32], m: &[f32], dn: &mut [f32], dm: &mut [f32]) {
        modulate_backward(self, dh, n, m, dn, dm)
    }
}

#[multiversion(targets = "simd")]
fn modulate(g: &Modulation, n: &[f32], m: &[f32], h: &mut [f32]) {
    let w = g.width;
    for (r, (n, h)) in n.chunks_exact(w).zip(h.chunks_exact_mut(w)).enumerate() {
        let row = &m[(r / g.tokens) * g.m_width..];
        let (shift, scale) = (&row[g.shift_at..g.shift_at + w], &row[g.scale_at..g.scale_at + w]);
        for i in 0..w {
            h[i] = n[i] * (1.0 + scale[i]) + shift[i];
        }
    }
}

#[multiversion(targets = "simd")]
fn modulate_backward(g: &Modulation, dh: &[f32], n: &[f32], m: &[f32], dn: &mut [f32], dm: &mut [f32]) {
    let w = g.width;
    for (r, ((dh, n), dn)) in dh.chunks_exact(w).zip(n.chunks_exact(w)).zip(dn.chunks_exact_mut(w)).enumerate() {
        let at = (r / g.tokens) * g.m_width;
        let (scale, dscale) = (&m[at + g.scale_at..][..w], at + g.scale_at);
        for i in 0..w {
            dn[i] = dh[i] * (1.0 + scale[i]);
        }
        for i in 0..w {
            dm[dscale + i] += dh[i] * n[i];
        }
        let dshift = &mut dm[at + g.shift_at..][..w];
        for i in 0..w {
            dshift[i] += dh[i];
        }
    }
}

/// x += y·gate, the sample's gate (row of `m` at `gate_at`) for each of its `tokens` rows.
#[multiversion(targets = "simd")]
pub fn gated_add(x: &mut [f32], y: &[f32], m: &[f32], g: &Modulation, gate_at: usize) {
    let w = g.width;
    for (r, (x, y)) in x.chunks_exact_mut(w).zip(y.chunks_exact(w)).enumerate() {
        let gate = &m[(r / g.tokens) * g.m_width + gate_at..][..w];
        for i in 0..w {
            x[i] += y[i] * gate[i];
        }
    }
}

/// Backward of [`gated_add`] for the added branch: dy = dx·gate; dgate += Σ_tokens dx·y (into `dm`).
#[multiversion(targets = "simd")]
pub fn gated_add_backward(
    dx: &[f32],
    y: &[f32],
    m: &[f32],
    g: &Modulation,
    gate_at: usize,
    dy: &mut [f32],
    dm: &mut [f32],
) {
    let w = g.width;
    for (r, ((dx, y), dy)) in dx.chunks_exact(w).zip(y.chunks_exact(w)).zip(dy.chunks_exact_mut(w)).enumerate() {
        let at = (r / g.tokens) * g.m_width + gate_at;
        let gate = &m[at..][..w];
        for i in 0..w {
            dy[i] = dx[i] * gate[i];
        }
        let dgate = &mut dm[at..][..w];
        for i in 0..w {
            dgate[i] += dx[i] * y[i];
        }
    }
}

/// The flow time's features [cos(1000·τ·f_i) …, sin(1000·τ·f_i) …], f_i = 10000^(−i/half), as
/// `crate::nn::time_embed` computes them (in f32, in that order of operations).
pub fn time_features(tau: &[f32], dim: usize, out: &mut [f32]) {
    let half = dim / 2;
    for (t, row) in tau.iter().zip(out.chunks_exact_mut(dim)) {
        let t = t * 1000.0;
        for i in 0..half {
            let f = (-(10_000f32.ln()) * i as f32 / half as f32).exp();
            let arg = t * f;
            row[i] = arg.cos();
            row[half + i] = arg.sin();
        }
    }
}
