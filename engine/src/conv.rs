//! 2-D convolution (no bias, zero padding, as candle's `conv2d_no_bias`) as im2col + the engine's linear layer:
//! each output pixel's receptive field is copied into one row of a preallocated matrix, and the product with the
//! kernel, flattened to [out, k·k·in] (candle's [out, in, k, k] with the taps moved outside the channels, so each
//! tap's channels are one contiguous copy from the channels-last input), goes through the same allocation-free gemm path
//! as the DiT's token linears (gemm's FMA microkernels on pre-packed weights, in row blocks that stay in cache).
//!
//! Activations are channels-last, [pixels, channels] row-major (NHWC for one image): a pixel's channels are
//! contiguous, which is what an im2col row and a product's output row are.

use crate::matmul::{MatMul, pack_panels};
use crate::weights::Linear;

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
}

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
        let panels = if mm.uses_panels() { pack_panels(&weight, cout, input) } else { Box::default() };
        let linear = Linear { weight, bias: vec![0.0; cout].into_boxed_slice(), input, output: cout, panels };
        Self { cin, cout, kernel, stride, pad, in_hw, out_hw, linear }
    }

    /// Whether the input is already the im2col matrix (a 1 × 1 convolution with stride 1).
    fn is_pointwise(&self) -> bool {
        self.kernel == 1 && self.stride == 1
    }

    /// Length of the im2col matrix this convolution needs (0 for a pointwise one).
    pub fn cols_len(&self) -> usize {
        if self.is_pointwise() { 0 } else { self.out_pixels() * self.linear.input }
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
        let cols = &mut cols[..self.cols_len()];
        self.im2col(x, cols);
        mm.linear(cols, rows, &self.linear, y);
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
    fn im2col_products_equal_a_direct_convolution() {
        let f = |i: usize| ((i * 7919 % 1013) as f32 / 1013.0) - 0.5;
        // The ResNet's shapes in small: a 7 × 7 stride-2 stem, 3 × 3 with stride 1 and 2, a 1 × 1 projection with
        // stride 2, a pointwise head; odd sizes so the edges and the last row block are exercised.
        let cases = [
            (3, 5, 7, 2, (13, 11)),
            (4, 6, 3, 1, (7, 9)),
            (4, 8, 3, 2, (9, 8)),
            (6, 4, 1, 2, (7, 7)),
            (5, 3, 1, 1, (6, 5)),
        ];
        let mut backends = vec![MatMul::Rows, MatMul::detect(1, false)];
        backends.dedup();
        for (cin, cout, k, stride, hw) in cases {
            let weight: Vec<f32> = (0..cout * cin * k * k).map(f).collect();
            let x: Vec<f32> = (0..hw.0 * hw.1 * cin).map(|i| f(i + 101)).collect();
            for &mm in &backends {
                let conv = Conv::new(&weight, cin, cout, k, stride, hw, mm);
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
