//! 2-D convolution (no bias, zero padding, as candle's `conv2d_no_bias`) as a product with the kernel, flattened to
//! [out, k·k·in] (candle's [out, in, k, k] with the taps moved outside the channels, so that one kernel row's taps
//! and channels are one contiguous run of the channels-last input), through the engine's allocation-free gemm
//! path (gemm's microkernels on pre-packed weights). Two ways to gather the receptive fields:
//!
//! - **implicit** (wide feature maps, microkernels): no copy. For one kernel row ky, an output pixel's inputs are
//!   k·in contiguous values of the input, and the next pixel's start `stride·in` further on: exactly a matrix
//!   with a column stride, which the microkernel reads in place. So each kernel row is one product over a row
//!   of output pixels, accumulated into the output; pixels whose kernel row hangs over the left or right edge
//!   take only the taps inside, a column of them at a time (their rows are `stride` input rows apart).
//! - **im2col** (small maps, where a row of pixels is too short for the microkernel's 6 columns; the portable
//!   and threaded backends): each output pixel's receptive field is copied into one row of a preallocated
//!   matrix and multiplied as the DiT's token linears are.
//!
//! Activations are channels-last, [pixels, channels] row-major (NHWC for one image): a pixel's channels are
//! contiguous, which is what an im2col row and a product's output row are.

use crate::matmul::Linear;
use crate::matmul::{Chunk, MAX_COLS, MatMul, Simd, pack_panels, tile};

/// One convolution with its input size fixed at load.
#[derive(Debug, Clone)]
pub struct Conv {
    pub cin: usize,
    pub cout: usize,
    pub kernel: usize,
    pub stride: usize,
    pub pad: usize,
    pub in_hw: (usize, usize),
    pub out_hw: (usize, usize),
    /// The kernel as a linear layer [cout, k·k·cin] (taps outer, channels inner) with a zero bias.
    linear: Linear,
    /// The microkernels that read the receptive fields in place, where this convolution uses them.
    implicit: Option<Simd>,
}

/// Output rows narrower than this take im2col: a row is one product of at most [`MAX_COLS`] pixels per call,
/// and a short row leaves the calls narrow.
const IMPLICIT_MIN_WIDTH: usize = 2 * MAX_COLS;

/// Output side of a convolution or pool: ⌊(n + 2·pad − k) / stride⌋ + 1.
pub fn out_size(n: usize, k: usize, stride: usize, pad: usize) -> usize {
    (n + 2 * pad - k) / stride + 1
}

impl Conv {
    /// `weight`: [cout, cin, k, k] row-major (candle's layout); padding k / 2 (the ResNet's "same" padding).
    pub fn new(
        weight: &[f32],
        cin: usize,
        cout: usize,
        kernel: usize,
        stride: usize,
        in_hw: (usize, usize),
        mm: MatMul,
    ) -> Self {
        let pad = kernel / 2;
        let out_hw = (out_size(in_hw.0, kernel, stride, pad), out_size(in_hw.1, kernel, stride, pad));
        let input = cin * kernel * kernel;
        assert_eq!(weight.len(), cout * input, "conv weight length");
        // [cout, cin, ky, kx] → [cout, ky, kx, cin]: an im2col row is then a copy of each kernel tap's channels,
        // contiguous in the channels-last input.
        let mut taps_last = vec![0.0; weight.len()];
        for o in 0..cout {
            for ci in 0..cin {
                for t in 0..kernel * kernel {
                    taps_last[o * input + t * cin + ci] = weight[(o * cin + ci) * kernel * kernel + t];
                }
            }
        }
        let weight = taps_last.into_boxed_slice();
        let panels = pack_panels(&weight, cout, input, mm);
        let linear = Linear { weight, bias: vec![0.0; cout].into_boxed_slice(), input, output: cout, panels };
        let pointwise = kernel == 1 && stride == 1;
        let implicit = match mm {
            MatMul::Microkernel(simd) if !pointwise && out_hw.1 >= IMPLICIT_MIN_WIDTH => Some(simd),
            _ => None,
        };
        Self { cin, cout, kernel, stride, pad, in_hw, out_hw, linear, implicit }
    }

    /// Whether the input is already the im2col matrix (a 1 × 1 convolution with stride 1).
    fn is_pointwise(&self) -> bool {
        self.kernel == 1 && self.stride == 1
    }

    /// Length of the im2col matrix this convolution needs (0 for a pointwise or an implicit one).
    pub fn cols_len(&self) -> usize {
        if self.is_pointwise() || self.implicit.is_some() { 0 } else { self.out_pixels() * self.linear.input }
    }

    pub fn out_pixels(&self) -> usize {
        self.out_hw.0 * self.out_hw.1
    }

    /// Multiply-adds per call (for the benchmark's GFLOP/s).
    pub fn macs(&self) -> usize {
        self.out_pixels() * self.linear.input * self.cout
    }

    /// y [out pixels, cout] = conv(x [in pixels, cin]); `cols` is scratch of at least [`Self::cols_len`].
    pub fn forward(&self, x: &[f32], cols: &mut [f32], y: &mut [f32], mm: MatMul) {
        let rows = self.out_pixels();
        if self.is_pointwise() {
            mm.linear(&x[..rows * self.cin], rows, &self.linear, y);
            return;
        }
        if let Some(simd) = self.implicit {
            self.implicit(simd, x, y);
            return;
        }
        let cols = &mut cols[..self.cols_len()];
        self.im2col(x, cols);
        mm.linear(cols, rows, &self.linear, y);
    }

    /// y = conv(x) with the receptive fields read in place (see the module doc).
    fn implicit(&self, simd: Simd, x: &[f32], y: &mut [f32]) {
        let ((h, w), (ho, wo)) = (self.in_hw, self.out_hw);
        let (k, c, s, pad, n) = (self.kernel, self.cin, self.stride, self.pad, self.cout);
        // Every address below is derived from these two lengths and the fixed geometry; checked once here
        // (the geometry is tested against a direct convolution at the edges, in `tests`).
        assert!(x.len() >= h * w * c && y.len() >= ho * wo * n);
        let y = &mut y[..ho * wo * n];
        y.fill(0.0);
        let tap_row = k * c;
        // Output columns whose whole kernel row is inside the input: ox·s − pad ≥ 0 and ox·s − pad + k ≤ w.
        let ox_lo = pad.div_ceil(s).min(wo);
        let ox_hi = if w + pad >= k { ((w + pad - k) / s + 1).min(wo) } else { 0 }.max(ox_lo);
        let panel_rows = MatMul::Microkernel(simd).panel_rows(n);
        let (xp, yp) = (x.as_ptr(), y.as_mut_ptr());
        for p in 0..n.div_ceil(panel_rows) {
            let out0 = p * panel_rows;
            for ky in 0..k {
                // Output rows whose input row oy·s + ky − pad is inside the image.
                let oy_lo = pad.saturating_sub(ky).div_ceil(s).min(ho);
                let oy_hi = if h + pad > ky { ((h + pad - ky - 1) / s + 1).min(ho) } else { 0 }.max(oy_lo);
                let row_taps = Chunk { k0: ky * tap_row, len: tap_row };
                for oy in oy_lo..oy_hi {
                    let iy = oy * s + ky - pad;
                    for (ox0, nb) in groups(ox_lo, ox_hi) {
                        // SAFETY: pixels ox0..ox0 + nb of output row oy (< ho·wo); their kernel rows lie inside
                        // input row iy (ox·s − pad ≥ 0, + k ≤ w), so rhs reads stay in x; asserted lengths above.
                        unsafe {
                            tile(
                                simd,
                                &self.linear,
                                p,
                                row_taps,
                                nb,
                                yp.add((oy * wo + ox0) * n + out0),
                                n,
                                xp.add((iy * w + ox0 * s - pad) * c),
                                s * c,
                            )
                        };
                    }
                }
                for ox in (0..ox_lo).chain(ox_hi..wo) {
                    // The taps of this column's kernel row that fall inside the input: lo..hi.
                    let ix0 = (ox * s) as isize - pad as isize;
                    let lo = (-ix0).clamp(0, k as isize) as usize;
                    let hi = (w as isize - ix0).clamp(0, k as isize) as usize;
                    if lo >= hi {
                        continue;
                    }
                    let taps = Chunk { k0: ky * tap_row + lo * c, len: (hi - lo) * c };
                    for (oy0, nb) in groups(oy_lo, oy_hi) {
                        let iy0 = oy0 * s + ky - pad;
                        // SAFETY: output pixels (oy0 + j, ox), j < nb, all inside; their taps lo..hi of input row
                        // iy0 + j·s are inside the image (rows checked by oy_lo..oy_hi, taps by lo..hi).
                        unsafe {
                            tile(
                                simd,
                                &self.linear,
                                p,
                                taps,
                                nb,
                                yp.add((oy0 * wo + ox) * n + out0),
                                wo * n,
                                xp.add((iy0 * w) * c).offset((ix0 + lo as isize) * c as isize),
                                s * w * c,
                            )
                        };
                    }
                }
            }
        }
    }

    /// Row p of `cols` = the receptive field of output pixel p, ordered (ky, kx, channel) like the kernel as
    /// stored here; zeros where it hangs over the edge. For one ky the k taps' channels are one contiguous run of
    /// the input row: one copy per kernel row.
    fn im2col(&self, x: &[f32], cols: &mut [f32]) {
        let (h, w) = (self.in_hw.0 as isize, self.in_hw.1 as isize);
        let (k, c, s, pad) = (self.kernel, self.cin, self.stride as isize, self.pad as isize);
        for (p, row) in cols.chunks_exact_mut(self.linear.input).enumerate() {
            let (oy, ox) = ((p / self.out_hw.1) as isize, (p % self.out_hw.1) as isize);
            let ix0 = ox * s - pad;
            // The taps of a kernel row that fall inside the image: lo..hi.
            let lo = (-ix0).clamp(0, k as isize) as usize;
            let hi = (w - ix0).clamp(0, k as isize) as usize;
            for (ky, seg) in row.chunks_exact_mut(k * c).enumerate() {
                let iy = oy * s + ky as isize - pad;
                if iy < 0 || iy >= h || lo >= hi {
                    seg.fill(0.0);
                    continue;
                }
                seg[..lo * c].fill(0.0);
                seg[hi * c..].fill(0.0);
                let start = (iy * w + ix0 + lo as isize) as usize * c;
                seg[lo * c..hi * c].copy_from_slice(&x[start..start + (hi - lo) * c]);
            }
        }
    }
}

/// lo..hi in near-equal groups of at most [`MAX_COLS`] (start, length): 8 → 4 + 4, not 6 + 2, since a narrow
/// call has too few independent accumulators to hide the FMA latency.
fn groups(lo: usize, hi: usize) -> impl Iterator<Item = (usize, usize)> {
    let len = hi.saturating_sub(lo);
    let count = len.div_ceil(MAX_COLS);
    let (base, extra) = (len / count.max(1), len % count.max(1));
    (0..count).scan(lo, move |at, i| {
        let nb = base + usize::from(i < extra);
        let start = *at;
        *at += nb;
        Some((start, nb))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct convolution, f64, from the definition.
    fn direct(x: &[f32], c: &Conv, weight: &[f32]) -> Vec<f32> {
        let ((h, w), (ho, wo), k) = (c.in_hw, c.out_hw, c.kernel);
        let mut y = vec![0.0; ho * wo * c.cout];
        for oy in 0..ho {
            for ox in 0..wo {
                for o in 0..c.cout {
                    let mut acc = 0.0f64;
                    for ci in 0..c.cin {
                        for ky in 0..k {
                            for kx in 0..k {
                                let iy = (oy * c.stride + ky) as isize - c.pad as isize;
                                let ix = (ox * c.stride + kx) as isize - c.pad as isize;
                                if iy < 0 || ix < 0 || iy as usize >= h || ix as usize >= w {
                                    continue;
                                }
                                let v = x[(iy as usize * w + ix as usize) * c.cin + ci] as f64;
                                acc += v * weight[((o * c.cin + ci) * k + ky) * k + kx] as f64;
                            }
                        }
                    }
                    y[(oy * wo + ox) * c.cout + o] = acc as f32;
                }
            }
        }
        y
    }

    #[test]
    fn implicit_and_im2col_products_equal_a_direct_convolution() {
        let f = |i: usize| ((i * 7919 % 1013) as f32 / 1013.0) - 0.5;
        // The ResNet's shapes in small: a 7 × 7 stride-2 stem, 3 × 3 with stride 1 and 2, a 1 × 1 projection with
        // stride 2, a pointwise head; odd sizes so the edges and the last row block are exercised.
        // Maps wide enough for the implicit path (output width ≥ IMPLICIT_MIN_WIDTH) with the same kernels, odd
        // and even widths, outputs that fill 1–4 AVX-512 registers and leave a partial panel.
        let cases = [
            (3, 5, 7, 2, (13, 11)),
            (4, 6, 3, 1, (7, 9)),
            (4, 8, 3, 2, (9, 8)),
            (6, 4, 1, 2, (7, 7)),
            (5, 3, 1, 1, (6, 5)),
            (3, 20, 7, 2, (31, 30)),
            (5, 40, 3, 1, (14, 13)),
            (4, 70, 3, 2, (27, 24)),
            (6, 33, 1, 2, (25, 24)),
            (2, 16, 3, 1, (12, 12)),
        ];
        let mut backends = vec![MatMul::Rows, MatMul::detect(1, false)];
        if backends[1] == MatMul::Microkernel(Simd::Avx512) {
            backends.push(MatMul::Microkernel(Simd::Avx2Fma)); // the CPUs without AVX-512
        }
        backends.dedup();
        for (cin, cout, k, stride, hw) in cases {
            let weight: Vec<f32> = (0..cout * cin * k * k).map(f).collect();
            let x: Vec<f32> = (0..hw.0 * hw.1 * cin).map(|i| f(i + 101)).collect();
            for &mm in &backends {
                let conv = Conv::new(&weight, cin, cout, k, stride, hw, mm);
                let wide = conv.out_hw.1 >= IMPLICIT_MIN_WIDTH && !conv.is_pointwise();
                assert_eq!(
                    conv.implicit.is_some(),
                    wide && mm.uses_panels(),
                    "{cin}→{cout} k{k} s{stride} {hw:?} {mm:?}"
                );
                let want = direct(&x, &conv, &weight);
                let mut cols = vec![f32::NAN; conv.cols_len()];
                let mut y = vec![f32::NAN; conv.out_pixels() * cout];
                conv.forward(&x, &mut cols, &mut y, mm);
                let err = y.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(err < 1e-5, "{cin}→{cout} k{k} s{stride} {hw:?} {mm:?}: max error {err}");
            }
        }
    }
}
