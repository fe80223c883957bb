//! `mars train --dataset`: a LeRobot v3.0 dataset's episodes as training demos, after checking that the
//! features the user named fit the policy's configuration (state and action sizes, one video per camera, the
//! image size the encoder takes: frames are resized to it as they are decoded).

use std::path::{Path, PathBuf};

use anyhow::Context;
use mars_lerobot::demos::{RestAction, to_demos};
use mars_lerobot::{Keys, LeRobotDataset, ReadReport};
use mars_tasks::demo::Demo;

use crate::config::{EncoderConfig, ModelConfig};

/// Which features of the dataset to train on.
#[derive(Debug, Clone)]
pub struct DatasetInput {
    pub dir: PathBuf,
    pub state_key: String,
    pub action_key: String,
    /// Camera streams; empty: every video feature of the dataset, in name order, when the policy has cameras.
    pub image_keys: Vec<String>,
    /// What pads the history before an episode's first action; `None`: the first state when state and action
    /// have the same size (position targets), else the first action.
    pub rest: Option<RestAction>,
}

/// Reads the dataset's episodes as demos for a policy of `cfg`; the demos carry no mode (a dataset does not say).
pub fn load(input: &DatasetInput, cfg: &ModelConfig) -> anyhow::Result<(Vec<Demo>, ReadReport)> {
    let ds = LeRobotDataset::open(&input.dir).with_context(|| format!("dataset {}", input.dir.display()))?;
    let state_dim = ds.vector_len(&input.state_key)?;
    let action_dim = ds.vector_len(&input.action_key)?;
    anyhow::ensure!(
        action_dim == cfg.action_dim,
        "the dataset's `{}` has {action_dim} values, the policy's model.action_dim is {}",
        input.action_key,
        cfg.action_dim
    );
    let (image_keys, image_hw) = match &cfg.encoder {
        EncoderConfig::StateMlp { .. } => {
            anyhow::ensure!(
                input.image_keys.is_empty(),
                "--image-key given, but the policy's encoder takes no cameras (model.encoder is a state MLP)"
            );
            (Vec::new(), (0, 0))
        }
        EncoderConfig::Vision(v) => {
            let keys = if input.image_keys.is_empty() {
                ds.info.features.iter().filter(|(_, f)| f.is_video()).map(|(k, _)| k.clone()).collect()
            } else {
                input.image_keys.clone()
            };
            anyhow::ensure!(
                keys.len() == v.cameras,
                "the policy takes {} camera(s) (model.encoder.cameras), the dataset gives {} ({}): name them with \
                 --image-key",
                v.cameras,
                keys.len(),
                keys.join(", ")
            );
            (keys, (v.image_height as u32, v.image_width as u32))
        }
    };
    let obs_dim = state_dim + image_keys.len() * (image_hw.0 * image_hw.1 * 3) as usize;
    anyhow::ensure!(
        obs_dim == cfg.obs_dim,
        "the dataset's `{}` ({state_dim} values){} make observations of {obs_dim} values; the policy's \
         model.obs_dim is {}",
        input.state_key,
        if image_keys.is_empty() {
            String::new()
        } else {
            format!(" and {} camera(s) at {}×{}×3", image_keys.len(), image_hw.0, image_hw.1)
        },
        cfg.obs_dim
    );
    let keys = Keys { state: input.state_key.clone(), action: input.action_key.clone(), images: image_keys };
    let (episodes, report) = ds.read(&keys, image_hw).with_context(|| format!("dataset {}", input.dir.display()))?;
    let rest =
        input.rest.unwrap_or(if state_dim == action_dim { RestAction::FirstState } else { RestAction::FirstAction });
    let demos = to_demos(&episodes, state_dim, action_dim, rest).map_err(anyhow::Error::msg)?;
    Ok((demos, report))
}

/// The line `mars train --dataset` prints about the read.
pub fn describe(dir: &Path, demos: &[Demo], r: &ReadReport) -> String {
    let decode = if r.decoded_frames > 0 {
        format!(
            ", {} video frames decoded in {:.2} s ({:.0} frames/s)",
            r.decoded_frames,
            r.decode_s,
            r.decoded_frames as f64 / r.decode_s.max(1e-9)
        )
    } else {
        String::new()
    };
    format!("{}: {} episodes, {} frames read in {:.2} s{decode}", dir.display(), demos.len(), r.frames, r.total_s)
}
