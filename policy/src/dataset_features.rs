//! `mars train --dataset DIR` with no `--config`: the policy's features come from the dataset, as LeRobot builds a
//! policy's input and output features from `meta/info.json`. The observation's size (the state's values, then each
//! camera's image), the action's size and the cameras are the dataset's; everything else (chunk, history, K, the
//! network's widths, training) is the shipped defaults', built into the binary so the command works from any
//! directory: `configs/policy.toml` for a policy on the state alone, `configs/push_t_policy.toml`'s vision encoder
//! when the dataset has cameras.

use anyhow::Context;
use mars_lerobot::LeRobotDataset;

use crate::config::{EncoderConfig, PolicyConfig};
use crate::from_dataset::DatasetInput;

/// The shipped policy on a state vector (the nav2d benchmark's sizes, replaced below).
const STATE_DEFAULTS: &str = include_str!("../../configs/policy.toml");
/// The shipped vision policy (Push-T's ResNet-18 at 64 px, replaced below).
const VISION_DEFAULTS: &str = include_str!("../../configs/push_t_policy.toml");

/// The config for a policy on `input`'s dataset: its state and action sizes, and its cameras (`input.image_keys`,
/// or every video feature), each resized as it is decoded to the defaults' image height and the width that keeps
/// the camera's aspect. Errors name the feature that does not fit.
pub fn config_for(input: &DatasetInput) -> anyhow::Result<PolicyConfig> {
    let ds = LeRobotDataset::open(&input.dir).with_context(|| format!("dataset {}", input.dir.display()))?;
    let state_dim = ds.vector_len(&input.state_key)?;
    let action_dim = ds.vector_len(&input.action_key)?;
    let keys = camera_keys(&ds, input);
    let mut cfg = if keys.is_empty() { defaults(STATE_DEFAULTS)? } else { defaults(VISION_DEFAULTS)? };
    let mut image_values = 0usize;
    if let EncoderConfig::Vision(v) = &mut cfg.model.encoder {
        let (height, width) = resized(&ds, &keys, v.image_height)?;
        (v.cameras, v.image_height, v.image_width) = (keys.len(), height, width);
        (v.crop_height, v.crop_width) = (height, width);
        image_values = keys.len().checked_mul(height * width * 3).context("the cameras' values overflow")?;
    }
    let obs_dim = state_dim.checked_add(image_values).context("the observation's values overflow")?;
    (cfg.model.obs_dim, cfg.model.action_dim) = (obs_dim, action_dim);
    cfg.validate().with_context(|| format!("the config made from {}", input.dir.join("meta/info.json").display()))?;
    Ok(cfg)
}

/// The cameras the policy takes: those named, else every video feature in name order.
fn camera_keys(ds: &LeRobotDataset, input: &DatasetInput) -> Vec<String> {
    if !input.image_keys.is_empty() {
        return input.image_keys.clone();
    }
    ds.info.features.iter().filter(|(_, f)| f.is_video()).map(|(k, _)| k.clone()).collect()
}

/// The image size every camera is decoded to: `height` rows, and the width of the first camera's aspect (one
/// encoder takes every camera, so they must agree on it).
fn resized(ds: &LeRobotDataset, keys: &[String], height: usize) -> anyhow::Result<(usize, usize)> {
    let mut size = None;
    for key in keys {
        let (h, w) = ds.image_size(key)?;
        let width = ((w as f64 * height as f64 / h as f64).round() as usize).max(1);
        match size {
            None => size = Some((key, width)),
            Some((first, first_width)) => anyhow::ensure!(
                first_width == width,
                "cameras `{first}` and `{key}` have different aspects ({first_width} and {width} px wide at \
                 {height} px high): give a --config whose encoder takes them, or name one with --image-key"
            ),
        }
    }
    Ok((height, size.map_or(height, |(_, w)| w)))
}

fn defaults(text: &str) -> anyhow::Result<PolicyConfig> {
    PolicyConfig::from_toml(text).context("the shipped defaults built into mars")
}
