//! Multi-head self-attention over each sample's `tokens` rows, forward and backward, on the packed projection
//! qkv [rows, 3W] (q, k, v side by side, each split into `heads` runs of `dh`), as `crate::nn::attention` lays it
//! out. The chunk has a handful of tokens, so plain loops over one (sample, head) at a time; each token's q, k
//! and v of a head are already `dh` contiguous floats of its qkv row, so they are read in place. Compiled for
//! the CPU's widest vectors (`multiversion`, as `super::layers`).

use multiversion::multiversion;

use super::exp::exp;
use super::layers::dot;

#[derive(Clone)]
pub struct Attention {
    tokens: usize,
    width: usize,
    heads: usize,
    /// One (sample, head)'s dL/dP and dL/dS [T, T], and one column of either.
    dp: Vec<f32>,
    ds: Vec<f32>,
    column: Vec<f32>,
}

/// out[..n] = Σ_j coef[j]·row(j)[..n], summed in j's order from 0. In pieces of 32 floats held in vector
/// registers across the whole sum: adding into `out` row after row instead stalled on reading back each store.
#[inline(always)]
fn weighted_sum<'a>(coef: &[f32], row: impl Fn(usize) -> &'a [f32], out: &mut [f32]) {
    const L: usize = 32;
    let n = out.len();
    let mut pieces = out.chunks_exact_mut(L);
    for (c, piece) in (&mut pieces).enumerate() {
        let mut acc = [0f32; L];
        for (j, &cj) in coef.iter().enumerate() {
            let r = &row(j)[c * L..][..L];
            for l in 0..L {
                acc[l] += cj * r[l];
            }
        }
        piece.copy_from_slice(&acc);
    }
    let done = n - pieces.into_remainder().len();
    for e in done..n {
        out[e] = coef.iter().enumerate().fold(0.0, |acc, (j, &cj)| acc + cj * row(j)[e]);
    }
}

/// Where sample `s`'s token `i`, head `h` of part `part` (0 q, 1 k, 2 v) starts in a [rows, 3W] buffer.
#[inline(always)]
fn at(a: &Attention, s: usize, i: usize, part: usize, h: usize) -> usize {
    let dh = a.width / a.heads;
    (s * a.tokens + i) * 3 * a.width + part * a.width + h * dh
}

impl Attention {
    pub fn new(tokens: usize, width: usize, heads: usize) -> Self {
        let z = |n: usize| vec![0f32; n];
        Self { tokens, width, heads, dp: z(tokens * tokens), ds: z(tokens * tokens), column: z(tokens) }
    }

    /// y [rows, W] from qkv [rows, 3W]; keeps the softmax probabilities [samples, heads, T, T] for the backward.
    pub fn forward(&mut self, qkv: &[f32], samples: usize, probs: &mut [f32], y: &mut [f32]) {
        forward(self, qkv, samples, probs, y)
    }

    /// dqkv [rows, 3W] from dy [rows, W] (overwritten, not accumulated).
    pub fn backward(&mut self, qkv: &[f32], probs: &[f32], dy: &[f32], samples: usize, dqkv: &mut [f32]) {
        let mut scratch =
            [std::mem::take(&mut self.dp), std::mem::take(&mut self.ds), std::mem::take(&mut self.column)];
        backward(self, qkv, probs, dy, samples, dqkv, &mut scratch);
        [self.dp, self.ds, self.column] = scratch;
    }
}

/// In three passes over all (sample, head) blocks, so that the exponentials run over the whole probability
/// buffer at once, in full vectors (a row of T = 8 scores is shorter than one vector, and looped over alone it
/// ran as scalar code): the scaled scores less their row's maximum, then e^x, then each row normalised and
/// applied to v.
#[multiversion(targets = "simd")]
fn forward(a: &Attention, qkv: &[f32], samples: usize, probs: &mut [f32], y: &mut [f32]) {
    let (t, w) = (a.tokens, a.width);
    let dh = w / a.heads;
    let scale = 1.0 / (dh as f32).sqrt();
    let probs = &mut probs[..samples * a.heads * t * t];
    for (block, p) in probs.chunks_exact_mut(t * t).enumerate() {
        let (s, h) = (block / a.heads, block % a.heads);
        for (i, row) in p.chunks_exact_mut(t).enumerate() {
            let q = &qkv[at(a, s, i, 0, h)..][..dh];
            for (j, r) in row.iter_mut().enumerate() {
                *r = dot(q, &qkv[at(a, s, j, 1, h)..][..dh]) * scale;
            }
            let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            for r in row.iter_mut() {
                *r -= max;
            }
        }
    }
    for r in probs.iter_mut() {
        *r = exp(*r);
    }
    for (block, p) in probs.chunks_exact_mut(t * t).enumerate() {
        let (s, h) = (block / a.heads, block % a.heads);
        for (i, row) in p.chunks_exact_mut(t).enumerate() {
            let sum: f32 = row.iter().sum();
            for r in row.iter_mut() {
                *r /= sum;
            }
            weighted_sum(row, |j| &qkv[at(a, s, j, 2, h)..][..dh], &mut y[(s * t + i) * w + h * dh..][..dh]);
        }
    }
}

/// dP = dY·Vᵀ, dS = P ∘ (dP − rowsum(P ∘ dP))·scale, then dQ = dS·K, dK = dSᵀ·Q, dV = Pᵀ·dY, each output row
/// one [`weighted_sum`].
#[multiversion(targets = "simd")]
fn backward(
    a: &Attention,
    qkv: &[f32],
    probs: &[f32],
    dy: &[f32],
    samples: usize,
    dqkv: &mut [f32],
    [dp, ds, column]: &mut [Vec<f32>; 3],
) {
    let (t, w) = (a.tokens, a.width);
    let dh = w / a.heads;
    let scale = 1.0 / (dh as f32).sqrt();
    let dy_of = |s: usize, i: usize, h: usize| &dy[(s * t + i) * w + h * dh..][..dh];
    for s in 0..samples {
        for h in 0..a.heads {
            let p = &probs[(s * a.heads + h) * t * t..][..t * t];
            for i in 0..t {
                for j in 0..t {
                    dp[i * t + j] = dot(dy_of(s, i, h), &qkv[at(a, s, j, 2, h)..][..dh]);
                }
                let (pi, dpi) = (&p[i * t..][..t], &dp[i * t..][..t]);
                let mean = dot(pi, dpi);
                for j in 0..t {
                    ds[i * t + j] = pi[j] * (dpi[j] - mean) * scale;
                }
            }
            for i in 0..t {
                let out = &mut dqkv[at(a, s, i, 0, h)..][..dh];
                weighted_sum(&ds[i * t..][..t], |j| &qkv[at(a, s, j, 1, h)..][..dh], out);
            }
            for j in 0..t {
                for i in 0..t {
                    column[i] = ds[i * t + j];
                }
                weighted_sum(column, |i| &qkv[at(a, s, i, 0, h)..][..dh], &mut dqkv[at(a, s, j, 1, h)..][..dh]);
                for i in 0..t {
                    column[i] = p[i * t + j];
                }
                weighted_sum(column, |i| dy_of(s, i, h), &mut dqkv[at(a, s, j, 2, h)..][..dh]);
            }
        }
    }
}
