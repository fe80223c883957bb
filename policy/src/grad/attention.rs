//! Multi-head self-attention over each sample's `tokens` rows, forward and backward, on the packed projection
//! qkv [rows, 3W] (q, k, v side by side, each split into `heads` runs of `dh`), as `crate::nn::attention` lays it
//! out. The chunk has a handful of tokens, so plain loops over one (sample, head) at a time, its q, k and v
//! first copied into contiguous scratch so the inner products run over unit-stride slices.

#[derive(Clone)]
pub struct Attention {
    tokens: usize,
    width: usize,
    heads: usize,
    /// One (sample, head)'s q, k, v [T, dh] and their gradients, and a row of T scores.
    q: Vec<f32>,
    k: Vec<f32>,
    v: Vec<f32>,
    dq: Vec<f32>,
    dk: Vec<f32>,
    dv: Vec<f32>,
    row: Vec<f32>,
}

use super::layers::dot;

/// out += s·x.
fn axpy(s: f32, x: &[f32], out: &mut [f32]) {
    for (o, x) in out.iter_mut().zip(x) {
        *o += s * x;
    }
}

impl Attention {
    pub fn new(tokens: usize, width: usize, heads: usize) -> Self {
        let n = tokens * (width / heads);
        let z = |n: usize| vec![0f32; n];
        Self { tokens, width, heads, q: z(n), k: z(n), v: z(n), dq: z(n), dk: z(n), dv: z(n), row: z(tokens) }
    }

    fn dh(&self) -> usize {
        self.width / self.heads
    }

    /// Copies sample `s`, head `h`'s q, k, v out of qkv into the scratch.
    fn gather(&mut self, qkv: &[f32], s: usize, h: usize) {
        let (t, w, dh) = (self.tokens, self.width, self.dh());
        for i in 0..t {
            let row = &qkv[(s * t + i) * 3 * w..][..3 * w];
            self.q[i * dh..][..dh].copy_from_slice(&row[h * dh..][..dh]);
            self.k[i * dh..][..dh].copy_from_slice(&row[w + h * dh..][..dh]);
            self.v[i * dh..][..dh].copy_from_slice(&row[2 * w + h * dh..][..dh]);
        }
    }

    /// y [rows, W] from qkv [rows, 3W]; keeps the softmax probabilities [samples, heads, T, T] for the backward.
    pub fn forward(&mut self, qkv: &[f32], samples: usize, probs: &mut [f32], y: &mut [f32]) {
        let (t, w, dh) = (self.tokens, self.width, self.dh());
        let scale = 1.0 / (dh as f32).sqrt();
        for s in 0..samples {
            for h in 0..self.heads {
                self.gather(qkv, s, h);
                let p = &mut probs[(s * self.heads + h) * t * t..][..t * t];
                for i in 0..t {
                    let q = &self.q[i * dh..][..dh];
                    let row = &mut p[i * t..][..t];
                    for (r, k) in row.iter_mut().zip(self.k.chunks_exact(dh)) {
                        *r = dot(q, k) * scale;
                    }
                    let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                    let mut sum = 0.0;
                    for r in row.iter_mut() {
                        *r = (*r - max).exp();
                        sum += *r;
                    }
                    for r in row.iter_mut() {
                        *r /= sum;
                    }
                    let out = &mut y[(s * t + i) * w + h * dh..][..dh];
                    out.fill(0.0);
                    for (&pj, v) in row.iter().zip(self.v.chunks_exact(dh)) {
                        axpy(pj, v, out);
                    }
                }
            }
        }
    }

    /// dqkv [rows, 3W] from dy [rows, W] (overwritten, not accumulated).
    pub fn backward(&mut self, qkv: &[f32], probs: &[f32], dy: &[f32], samples: usize, dqkv: &mut [f32]) {
        let (t, w, dh) = (self.tokens, self.width, self.dh());
        let scale = 1.0 / (dh as f32).sqrt();
        for s in 0..samples {
            for h in 0..self.heads {
                self.gather(qkv, s, h);
                self.dq.fill(0.0);
                self.dk.fill(0.0);
                self.dv.fill(0.0);
                let p = &probs[(s * self.heads + h) * t * t..][..t * t];
                for i in 0..t {
                    let dyi = &dy[(s * t + i) * w + h * dh..][..dh];
                    let pi = &p[i * t..][..t];
                    // dP_ij = dy_i · v_j; dv_j += P_ij dy_i.
                    for j in 0..t {
                        self.row[j] = dot(dyi, &self.v[j * dh..][..dh]);
                        axpy(pi[j], dyi, &mut self.dv[j * dh..][..dh]);
                    }
                    // Softmax: dS_ij = P_ij (dP_ij − Σ_k P_ik dP_ik), then through the scaled dot product.
                    let mean = dot(pi, &self.row);
                    for j in 0..t {
                        let g = pi[j] * (self.row[j] - mean) * scale;
                        axpy(g, &self.k[j * dh..][..dh], &mut self.dq[i * dh..][..dh]);
                        axpy(g, &self.q[i * dh..][..dh], &mut self.dk[j * dh..][..dh]);
                    }
                }
                for i in 0..t {
                    let row = &mut dqkv[(s * t + i) * 3 * w..][..3 * w];
                    row[h * dh..][..dh].copy_from_slice(&self.dq[i * dh..][..dh]);
                    row[w + h * dh..][..dh].copy_from_slice(&self.dk[i * dh..][..dh]);
                    row[2 * w + h * dh..][..dh].copy_from_slice(&self.dv[i * dh..][..dh]);
                }
            }
        }
    }
}
