//! Linear layers, y = x·Wᵀ + b, through the `gemm` crate, without heap allocation.
//!
//! `gemm::gemm` is not allocation-free in general: its packed path allocates bookkeeping
//! (`vec![false; mc / MR]`) and packing buffers on every call, and that is the path it takes for the
//! multi-row products here (8 tokens × 128–384 outputs). What it does without allocating on every target:
//! matrix-vector products (its gemv kernels; on x86 also products of ≤ 256 outputs, but that "horizontal"
//! path does not exist on ARM). So:
//!
//! - single-row products (encoder, scheduler, the observation's conditioning) call `gemm::gemm` whole: gemv;
//! - multi-row products (the C tokens, the K steps' conditioning), on x86-64 with AVX2 + FMA, call gemm's own
//!   register-blocked microkernels (`gemm_f32::microkernel::fma`, the ones its packed path uses) directly on
//!   weights pre-packed at load time into the panel layout those kernels read: gemm's inner loop without its
//!   per-call setup, packing or allocation. Each output accumulates over k sequentially, as in gemm's packed
//!   path (the one candle's matmuls take for these shapes).
//! - on other CPUs (or when asked for, [`crate::EngineConfig::portable_kernels`]) multi-row products are one
//!   `gemm::gemm` gemv per row: allocation-free everywhere, slower;
//! - with `threads > 1`, multi-row products go to `gemm::gemm` whole with rayon parallelism; that path
//!   allocates inside gemm, which is why it is not the default.

use crate::weights::Linear;
use gemm::Parallelism;

/// How token products are computed, chosen once at load.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatMul {
    /// gemm's FMA microkernels on pre-packed panels (x86-64 with AVX2 + FMA).
    Microkernel,
    /// One `gemm::gemm` matrix-vector product per row.
    Rows,
    /// `gemm::gemm` whole, rayon-parallel (allocates inside gemm).
    Threaded(usize),
}

impl MatMul {
    /// The fastest allocation-free way on this CPU (the portable one if `portable`), or the threaded one
    /// when `threads > 1`.
    pub fn detect(threads: usize, portable: bool) -> Self {
        if threads > 1 {
            MatMul::Threaded(threads)
        } else if panels::available() && !portable {
            MatMul::Microkernel
        } else {
            MatMul::Rows
        }
    }

    /// Whether token linears need their weights in panel layout ([`pack_panels`]).
    pub fn uses_panels(self) -> bool {
        self == MatMul::Microkernel
    }

    pub fn describe(self) -> &'static str {
        match self {
            MatMul::Microkernel => "gemm FMA microkernels on pre-packed weights",
            MatMul::Rows => "gemm matrix-vector products, one per row (portable)",
            MatMul::Threaded(_) => "gemm, rayon-threaded (allocates)",
        }
    }

    fn parallelism(self) -> Parallelism {
        match self {
            MatMul::Threaded(n) => Parallelism::Rayon(n),
            _ => Parallelism::None,
        }
    }

    /// y[rows, out] = x[rows, in]·Wᵀ + b.
    pub fn linear(self, x: &[f32], rows: usize, l: &Linear, y: &mut [f32]) {
        let (k, n) = (l.input, l.output);
        // These guard the raw-pointer kernel calls below; all sizes are fixed at load, so they never fire.
        assert!(x.len() >= rows * k && y.len() >= rows * n && l.weight.len() == n * k && l.bias.len() == n);
        for row in y[..rows * n].chunks_exact_mut(n) {
            row.copy_from_slice(&l.bias);
        }
        match self {
            _ if rows == 1 => gemm_tiles(x, 1, l, y, 1, n, Parallelism::None),
            MatMul::Microkernel if l.panels.len() == panels::packed_len(n, k) => {
                // SAFETY: `Microkernel` is only chosen when `panels::available()`; lengths asserted above.
                unsafe { panels::product(x, rows, l, y) }
            }
            MatMul::Threaded(_) => gemm_tiles(x, rows, l, y, rows, n, self.parallelism()),
            _ => gemm_tiles(x, rows, l, y, 1, n, Parallelism::None),
        }
    }
}

/// y += x·Wᵀ through `gemm::gemm`, in tiles of `tile_rows` × `tile_cols` outputs.
fn gemm_tiles(x: &[f32], rows: usize, l: &Linear, y: &mut [f32], tile_rows: usize, tile_cols: usize, par: Parallelism) {
    let (k, n) = (l.input, l.output);
    for r0 in (0..rows).step_by(tile_rows) {
        let m = tile_rows.min(rows - r0);
        for c0 in (0..n).step_by(tile_cols) {
            let nc = tile_cols.min(n - c0);
            // SAFETY: dst is y[r0..r0+m, c0..c0+nc] (row stride n); lhs is x[r0..r0+m, ..k] (row stride k);
            // rhs(kk, j) = W[c0 + j, kk] (column stride k). All inside the lengths `linear` asserted.
            unsafe {
                gemm::gemm(
                    m,
                    nc,
                    k,
                    y.as_mut_ptr().add(r0 * n + c0),
                    1,
                    n as isize,
                    true,
                    x.as_ptr().add(r0 * k),
                    1,
                    k as isize,
                    l.weight.as_ptr().add(c0 * k),
                    k as isize,
                    1,
                    1.0,
                    1.0,
                    false,
                    false,
                    false,
                    par,
                );
            }
        }
    }
}

/// `weight` [out, in] in the panel layout of gemm's microkernels: panels of [`panels::MR`] outputs, each
/// stored k-major ([k][MR], contiguous), the last panel zero-padded. Empty where the microkernels are not used.
pub fn pack_panels(weight: &[f32], output: usize, input: usize) -> Box<[f32]> {
    let mr = panels::MR;
    let mut packed = vec![0.0; panels::packed_len(output, input)];
    for (o, row) in weight.chunks_exact(input).enumerate() {
        let (p, r) = (o / mr, o % mr);
        for (kk, &v) in row.iter().enumerate() {
            packed[p * mr * input + kk * mr + r] = v;
        }
    }
    packed.into_boxed_slice()
}

#[cfg(target_arch = "x86_64")]
mod panels {
    use crate::weights::Linear;
    use gemm_f32::microkernel::fma::f32 as uk;

    /// f32 lanes of an AVX register.
    const LANES: usize = 8;
    /// Outputs per panel (rows of gemm's microkernel tile).
    pub const MR: usize = uk::MR_DIV_N * LANES;
    /// Tokens per microkernel call (columns of its tile).
    const NR: usize = uk::NR;

    pub fn packed_len(output: usize, input: usize) -> usize {
        output.div_ceil(MR) * MR * input
    }

    pub fn available() -> bool {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }

    /// Rows of activations one pass over the weight panels works on: as many as fit in this many bytes, so
    /// that they stay in the L2 cache while every panel reads them (a convolution's im2col matrix has hundreds
    /// or thousands of rows; the DiT's 8 tokens are one block).
    const ROW_BLOCK_BYTES: usize = 128 * 1024;
    const MIN_ROW_BLOCK: usize = 8 * NR;

    /// y += x·Wᵀ for `rows` tokens (or pixels), W read from `l.panels`.
    ///
    /// # Safety
    /// The CPU has AVX2 and FMA; `x` holds rows·in values, `y` rows·out, `l.panels` is `pack_panels` of `l`.
    pub unsafe fn product(x: &[f32], rows: usize, l: &Linear, y: &mut [f32]) {
        let (k, n) = (l.input, l.output);
        // Not fewer than MIN_ROW_BLOCK rows, though: every block streams all the weights once, and a deep layer's
        // weights (MBs) cost more to stream than its few rows' activations to keep.
        let block = (ROW_BLOCK_BYTES / (4 * k)).max(MIN_ROW_BLOCK);
        for b0 in (0..rows).step_by(block) {
            let brows = block.min(rows - b0);
            // Rows in near-equal groups of at most NR (8 → 4 + 4, not 6 + 2): a narrow group has too few
            // independent accumulators to hide the FMA latency.
            let groups = brows.div_ceil(NR);
            let per_group = brows.div_ceil(groups);
            for p in 0..n.div_ceil(MR) {
                unsafe { panel(x, b0, brows, per_group, p, l, y) };
            }
        }
    }

    /// Rows b0..b0 + brows of y, outputs of panel `p`, in groups of `per_group` rows.
    ///
    /// # Safety
    /// As [`product`].
    unsafe fn panel(x: &[f32], b0: usize, brows: usize, per_group: usize, p: usize, l: &Linear, y: &mut [f32]) {
        let (k, n) = (l.input, l.output);
        let m = MR.min(n - p * MR);
        let lhs = unsafe { l.panels.as_ptr().add(p * MR * k) };
        for j0 in (b0..b0 + brows).step_by(per_group) {
            let nb = per_group.min(b0 + brows - j0);
            // The kernel for exactly `nb` columns: kernels read all their columns of the activations.
            let ukr = uk::UKR[uk::MR_DIV_N - 1][nb - 1];
            // dst(i, j) = y[j0 + j, p·MR + i]: row stride 1, column stride n. lhs: one zero-padded panel,
            // MR values per k. rhs(kk, j) = x[j0 + j, kk]: row stride 1, column stride k. alpha_status 1:
            // dst = acc + dst (dst holds the bias). Rows past `m` of the panel are padding and not stored.
            unsafe {
                ukr(
                    m,
                    nb,
                    k,
                    y.as_mut_ptr().add(j0 * n + p * MR),
                    lhs,
                    x.as_ptr().add(j0 * k),
                    n as isize,
                    1,
                    MR as isize,
                    1,
                    k as isize,
                    1.0,
                    1.0,
                    1,
                    false,
                    false,
                    false,
                    lhs,
                )
            };
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
mod panels {
    use crate::weights::Linear;

    pub const MR: usize = 1;

    pub fn packed_len(_output: usize, _input: usize) -> usize {
        usize::MAX // never equal to a real length: the microkernel branch is never taken
    }

    pub fn available() -> bool {
        false
    }

    pub unsafe fn product(_x: &[f32], _rows: usize, _l: &Linear, _y: &mut [f32]) {
        unreachable!("MatMul::Microkernel is never chosen off x86-64")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lin(input: usize, output: usize) -> Linear {
        let f = |i: usize| ((i * 7919 % 1000) as f32 / 1000.0) - 0.5;
        let weight: Box<[f32]> = (0..input * output).map(f).collect();
        Linear {
            panels: pack_panels(&weight, output, input),
            weight,
            bias: (0..output).map(|i| f(i + 13)).collect(),
            input,
            output,
        }
    }

    fn naive(x: &[f32], rows: usize, l: &Linear) -> Vec<f32> {
        let mut y = vec![0.0; rows * l.output];
        for r in 0..rows {
            for o in 0..l.output {
                let dot: f64 = (0..l.input).map(|k| x[r * l.input + k] as f64 * l.weight[o * l.input + k] as f64).sum();
                y[r * l.output + o] = (dot + l.bias[o] as f64) as f32;
            }
        }
        y
    }

    #[test]
    fn every_backend_matches_a_naive_product() {
        // rows 1 (gemv), fewer/more than a microkernel's columns; outputs that are not multiples of a panel;
        // k of 1, 2 and odd sizes; convolution-sized products that the microkernel path splits into row blocks.
        let shapes = [
            (1, 2, 128),
            (1, 128, 3328),
            (8, 2, 128),
            (8, 128, 384),
            (3, 33, 7),
            (17, 40, 100),
            (40, 5, 1),
            (700, 147, 20),
            (90, 600, 40),
        ];
        let mut backends = vec![MatMul::Rows, MatMul::Threaded(2)];
        if panels::available() {
            backends.push(MatMul::Microkernel);
        }
        for &(rows, input, output) in &shapes {
            let l = lin(input, output);
            let x: Vec<f32> = (0..rows * input).map(|i| ((i * 31 % 17) as f32 - 8.0) / 8.0).collect();
            let want = naive(&x, rows, &l);
            for &mm in &backends {
                let mut y = vec![f32::NAN; rows * output];
                mm.linear(&x, rows, &l, &mut y);
                let err = y.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(err < 1e-4, "{rows}x{input}x{output} {mm:?}: max error {err}");
            }
        }
    }
}
