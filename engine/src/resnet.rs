//! The policy's image encoder (`mars_policy::nn::resnet::ResNet18`: ResNet-18 with GroupNorm, a spatial-softmax
//! or average-pool head) without heap allocation: every activation, im2col matrix and output buffer is sized at
//! load for the one image size the policy was trained on. Its output equals the candle forward's up to float
//! summation order (tested within 1e-4 in `tests/image_encoder.rs`).
//!
//! Layout: channels-last activations ([pixels, channels]; see `conv`), the image in as [H·W, 3] f32 (the
//! policy's preprocessing, `mars_policy::vision`), the feature vector out.

use std::path::Path;

use mars_policy_format::encoder::{ResNetConfig, ResNetHead};

use crate::conv::{Conv, out_size};
use crate::error::{EngineError, Input, LoadError};
use crate::matmul::Linear;
use crate::matmul::MatMul;
use crate::weights::{Reader, with_reader};

/// candle's GroupNorm ε in the policy's ResNet.
const GN_EPS: f64 = 1e-5;

/// GroupNorm's affine parameters and its grouping.
#[derive(Debug, Clone)]
struct GroupNorm {
    groups: usize,
    gamma: Box<[f32]>,
    beta: Box<[f32]>,
}

impl GroupNorm {
    /// Normalises `x` [pixels, C] in place over each group of C / groups contiguous channels and all pixels, then
    /// scales and shifts per channel; `relu` fuses a ReLU. Per group: the mean, then the variance about it (two
    /// passes, f64 sums, as candle's two-pass formula), then x·a + b per channel with a = γ / √(var + ε) and
    /// b = β − mean·a.
    ///
    /// Each pass sums [`LANES`] channels at a time over all pixels in f64 registers of their own (independent
    /// adds that pipeline), then adds a group's channel sums: a running sum per group was a chain of dependent
    /// adds, and per-channel sums in memory a load and store per value — 16 % of a narrow encoder's time.
    fn apply(&self, x: &mut [f32], channels: usize, relu: bool, s: &mut NormScratch) {
        let per = channels / self.groups;
        let n = (x.len() / channels * per) as f64;
        let (sums, rest) = s.wide[..3 * channels].split_at_mut(channels);
        let (means, squares) = rest.split_at_mut(channels);
        channel_sums(x, channels, sums, |v, _| v);
        for (group, means) in sums.chunks_exact(per).zip(means.chunks_exact_mut(per)) {
            means.fill(group.iter().sum::<f64>() / n);
        }
        channel_sums(x, channels, squares, |v, c| (v - means[c]).powi(2));
        let (a, b) = s.narrow[..2 * channels].split_at_mut(channels);
        for (g, group) in squares.chunks_exact(per).enumerate() {
            let inv = 1.0 / (group.iter().sum::<f64>() / n + GN_EPS).sqrt();
            for c in g * per..(g + 1) * per {
                let scale = self.gamma[c] as f64 * inv;
                a[c] = scale as f32;
                b[c] = (self.beta[c] as f64 - means[c] * scale) as f32;
            }
        }
        for px in x.chunks_exact_mut(channels) {
            for ((v, a), b) in px.iter_mut().zip(a.iter()).zip(b.iter()) {
                let y = *v * a + b;
                *v = if relu { y.max(0.0) } else { y };
            }
        }
    }
}

/// Channels summed together in [`channel_sums`]: 8 f64 accumulators.
const LANES: usize = 8;

/// sums[c] = Σ over pixels of f(x[pixel, c] as f64, c), for `x` [pixels, channels].
#[inline(always)]
fn channel_sums(x: &[f32], channels: usize, sums: &mut [f64], f: impl Fn(f64, usize) -> f64) {
    let mut c0 = 0;
    while c0 + LANES <= channels {
        let mut acc = [0.0f64; LANES];
        for px in x.chunks_exact(channels) {
            let px = &px[c0..c0 + LANES];
            for i in 0..LANES {
                acc[i] += f(px[i] as f64, c0 + i);
            }
        }
        sums[c0..c0 + LANES].copy_from_slice(&acc);
        c0 += LANES;
    }
    for (c, sum) in sums.iter_mut().enumerate().take(channels).skip(c0) {
        *sum = x.iter().skip(c).step_by(channels).map(|v| f(*v as f64, c)).sum();
    }
}

/// GroupNorm's working memory, sized at load for the widest layer: per-channel f64 sums, group means and sums
/// of squares; per-channel f32 scale and shift.
struct NormScratch {
    wide: Box<[f64]>,
    narrow: Box<[f32]>,
}

impl NormScratch {
    fn new(channels: usize) -> Self {
        Self { wide: vec![0.0; 3 * channels].into_boxed_slice(), narrow: vec![0.0; 2 * channels].into_boxed_slice() }
    }
}

#[derive(Debug, Clone)]
struct Block {
    conv1: Conv,
    norm1: GroupNorm,
    conv2: Conv,
    norm2: GroupNorm,
    down: Option<(Conv, GroupNorm)>,
}

#[derive(Debug, Clone)]
enum Head {
    /// 1 × 1 keypoint maps (a linear over each pixel's channels), then each map's expected (x, y).
    SpatialSoftmax {
        keypoints: Linear,
        xs: Box<[f32]>,
        ys: Box<[f32]>,
    },
    AvgPool,
}

/// ResNet-18 forward on one image of the size given at load; see the module doc.
pub struct ImageEncoder {
    mm: MatMul,
    height: usize,
    width: usize,
    stem: Conv,
    stem_norm: GroupNorm,
    pooled_hw: (usize, usize),
    blocks: Vec<Block>,
    head: Head,
    /// Activations: the current feature map and three scratch maps, each as large as the largest.
    x: Box<[f32]>,
    t1: Box<[f32]>,
    t2: Box<[f32]>,
    t3: Box<[f32]>,
    cols: Box<[f32]>,
    norm_scratch: NormScratch,
    out: Box<[f32]>,
}

impl ImageEncoder {
    /// Reads the encoder's weights under `prefix` (e.g. `"encoder.image."`, or `""`) from a safetensors file, for
    /// images of `height` × `width`.
    pub fn load(
        path: &Path,
        prefix: &str,
        cfg: &ResNetConfig,
        height: usize,
        width: usize,
        portable: bool,
    ) -> Result<Self, LoadError> {
        with_reader(path, MatMul::detect(1, portable), |r| Self::from_reader(r, prefix, cfg, height, width))
    }

    pub(crate) fn from_reader(
        r: &Reader,
        prefix: &str,
        cfg: &ResNetConfig,
        height: usize,
        width: usize,
    ) -> Result<Self, LoadError> {
        if cfg.width == 0 || height < 32 || width < 32 {
            return Err(LoadError::Config(format!(
                "a ResNet-18 needs width ≥ 1 and images of at least 32 × 32 pixels (got width {}, {height} × {width})",
                cfg.width
            )));
        }
        let mm = r.mm();
        let conv = |name: &str, cin: usize, cout: usize, k: usize, stride: usize, hw: (usize, usize)| {
            let weight = r.tensor(&format!("{prefix}{name}.weight"), &[cout, cin, k, k])?;
            Ok::<_, LoadError>(Conv::new(&weight, cin, cout, k, stride, hw, mm))
        };
        let norm = |name: &str, channels: usize| {
            Ok::<_, LoadError>(GroupNorm {
                groups: (channels / 16).max(1),
                gamma: r.tensor(&format!("{prefix}{name}.weight"), &[channels])?,
                beta: r.tensor(&format!("{prefix}{name}.bias"), &[channels])?,
            })
        };
        let w = cfg.width;
        let stem = conv("stem", 3, w, 7, 2, (height, width))?;
        let pooled_hw = (out_size(stem.out_hw.0, 3, 2, 1), out_size(stem.out_hw.1, 3, 2, 1));
        let mut blocks = Vec::with_capacity(8);
        let (mut channels, mut hw) = (w, pooled_hw);
        for (stage, mult) in [1, 2, 4, 8].into_iter().enumerate() {
            let o = w * mult;
            for b in 0..2 {
                let stride = if stage > 0 && b == 0 { 2 } else { 1 };
                let p = format!("layer{}.{b}.", stage + 1);
                let conv1 = conv(&format!("{p}conv1"), channels, o, 3, stride, hw)?;
                let down = if stride != 1 || channels != o {
                    Some((
                        conv(&format!("{p}down.conv"), channels, o, 1, stride, hw)?,
                        norm(&format!("{p}down.norm"), o)?,
                    ))
                } else {
                    None
                };
                let out_hw = conv1.out_hw;
                blocks.push(Block {
                    conv1,
                    norm1: norm(&format!("{p}norm1"), o)?,
                    conv2: conv(&format!("{p}conv2"), o, o, 3, 1, out_hw)?,
                    norm2: norm(&format!("{p}norm2"), o)?,
                    down,
                });
                (channels, hw) = (o, out_hw);
            }
        }
        let pixels = hw.0 * hw.1;
        let at = |i: usize, n: usize| if n > 1 { -1.0 + 2.0 * i as f32 / (n - 1) as f32 } else { 0.0 };
        let head = match cfg.head {
            ResNetHead::SpatialSoftmax { keypoints } => Head::SpatialSoftmax {
                keypoints: r.panels(Linear {
                    weight: r.tensor(&format!("{prefix}head.keypoints.weight"), &[keypoints, channels, 1, 1])?,
                    bias: vec![0.0; keypoints].into_boxed_slice(),
                    input: channels,
                    output: keypoints,
                    panels: Default::default(),
                }),
                xs: (0..pixels).map(|p| at(p % hw.1, hw.1)).collect(),
                ys: (0..pixels).map(|p| at(p / hw.1, hw.0)).collect(),
            },
            ResNetHead::AvgPool => Head::AvgPool,
        };
        let convs = std::iter::once(&stem)
            .chain(blocks.iter().flat_map(|b| [&b.conv1, &b.conv2].into_iter().chain(b.down.as_ref().map(|(c, _)| c))));
        let (mut act, mut cols) = (stem.out_pixels() * w, 0);
        for c in convs {
            act = act.max(c.out_pixels() * c.cout).max(c.in_hw.0 * c.in_hw.1 * c.cin);
            cols = cols.max(c.cols_len());
        }
        if let Head::SpatialSoftmax { keypoints, .. } = &head {
            act = act.max(pixels * keypoints.output);
        }
        let mut alloc = crate::buffers::Allocator::default();
        let mut buf = |what: &str, n: usize| {
            alloc.zeros(what, &[n]).map_err(|p| LoadError::Config(format!("a {height} × {width} camera encoder: {p}")))
        };
        Ok(Self {
            mm,
            height,
            width,
            stem,
            stem_norm: norm("stem_norm", w)?,
            pooled_hw,
            blocks,
            out: buf("output", cfg.out_dim())?,
            head,
            x: buf("activation", act)?,
            t1: buf("activation", act)?,
            t2: buf("activation", act)?,
            t3: buf("activation", act)?,
            cols: buf("im2col", cols)?,
            norm_scratch: NormScratch::new(8 * w),
        })
    }

    pub fn out_dim(&self) -> usize {
        self.out.len()
    }

    /// Pixels the encoder takes (H, W).
    pub fn image_size(&self) -> (usize, usize) {
        (self.height, self.width)
    }

    /// Multiply-adds of one forward pass (convolutions and the keypoint maps).
    pub fn macs(&self) -> usize {
        let blocks: usize = self
            .blocks
            .iter()
            .map(|b| b.conv1.macs() + b.conv2.macs() + b.down.as_ref().map_or(0, |(c, _)| c.macs()))
            .sum();
        let head = match &self.head {
            Head::SpatialSoftmax { keypoints, .. } => {
                let last = &self.blocks[7].conv2;
                last.out_pixels() * keypoints.input * keypoints.output
            }
            Head::AvgPool => 0,
        };
        self.stem.macs() + blocks + head
    }

    /// The feature vector of `image`: [H·W, 3] f32, row-major (channels last). Allocation-free.
    pub fn encode(&mut self, image: &[f32]) -> Result<&[f32], EngineError> {
        let want = self.height * self.width * 3;
        if image.len() != want {
            return Err(EngineError::Length { what: Input::Image, got: image.len(), want });
        }
        if let Some((index, &value)) = image.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(EngineError::NonFinite { what: Input::Image, index, value });
        }
        let mm = self.mm;
        let s = &self.stem;
        s.forward(image, &mut self.cols, &mut self.t1, mm);
        let stem_len = s.out_pixels() * s.cout;
        self.stem_norm.apply(&mut self.t1[..stem_len], s.cout, true, &mut self.norm_scratch);
        max_pool_3x3_stride_2(&self.t1[..stem_len], s.out_hw, s.cout, self.pooled_hw, &mut self.x);
        for b in &self.blocks {
            let (c1, c2) = (&b.conv1, &b.conv2);
            let len = c1.out_pixels() * c1.cout;
            c1.forward(&self.x, &mut self.cols, &mut self.t1, mm);
            b.norm1.apply(&mut self.t1[..len], c1.cout, true, &mut self.norm_scratch);
            c2.forward(&self.t1, &mut self.cols, &mut self.t2, mm);
            b.norm2.apply(&mut self.t2[..len], c2.cout, false, &mut self.norm_scratch);
            let skip: &[f32] = match &b.down {
                Some((c, n)) => {
                    c.forward(&self.x, &mut self.cols, &mut self.t3, mm);
                    n.apply(&mut self.t3[..len], c.cout, false, &mut self.norm_scratch);
                    &self.t3[..len]
                }
                None => &self.x[..len],
            };
            for (y, s) in self.t2[..len].iter_mut().zip(skip) {
                *y = (*y + s).max(0.0);
            }
            std::mem::swap(&mut self.x, &mut self.t2);
        }
        let last = &self.blocks[7].conv2;
        let (pixels, channels) = (last.out_pixels(), last.cout);
        let features = &self.x[..pixels * channels];
        match &self.head {
            Head::SpatialSoftmax { keypoints, xs, ys } => {
                let k = keypoints.output;
                let maps = &mut self.t1[..pixels * k];
                mm.linear(features, pixels, keypoints, maps);
                spatial_softmax(maps, k, xs, ys, &mut self.out);
            }
            Head::AvgPool => {
                for (c, o) in self.out.iter_mut().enumerate() {
                    *o = features.iter().skip(c).step_by(channels).sum::<f32>() / pixels as f32;
                }
            }
        }
        Ok(&self.out)
    }
}

/// 3 × 3 max pool, stride 2, padding 1 (the padding never wins a max), on [pixels, channels].
fn max_pool_3x3_stride_2(x: &[f32], (h, w): (usize, usize), c: usize, (ho, wo): (usize, usize), y: &mut [f32]) {
    for oy in 0..ho {
        for ox in 0..wo {
            let out = &mut y[(oy * wo + ox) * c..][..c];
            out.fill(f32::NEG_INFINITY);
            for iy in (2 * oy).saturating_sub(1)..(2 * oy + 2).min(h) {
                for ix in (2 * ox).saturating_sub(1)..(2 * ox + 2).min(w) {
                    for (o, v) in out.iter_mut().zip(&x[(iy * w + ix) * c..][..c]) {
                        *o = o.max(*v);
                    }
                }
            }
        }
    }
}

/// Each of the k maps in `maps` [pixels, k] as a softmax over the pixels (max-subtracted, as candle's), then its
/// expected x and y: out = [x₀ … x_{k−1}, y₀ … y_{k−1}]. The maps are overwritten with the probabilities.
fn spatial_softmax(maps: &mut [f32], k: usize, xs: &[f32], ys: &[f32], out: &mut [f32]) {
    for j in 0..k {
        let max = maps.iter().skip(j).step_by(k).fold(f32::NEG_INFINITY, |m, v| m.max(*v));
        let mut den = 0.0f32;
        for v in maps.iter_mut().skip(j).step_by(k) {
            *v = (*v - max).exp();
            den += *v;
        }
        let (mut x, mut y) = (0.0f32, 0.0f32);
        for (p, v) in maps.iter_mut().skip(j).step_by(k).enumerate() {
            *v /= den;
            x += *v * xs[p];
            y += *v * ys[p];
        }
        out[j] = x;
        out[k + j] = y;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GroupNorm from its definition, in f64, one group at a time.
    fn reference(x: &[f32], channels: usize, norm: &GroupNorm, relu: bool) -> Vec<f32> {
        let per = channels / norm.groups;
        let mut y = vec![0.0; x.len()];
        for g in 0..norm.groups {
            let values: Vec<f64> =
                x.chunks_exact(channels).flat_map(|px| px[g * per..(g + 1) * per].iter().map(|v| *v as f64)).collect();
            let mean = values.iter().sum::<f64>() / values.len() as f64;
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64;
            for (p, px) in x.chunks_exact(channels).enumerate() {
                for c in g * per..(g + 1) * per {
                    let v = (px[c] as f64 - mean) / (var + GN_EPS).sqrt() * norm.gamma[c] as f64 + norm.beta[c] as f64;
                    y[p * channels + c] = if relu { v.max(0.0) } else { v } as f32;
                }
            }
        }
        y
    }

    #[test]
    fn group_norm_equals_its_definition_for_any_channel_count() {
        // Multiples of the 8 summing lanes, and counts with a remainder (a width-1 or odd-width network).
        for (channels, groups) in [(32, 2), (16, 1), (24, 3), (12, 1), (5, 1), (1, 1)] {
            let f = |i: usize| ((i * 7919 % 1013) as f32 / 101.3) - 4.0;
            let norm = GroupNorm {
                groups,
                gamma: (0..channels).map(|c| 0.5 + c as f32 / 8.0).collect(),
                beta: (0..channels).map(|c| c as f32 / 16.0 - 0.3).collect(),
            };
            let x: Vec<f32> = (0..37 * channels).map(f).collect();
            for relu in [false, true] {
                let mut y = x.clone();
                norm.apply(&mut y, channels, relu, &mut NormScratch::new(channels));
                let want = reference(&x, channels, &norm, relu);
                let err = y.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(err < 1e-5, "{channels} channels, {groups} groups, relu {relu}: max error {err}");
            }
        }
    }
}
