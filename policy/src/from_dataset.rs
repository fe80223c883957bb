//! `mars train --dataset`: a LeRobot v3.0 dataset's episodes as training demos, after checking that the
//! features the user named fit the policy's configuration (state and action sizes, one video per camera, the
//! image size the encoder takes: frames are resized to it as they are decoded).

use std::path::{Path, PathBuf};

use anyhow::Context;
use mars_lerobot::demos::{RestAction, to_demos};
use mars_lerobot::{Keys, LeRobotDataset, ReadReport};
use mars_tasks::demo::Demo;

use crate::config::{EncoderConfig, ModelConfig};
use crate::normalize::{Normalizer, Stats};

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
    /// Where the normalisation's mean and std come from.
    pub normalize: Normalization,
}

/// `--normalize-from`: the statistics of the frames read (as for any demos), or those the dataset ships in
/// `meta/stats.json` (LeRobot's, computed by whoever wrote it: a policy trained on a subset of a dataset, or
/// fine-tuned on a small one, can keep the whole dataset's scale).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Normalization {
    #[default]
    Data,
    Stats,
}

/// The normalisation `--normalize-from stats` asks for: the state's and the action's mean and std from
/// `meta/stats.json`, cameras left raw (the encoder takes pixels / 255 as they are); `None` for `data`.
pub fn given_normalizer(input: &DatasetInput, cfg: &ModelConfig) -> anyhow::Result<Option<Normalizer>> {
    if input.normalize == Normalization::Data {
        return Ok(None);
    }
    let path = input.dir.join("meta/stats.json");
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!("{}: --normalize-from stats needs it (or use --normalize-from data)", path.display())
    })?;
    let stats: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{}", path.display()))?;
    let of = |key: &str, dim: usize| -> anyhow::Result<(Vec<f32>, Vec<f32>)> {
        let field = |name: &str| -> anyhow::Result<Vec<f32>> {
            let v = stats
                .get(key)
                .and_then(|f| f.get(name))
                .and_then(|v| v.as_array())
                .with_context(|| format!("{}: no {key}.{name}", path.display()))?;
            let v: Option<Vec<f32>> = v.iter().map(|x| x.as_f64().map(|x| x as f32)).collect();
            let v = v.with_context(|| format!("{}: {key}.{name} is not a list of numbers", path.display()))?;
            anyhow::ensure!(
                v.len() == dim && v.iter().all(|x| x.is_finite()),
                "{}: {key}.{name} has {} values, the dataset's {key} {dim}",
                path.display(),
                v.len()
            );
            Ok(v)
        };
        Ok((field("mean")?, field("std")?))
    };
    let action = of(&input.action_key, cfg.action_dim)?;
    let state_dim = cfg.obs_dim - crate::encoder::raw_dims(&cfg.encoder, cfg.obs_dim).len();
    let (mut mean, mut std) = of(&input.state_key, state_dim)?;
    mean.resize(cfg.obs_dim, 0.0);
    std.resize(cfg.obs_dim, 1.0);
    Ok(Some(Normalizer { obs: Stats::given(mean, std), action: Stats::given(action.0, action.1) }))
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
    // Checked: the dataset's sizes are its own word (a state of usize::MAX values must be an error, not a panic).
    let obs_dim = (image_hw.0 as usize)
        .checked_mul(image_hw.1 as usize)
        .and_then(|px| px.checked_mul(3 * image_keys.len()))
        .and_then(|images| images.checked_add(state_dim));
    anyhow::ensure!(
        obs_dim == Some(cfg.obs_dim),
        "the dataset's `{}` ({state_dim} values){} make observations of {} values; the policy's \
         model.obs_dim is {}",
        input.state_key,
        if image_keys.is_empty() {
            String::new()
        } else {
            format!(" and {} camera(s) at {}×{}×3", image_keys.len(), image_hw.0, image_hw.1)
        },
        obs_dim.map_or("more than 2⁶⁴".into(), |n| n.to_string()),
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
    let cached = if r.cached_frames > 0 {
        format!(", {} video frames from the decoded-frame cache in {:.3} s", r.cached_frames, r.cache_read_s)
    } else {
        String::new()
    };
    let warnings: String = r.cache_warnings.iter().map(|w| format!("\n  cache: {w}")).collect();
    format!(
        "{}: {} episodes, {} frames read in {:.2} s{decode}{cached}{warnings}",
        dir.display(),
        demos.len(),
        r.frames,
        r.total_s
    )
}
