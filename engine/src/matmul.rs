//! Linear layers, y = x·Wᵀ + b, through the `gemm` crate, without heap allocation.
//!
//! `gemm::gemm` is not allocation-free in general: its packed path allocates bookkeeping
//! (`vec![false; mc / MR]`) and packing buffers on every call, and that is the path it takes for the
//! multi-row products here (8 tokens × 128–384 outputs). What it does without allocating on every target:
//! matrix-vector products (its gemv kernels; on x86 also products of ≤ 256 outputs, but that "horizontal"
//! path does not exist on ARM). So:
//!
//! - single-row products (encoder, scheduler, the observation's conditioning) call `gemm::gemm` whole: gemv;
//! - multi-row products (the C tokens, the K steps' conditioning, a convolution's pixels), on x86-64 with
//!   AVX2 + FMA, call gemm's own register-blocked microkernels (`gemm_f32::microkernel::fma`, or
//!   `::avx512f` where the CPU has AVX-512F — the ones its packed path uses) directly on weights pre-packed at
//!   load time, 64-byte aligned, into the panel layout those kernels read: gemm's inner loop without its
//!   per-call setup, packing or allocation. Each output accumulates over k in chunks of a few hundred, as in
//!   gemm's packed path (the one candle's matmuls take for these shapes); [`tile`] is one such call with the
//!   caller's strides (a convolution reads its receptive fields in place with it).
//! - on other CPUs (or when asked for, [`crate::EngineConfig::portable_kernels`]) multi-row products are one
//!   `gemm::gemm` gemv per row: allocation-free everywhere, slower;
//! - with `threads > 1`, multi-row products go to `gemm::gemm` whole with rayon parallelism; that path
//!   allocates inside gemm, which is why it is not the default.

use gemm::Parallelism;

/// y = x·Wᵀ + b: what every product here multiplies by.
#[derive(Debug, Clone)]
pub struct Linear {
    /// [out, in], row-major.
    pub weight: Box<[f32]>,
    pub bias: Box<[f32]>,
    pub input: usize,
    pub output: usize,
    /// `weight` in microkernel panel layout for token linears; empty otherwise.
    pub panels: Panels,
}

/// How token products are computed, chosen once at load.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatMul {
    /// gemm's microkernels on pre-packed panels (x86-64 with AVX2 + FMA, or AVX-512F).
    Microkernel(Simd),
    /// One `gemm::gemm` matrix-vector product per row.
    Rows,
    /// `gemm::gemm` whole, rayon-parallel (allocates inside gemm).
    Threaded(usize),
}

/// Which of gemm's microkernel families the panels are packed for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Simd {
    /// 256-bit registers: panels of 16 outputs, 6 rows per call.
    Avx2Fma,
    /// 512-bit registers: panels of 16–64 outputs (as many as the layer has, up to 4 registers), 6 rows per call.
    /// Twice the multiply-adds per instruction: it pays off on the encoder's convolutions.
    Avx512,
}

impl MatMul {
    /// The fastest allocation-free way on this CPU (the portable one if `portable`), or the threaded one
    /// when `threads > 1`.
    pub fn detect(threads: usize, portable: bool) -> Self {
        if threads > 1 {
            MatMul::Threaded(threads)
        } else if portable {
            MatMul::Rows
        } else if panels::avx512_available() {
            MatMul::Microkernel(Simd::Avx512)
        } else if panels::available() {
            MatMul::Microkernel(Simd::Avx2Fma)
        } else {
            MatMul::Rows
        }
    }

    /// Whether token linears need their weights in panel layout ([`pack_panels`]).
    pub fn uses_panels(self) -> bool {
        matches!(self, MatMul::Microkernel(_))
    }

    /// Outputs per weight panel for a layer of `output` outputs (0 where panels are not used).
    pub fn panel_rows(self, output: usize) -> usize {
        match self {
            MatMul::Microkernel(simd) => panels::panel_rows(simd, output),
            _ => 0,
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            MatMul::Microkernel(Simd::Avx2Fma) => "gemm AVX2 + FMA microkernels on pre-packed weights",
            MatMul::Microkernel(Simd::Avx512) => "gemm AVX-512 microkernels on pre-packed weights",
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
            MatMul::Microkernel(simd) if l.panels.len() == panels::packed_len(n, k, self.panel_rows(n)) => {
                // SAFETY: `Microkernel(simd)` is only chosen when the CPU has that family's instructions
                // (`MatMul::detect`, or a caller that checked `panels::*available`); lengths asserted above.
                unsafe { panels::product(simd, x, rows, l, y) }
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

/// Weights in panel layout, 64-byte aligned: each k of a panel is whole 512-bit registers, and a register load
/// from an address that is not 64-byte aligned spans two cache lines (half the load throughput).
#[derive(Debug, Clone, Default)]
pub struct Panels {
    lines: Vec<CacheLine>,
    len: usize,
}

#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
struct CacheLine([f32; 16]);

impl Panels {
    fn zeroed(len: usize) -> Self {
        Self { lines: vec![CacheLine::default(); len.div_ceil(16)], len }
    }

    /// Length in f32 values.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    fn as_ptr(&self) -> *const f32 {
        self.lines.as_ptr().cast()
    }

    fn as_mut_slice(&mut self) -> &mut [f32] {
        // SAFETY: `lines` holds len.div_ceil(16) · 16 ≥ len contiguous f32 values (repr(C) arrays, no padding:
        // 16 · 4 bytes is exactly the 64-byte alignment).
        unsafe { std::slice::from_raw_parts_mut(self.lines.as_mut_ptr().cast(), self.len) }
    }
}

/// `weight` [out, in] in the panel layout of `mm`'s microkernels: panels of [`MatMul::panel_rows`] outputs, each
/// stored k-major ([k][rows], contiguous), the last panel zero-padded. Empty where the microkernels are not used.
pub fn pack_panels(weight: &[f32], output: usize, input: usize, mm: MatMul) -> Panels {
    let mr = mm.panel_rows(output);
    if mr == 0 {
        return Panels::default();
    }
    let mut panels = Panels::zeroed(panels::packed_len(output, input, mr));
    let packed = panels.as_mut_slice();
    for (o, row) in weight.chunks_exact(input).enumerate() {
        let (p, r) = (o / mr, o % mr);
        for (kk, &v) in row.iter().enumerate() {
            packed[p * mr * input + kk * mr + r] = v;
        }
    }
    panels
}

pub(crate) use panels::{Chunk, MAX_COLS, tile};

#[cfg(target_arch = "x86_64")]
mod panels {
    use super::Linear;
    use super::Simd;
    use gemm_common::microkernel::MicroKernelFn;
    use gemm_f32::microkernel::{avx512f::f32 as uk512, fma::f32 as uk256};

    /// f32 lanes of a 256- and a 512-bit register.
    const LANES_256: usize = 8;
    const LANES_512: usize = 16;
    /// Rows of activations per microkernel call (columns of its tile); the same in both families.
    const NR: usize = uk256::NR;
    const _: () = assert!(uk512::NR == NR);

    pub fn available() -> bool {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }

    pub fn avx512_available() -> bool {
        available() && is_x86_feature_detected!("avx512f")
    }

    /// AVX2: gemm's 2-register panels (16 outputs). AVX-512: 1–4 registers, as few as hold the layer's outputs,
    /// so that a 16-channel convolution does not compute 48 padding rows.
    pub fn panel_rows(simd: Simd, output: usize) -> usize {
        match simd {
            Simd::Avx2Fma => uk256::MR_DIV_N * LANES_256,
            Simd::Avx512 => output.div_ceil(LANES_512).clamp(1, uk512::MR_DIV_N) * LANES_512,
        }
    }

    pub fn packed_len(output: usize, input: usize, panel_rows: usize) -> usize {
        output.div_ceil(panel_rows) * panel_rows * input
    }

    /// The kernel for panels of `panel_rows` outputs and exactly `cols` rows of activations (a kernel reads all
    /// its columns).
    fn kernel(simd: Simd, panel_rows: usize, cols: usize) -> MicroKernelFn<f32> {
        match simd {
            Simd::Avx2Fma => uk256::UKR[panel_rows / LANES_256 - 1][cols - 1],
            Simd::Avx512 => uk512::UKR[panel_rows / LANES_512 - 1][cols - 1],
        }
    }

    /// Rows of activations one pass over the weight panels works on: as many as fit in this many bytes, so
    /// that they stay in the L2 cache while every panel reads them (a convolution's im2col matrix has hundreds
    /// or thousands of rows; the DiT's 8 tokens are one block).
    const ROW_BLOCK_BYTES: usize = 128 * 1024;
    const MIN_ROW_BLOCK: usize = 8 * NR;
    /// Columns of one microkernel call at most.
    pub const MAX_COLS: usize = NR;
    /// The reduction is cut into chunks whose slice of one weight panel is at most this large, so that it stays
    /// in the L1 cache while every group of rows of the block reads it (a whole panel of a deep layer, e.g.
    /// 64 outputs × 4608 inputs, is over 1 MB and would be streamed from L2 once per group).
    const PANEL_CHUNK_BYTES: usize = 32 * 1024;

    /// y += x·Wᵀ for `rows` tokens (or pixels), W read from `l.panels`.
    ///
    /// # Safety
    /// The CPU has `simd`'s instructions; `x` holds rows·in values, `y` rows·out, `l.panels` is `pack_panels`
    /// of `l` for `simd`.
    pub unsafe fn product(simd: Simd, x: &[f32], rows: usize, l: &Linear, y: &mut [f32]) {
        let (k, n) = (l.input, l.output);
        let mr = panel_rows(simd, n);
        let kc =
            (std::env::var("KCB").ok().and_then(|v| v.parse().ok()).unwrap_or(PANEL_CHUNK_BYTES) / (4 * mr)).max(1);
        // Not fewer than MIN_ROW_BLOCK rows, though: every block streams all the weights once, and a deep layer's
        // weights (MBs) cost more to stream than its few rows' activations to keep. A whole number of groups of
        // NR rows, so that only the last block has a narrower group.
        let block = (ROW_BLOCK_BYTES / (4 * k)).max(MIN_ROW_BLOCK) / NR * NR;
        for b0 in (0..rows).step_by(block) {
            let brows = block.min(rows - b0);
            // Rows in near-equal groups of at most NR (8 → 4 + 4, not 6 + 2): a narrow group has too few
            // independent accumulators to hide the FMA latency.
            let groups = brows.div_ceil(NR);
            let per_group = brows.div_ceil(groups);
            for k0 in (0..k).step_by(kc) {
                let chunk = Chunk { k0, len: kc.min(k - k0) };
                for p in 0..n.div_ceil(mr) {
                    unsafe { panel(simd, chunk, x, (b0, brows, per_group), p, l, y) };
                }
            }
        }
    }

    /// Inputs k0..k0 + len of the reduction.
    #[derive(Clone, Copy)]
    pub struct Chunk {
        pub k0: usize,
        pub len: usize,
    }

    /// Adds inputs `chunk` of the products for rows b0..b0 + brows of y and the outputs of panel `p`, in groups
    /// of `per_group` rows.
    ///
    /// # Safety
    /// As [`product`].
    unsafe fn panel(
        simd: Simd,
        chunk: Chunk,
        x: &[f32],
        (b0, brows, per_group): (usize, usize, usize),
        p: usize,
        l: &Linear,
        y: &mut [f32],
    ) {
        let (k, n) = (l.input, l.output);
        let mr = panel_rows(simd, n);
        for j0 in (b0..b0 + brows).step_by(per_group) {
            let nb = per_group.min(b0 + brows - j0);
            // Column j of the tile is row j0 + j of x and of y.
            unsafe {
                tile(
                    simd,
                    l,
                    p,
                    chunk,
                    nb,
                    y.as_mut_ptr().add(j0 * n + p * mr),
                    n,
                    x.as_ptr().add(j0 * k + chunk.k0),
                    k,
                )
            };
        }
    }

    /// One microkernel call: dst(i, j) += Σ_{kk < chunk.len} W[p·mr + i, chunk.k0 + kk] · rhs[j·rhs_cs + kk] for
    /// the outputs i of panel `p` (mr per panel) and the `nb` ≤ NR columns j, where dst(i, j) is
    /// `dst[j·dst_cs + i]`. A convolution gives its own strides (`conv`): a column is then an output pixel
    /// whose receptive-field row lies in the input at stride `rhs_cs`, with no im2col copy.
    ///
    /// # Safety
    /// The CPU has `simd`'s instructions; `l.panels` is `pack_panels` of `l` for `simd`; chunk.k0 + chunk.len ≤
    /// l.input; 1 ≤ nb ≤ NR; every dst(i, j) and rhs[j·rhs_cs + kk] addressed lies in its allocation.
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn tile(
        simd: Simd,
        l: &Linear,
        p: usize,
        chunk: Chunk,
        nb: usize,
        dst: *mut f32,
        dst_cs: usize,
        rhs: *const f32,
        rhs_cs: usize,
    ) {
        let (k, n) = (l.input, l.output);
        let mr = panel_rows(simd, n);
        let m = mr.min(n - p * mr);
        // Panel p is [k][mr]: its chunk is contiguous from k0·mr on.
        let lhs = unsafe { l.panels.as_ptr().add(p * mr * k + chunk.k0 * mr) };
        // lhs: mr values per k (column stride mr, row stride 1); rhs(kk, j) = rhs[j·rhs_cs + kk] (row stride 1);
        // dst row stride 1. alpha_status 1: dst = acc + dst (dst holds the bias and the earlier chunks' sums).
        // Rows past `m` of the panel are padding and not stored.
        unsafe {
            kernel(simd, mr, nb)(
                m,
                nb,
                chunk.len,
                dst,
                lhs,
                rhs,
                dst_cs as isize,
                1,
                mr as isize,
                1,
                rhs_cs as isize,
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

#[cfg(not(target_arch = "x86_64"))]
mod panels {
    use super::Linear;
    use super::Simd;

    pub fn panel_rows(_simd: Simd, _output: usize) -> usize {
        1
    }

    pub fn packed_len(_output: usize, _input: usize, _panel_rows: usize) -> usize {
        usize::MAX // never equal to a real length: the microkernel branch is never taken
    }

    pub fn available() -> bool {
        false
    }

    pub fn avx512_available() -> bool {
        false
    }

    pub unsafe fn product(_simd: Simd, _x: &[f32], _rows: usize, _l: &Linear, _y: &mut [f32]) {
        unreachable!("MatMul::Microkernel is never chosen off x86-64")
    }

    pub const MAX_COLS: usize = 1;

    #[derive(Clone, Copy)]
    pub struct Chunk {
        pub k0: usize,
        pub len: usize,
    }

    #[allow(clippy::too_many_arguments)]
    pub unsafe fn tile(
        _simd: Simd,
        _l: &Linear,
        _p: usize,
        _chunk: Chunk,
        _nb: usize,
        _dst: *mut f32,
        _dst_cs: usize,
        _rhs: *const f32,
        _rhs_cs: usize,
    ) {
        unreachable!("MatMul::Microkernel is never chosen off x86-64")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lin(input: usize, output: usize, mm: MatMul) -> Linear {
        let f = |i: usize| ((i * 7919 % 1000) as f32 / 1000.0) - 0.5;
        let weight: Box<[f32]> = (0..input * output).map(f).collect();
        Linear {
            panels: pack_panels(&weight, output, input, mm),
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
        // k of 1, 2 and odd sizes; convolution-sized products that the microkernel path splits into row blocks;
        // outputs that take AVX-512 panels of 1, 2, 3 and 4 registers (7, 20, 40, 100 and 128).
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
            backends.push(MatMul::Microkernel(Simd::Avx2Fma));
        }
        if panels::avx512_available() {
            backends.push(MatMul::Microkernel(Simd::Avx512));
        }
        for &(rows, input, output) in &shapes {
            let x: Vec<f32> = (0..rows * input).map(|i| ((i * 31 % 17) as f32 - 8.0) / 8.0).collect();
            let want = naive(&x, rows, &lin(input, output, MatMul::Rows));
            for &mm in &backends {
                let l = lin(input, output, mm);
                assert_eq!(l.panels.len() == 0, !mm.uses_panels(), "{mm:?}");
                let mut y = vec![f32::NAN; rows * output];
                mm.linear(&x, rows, &l, &mut y);
                let err = y.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(err < 1e-4, "{rows}x{input}x{output} {mm:?}: max error {err}");
            }
        }
    }
}
