//! The element-wise and attention kernels, on plain slices the engine allocated at load time. Each writes into an output it is
//! given and allocates nothing.
//!
//! Element-wise operations follow the candle model's op order exactly (e.g. `x·(1 + scale) + shift` as a
//! multiply then an add, LayerNorm as mean, centre, mean of squares, divide by √(var + ε)), so the only
//! differences from candle come from the summation order inside dot products.

const LN_EPS: f32 = 1e-6;

/// Independent partial sums in reductions. A plain left-to-right f32 sum is one dependency chain (one add
/// per 4 cycles) that the compiler may not reorder; eight lanes of partial sums vectorise and pipeline.
const LANES: usize = 8;

/// Σ aᵢ·bᵢ with [`LANES`] partial sums.
#[inline]
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum();
    let mut acc = [0.0f32; LANES];
    for (x, y) in ca.zip(cb) {
        for i in 0..LANES {
            acc[i] += x[i] * y[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// Σ aᵢ with [`LANES`] partial sums.
#[inline]
fn sum(a: &[f32]) -> f32 {
    let c = a.chunks_exact(LANES);
    let tail: f32 = c.remainder().iter().sum();
    let mut acc = [0.0f32; LANES];
    for x in c {
        for i in 0..LANES {
            acc[i] += x[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// SiLU as candle computes it: x / (1 + e^(−x)).
#[inline]
pub fn silu(v: f32) -> f32 {
    v / (1.0 + (-v).exp())
}

pub fn silu_in_place(x: &mut [f32]) {
    for v in x {
        *v = silu(*v);
    }
}

/// Sigmoid as candle-nn computes it: 1 / (e^(−x) + 1).
pub fn sigmoid_in_place(x: &mut [f32]) {
    for v in x {
        *v = 1.0 / ((-*v).exp() + 1.0);
    }
}

/// out = LayerNorm(x)·(1 + scale) + shift per row of width `shift.len()`, LayerNorm without affine.
/// `shift` and `scale` are per sample, the same for every token.
pub fn layer_norm_modulate(x: &[f32], shift: &[f32], scale: &[f32], out: &mut [f32]) {
    let w = shift.len();
    let inv_w = (1.0 / w as f64) as f32;
    for (xr, or) in x.chunks_exact(w).zip(out.chunks_exact_mut(w)) {
        let mean = sum(xr) * inv_w;
        for (o, &v) in or.iter_mut().zip(xr) {
            *o = v - mean;
        }
        let denom = (dot(or, or) * inv_w + LN_EPS).sqrt();
        for ((o, &sh), &sc) in or.iter_mut().zip(shift).zip(scale) {
            *o = (*o / denom) * (sc + 1.0) + sh;
        }
    }
}

/// x += gate ⊙ y per row (the residual update of a DiT block; `gate` is per sample).
pub fn add_gated(x: &mut [f32], y: &[f32], gate: &[f32]) {
    let w = gate.len();
    for (xr, yr) in x.chunks_exact_mut(w).zip(y.chunks_exact(w)) {
        for ((xv, &yv), &g) in xr.iter_mut().zip(yr).zip(gate) {
            *xv += yv * g;
        }
    }
}

/// Multi-head self-attention core: `qkv` [T, 3W] (q, k, v column blocks, head h at columns h·dh..) →
/// `y` [T, W], heads concatenated. `scores` holds one row of T.
///
/// Plain loops, not gemm: each head's products are T×T×dh (8×8×32 for nav2d), far too small for a gemm
/// call's dispatch to pay off, and they are under 2% of a step's FLOPs.
pub fn attention(qkv: &[f32], tokens: usize, width: usize, heads: usize, scores: &mut [f32], y: &mut [f32]) {
    let dh = width / heads;
    let scale = (1.0 / (dh as f64).sqrt()) as f32;
    let stride = 3 * width;
    let scores = &mut scores[..tokens];
    for h in 0..heads {
        let off = h * dh;
        for i in 0..tokens {
            let q = &qkv[i * stride + off..][..dh];
            for (j, s) in scores.iter_mut().enumerate() {
                let k = &qkv[j * stride + width + off..][..dh];
                *s = dot(q, k) * scale;
            }
            softmax_in_place(scores);
            let yi = &mut y[i * width + off..][..dh];
            yi.fill(0.0);
            for (j, &p) in scores.iter().enumerate() {
                let v = &qkv[j * stride + 2 * width + off..][..dh];
                for (o, &vv) in yi.iter_mut().zip(v) {
                    *o += p * vv;
                }
            }
        }
    }
}

/// Softmax as candle-nn's `ops::softmax`: subtract the max, exponentiate, divide by the sum.
fn softmax_in_place(x: &mut [f32]) {
    let max = x.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut sum = 0.0;
    for v in x.iter_mut() {
        *v = (*v - max).exp();
        sum += *v;
    }
    for v in x.iter_mut() {
        *v /= sum;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reductions_match_plain_sums_for_every_length() {
        for n in [0, 1, 7, 8, 9, 31, 128, 130] {
            let a: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin()).collect();
            let b: Vec<f32> = (0..n).map(|i| (i as f32 * 0.11).cos()).collect();
            let want_dot: f64 = a.iter().zip(&b).map(|(x, y)| *x as f64 * *y as f64).sum();
            let want_sum: f64 = a.iter().map(|x| *x as f64).sum();
            assert!((dot(&a, &b) as f64 - want_dot).abs() < 1e-5, "dot, n = {n}");
            assert!((sum(&a) as f64 - want_sum).abs() < 1e-5, "sum, n = {n}");
        }
    }

    #[test]
    fn layer_norm_gives_zero_mean_unit_variance_before_modulation() {
        let x: Vec<f32> = (0..16).map(|i| (i as f32).powi(2)).collect();
        let mut out = vec![0.0; 16];
        layer_norm_modulate(&x, &[0.0; 8], &[0.0; 8], &mut out);
        for row in out.chunks(8) {
            let mean = row.iter().sum::<f32>() / 8.0;
            let var = row.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / 8.0;
            assert!(mean.abs() < 1e-5 && (var - 1.0).abs() < 1e-4, "mean {mean} var {var}");
        }
        let mut shifted = vec![0.0; 16];
        layer_norm_modulate(&x, &[1.0; 8], &[1.0; 8], &mut shifted);
        for (a, b) in shifted.iter().zip(&out) {
            assert!((a - (2.0 * b + 1.0)).abs() < 1e-5);
        }
    }

    #[test]
    fn attention_with_equal_keys_averages_values() {
        // All keys equal → uniform weights → every output is the mean of the values.
        let (t, w) = (4, 4);
        let mut qkv = vec![0.0; t * 3 * w];
        for j in 0..t {
            for c in 0..w {
                qkv[j * 3 * w + c] = j as f32; // q
                qkv[j * 3 * w + w + c] = 1.0; // k
                qkv[j * 3 * w + 2 * w + c] = (j * w + c) as f32; // v
            }
        }
        let mut y = vec![0.0; t * w];
        attention(&qkv, t, w, 2, &mut [0.0; 4], &mut y);
        for i in 0..t {
            for c in 0..w {
                let mean = (0..t).map(|j| (j * w + c) as f32).sum::<f32>() / t as f32;
                assert!((y[i * w + c] - mean).abs() < 1e-5);
            }
        }
    }
}
