//! A checkpoint is a directory: `model.safetensors` (the weights) and `policy.json` (a [`CheckpointMeta`]: policy
//! kind, network config, normalisation statistics, training log). This is the `policy.json` half — reading it
//! checks everything (format, version, every size, the statistics' lengths) before anything is sized by it, so a
//! corrupt or hostile file is an error that names it, never a panic. The weights are read by whoever builds a
//! network from them (the trainer's candle model, the engine's own kernels), each against these sizes.

use crate::config::{ModelConfig, PolicyKind, TrainConfig};
use crate::normalize::Normalizer;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const META_FILE: &str = "policy.json";
pub const FORMAT: &str = "mars-policy-checkpoint";
pub const VERSION: u32 = 1;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckpointMeta {
    pub format: String,
    pub version: u32,
    pub kind: PolicyKind,
    pub model: ModelConfig,
    pub train: TrainConfig,
    pub normalizer: Normalizer,
    pub log: Vec<EpochLog>,
}

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}: cannot read: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("checkpoint {path}: not a valid {META_FILE}: {problem}")]
    Meta { path: PathBuf, problem: String },
    #[error("checkpoint {path}: corrupt or truncated safetensors file: {problem}")]
    Corrupt { path: PathBuf, problem: String },
    #[error("checkpoint {path}: tensor `{name}`: {problem}")]
    Tensor { path: PathBuf, name: String, problem: String },
    #[error("checkpoint {path}: {problem}")]
    Model { path: PathBuf, problem: String },
}

impl CheckpointMeta {
    /// The `policy.json` of a policy trained with `kind`, `model` and `train`, in this build's format.
    pub fn new(
        kind: PolicyKind,
        model: ModelConfig,
        train: TrainConfig,
        normalizer: Normalizer,
        log: Vec<EpochLog>,
    ) -> Self {
        Self { format: FORMAT.into(), version: VERSION, kind, model, train, normalizer, log }
    }
}

/// Mean loss terms over one epoch (terms a policy kind does not use stay 0).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct EpochLog {
    pub epoch: usize,
    pub total: f32,
    pub fm: f32,
    pub rec: f32,
    pub div: f32,
    /// Mean ‖w‖∞ over the epoch's samples.
    pub w_inf: f32,
}

pub fn load_meta(dir: &Path) -> Result<CheckpointMeta, CheckpointError> {
    let path = dir.join(META_FILE);
    let text = std::fs::read_to_string(&path).map_err(|source| CheckpointError::Io { path: path.clone(), source })?;
    parse_meta(dir, &text)
}

/// [`load_meta`] of the text of `dir`'s `policy.json`.
pub fn parse_meta(dir: &Path, text: &str) -> Result<CheckpointMeta, CheckpointError> {
    let path = dir.join(META_FILE);
    let meta_err = |problem: String| CheckpointError::Meta { path: path.clone(), problem };
    let meta: CheckpointMeta = serde_json::from_str(text).map_err(|e| meta_err(e.to_string()))?;
    if meta.format != FORMAT || meta.version != VERSION {
        return Err(meta_err(format!(
            "format {} v{}, this build reads {FORMAT} v{VERSION}",
            meta.format, meta.version
        )));
    }
    meta.model.validate().map_err(|e| meta_err(e.to_string()))?;
    let n = &meta.normalizer;
    if !n.obs.is_valid() || n.obs.dim() != meta.model.obs_dim {
        return Err(meta_err(format!(
            "observation statistics must be {} finite values with std > 0",
            meta.model.obs_dim
        )));
    }
    if !n.action.is_valid() || n.action.dim() != meta.model.action_dim {
        return Err(meta_err(format!(
            "action statistics must be {} finite values with std > 0",
            meta.model.action_dim
        )));
    }
    Ok(meta)
}
