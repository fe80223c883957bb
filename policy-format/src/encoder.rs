//! The image encoder's shape: which ResNet-18 and which head, and so how long its feature vector is. The
//! trainer builds the network from it (`mars_policy::nn::resnet`), the engine its allocation-free copy.

use serde::{Deserialize, Serialize};

/// How the feature map becomes a vector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ResNetHead {
    /// K keypoints' expected positions (2K values).
    SpatialSoftmax { keypoints: usize },
    /// The mean of each channel (8 × width values).
    AvgPool,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResNetConfig {
    /// Channels of the first stage (the paper's 64); the stages have 1, 2, 4 and 8 times this.
    pub width: usize,
    pub head: ResNetHead,
}

impl ResNetConfig {
    /// Length of the vector the ResNet-18's forward pass returns.
    pub fn out_dim(&self) -> usize {
        match self.head {
            ResNetHead::SpatialSoftmax { keypoints } => 2 * keypoints,
            ResNetHead::AvgPool => 8 * self.width,
        }
    }
}
