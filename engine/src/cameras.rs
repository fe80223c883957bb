//! A vision policy's cameras: each image of the (normalised) observation is centre-cropped, as the candle
//! encoder does at inference, and encoded by its own [`ImageEncoder`]; the features of every camera, then the
//! state, become the encoder MLP's input — the order of `mars_policy::vision`'s concatenation.

use crate::dims::VisionDims;
use crate::error::LoadError;
use crate::matmul::MatMul;
use crate::resnet::ImageEncoder;
use crate::weights::Reader;

pub struct Cameras {
    v: VisionDims,
    encoders: Vec<ImageEncoder>,
    /// One camera's crop [crop H · crop W, 3].
    crop: Box<[f32]>,
}

impl Cameras {
    /// The encoders under `encoder.vision.camera<i>.` of the checkpoint's weights. Each runs on one thread
    /// (its own kernels, packed for them).
    pub(crate) fn read(r: &Reader, v: &VisionDims, portable: bool) -> Result<Self, LoadError> {
        let encoders = r.with_mm(MatMul::detect(1, portable), |r| {
            (0..v.cameras)
                .map(|i| {
                    let prefix = format!("encoder.vision.camera{i}.");
                    ImageEncoder::from_reader(r, &prefix, &v.resnet, v.crop_hw.0, v.crop_hw.1)
                })
                .collect::<Result<Vec<_>, _>>()
        })?;
        let crop = vec![0.0; v.crop_hw.0 * v.crop_hw.1 * 3].into_boxed_slice();
        Ok(Self { v: *v, encoders, crop })
    }

    /// Multiply-adds of every camera's encoder.
    pub fn macs(&self) -> usize {
        self.encoders.iter().map(ImageEncoder::macs).sum()
    }

    /// `obs`: the normalised observation; `enc_in`: [features of each camera, state]. Allocation-free.
    pub fn encode(&mut self, obs: &[f32], enc_in: &mut [f32]) {
        let v = &self.v;
        let ((h, w), (ch, cw)) = (v.image_hw, v.crop_hw);
        let (top, left) = ((h - ch) / 2, (w - cw) / 2);
        for (i, enc) in self.encoders.iter_mut().enumerate() {
            let image = &obs[v.state + i * v.image_len()..][..v.image_len()];
            for (y, row) in self.crop.chunks_exact_mut(cw * 3).enumerate() {
                row.copy_from_slice(&image[((top + y) * w + left) * 3..][..cw * 3]);
            }
            // The crop is finite (the engine checked the observation), of the encoder's size: no error possible.
            let features = enc.encode(&self.crop).expect("a checked crop of the encoder's size");
            enc_in[i * v.features..][..v.features].copy_from_slice(features);
        }
        let n = v.cameras * v.features;
        enc_in[n..n + v.state].copy_from_slice(&obs[..v.state]);
    }
}
