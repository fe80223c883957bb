//! `meta/info.json`: the dataset's version, rate, features (dtype, shape, names) and where its files are.

use std::collections::BTreeMap;
use std::path::{Component, Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::LeRobotError;

/// The only layout this crate reads and writes.
pub const CODEBASE_VERSION: &str = "v3.0";

/// The highest frame rate read (a camera or a control loop faster than 10 kHz is not a robot demonstration).
pub const MAX_FPS: f64 = 10_000.0;
/// The most values one frame of a feature may have (a 4096 × 4096 RGB image has 3 · 2²⁴): a shape beyond it is
/// refused when `info.json` is read, so no product of a feature's sizes can overflow.
pub const MAX_FEATURE_VALUES: usize = 1 << 26;
/// A camera image's largest height and width.
pub const MAX_IMAGE_SIDE: usize = 4096;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Info {
    pub codebase_version: String,
    pub fps: f64,
    pub features: BTreeMap<String, Feature>,
    pub total_episodes: usize,
    pub total_frames: usize,
    #[serde(default)]
    pub total_tasks: usize,
    pub chunks_size: usize,
    #[serde(default)]
    pub data_files_size_in_mb: Option<f64>,
    #[serde(default)]
    pub video_files_size_in_mb: Option<f64>,
    /// e.g. `data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet`
    pub data_path: String,
    /// e.g. `videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4`; absent without videos.
    #[serde(default)]
    pub video_path: Option<String>,
    #[serde(default)]
    pub robot_type: Option<String>,
    #[serde(default)]
    pub splits: BTreeMap<String, String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Feature {
    /// `float32`, `int64`, `video`, `image`, `string`, …
    pub dtype: String,
    pub shape: Vec<usize>,
    #[serde(default)]
    pub names: Option<serde_json::Value>,
    /// For videos: codec, pixel format, rate, … as LeRobot's writer describes them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub info: Option<serde_json::Value>,
}

impl Feature {
    pub fn is_video(&self) -> bool {
        self.dtype == "video"
    }

    /// Values per frame (a loaded dataset's features have at most [`MAX_FEATURE_VALUES`]; saturates otherwise).
    pub fn len(&self) -> usize {
        self.shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).unwrap_or(usize::MAX)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Info {
    /// Reads `<root>/meta/info.json` and refuses anything but v3.0 (the layouts before it differ in every file).
    pub fn load(root: &Path) -> Result<Self, LeRobotError> {
        let path = root.join("meta/info.json");
        let text = std::fs::read_to_string(&path).map_err(|error| LeRobotError::Read { path: path.clone(), error })?;
        Self::parse(&text, path)
    }

    /// [`Info::load`] of the text of `path` (named in errors).
    pub fn parse(text: &str, path: PathBuf) -> Result<Self, LeRobotError> {
        // The version first, on its own: an older layout may lack the fields v3.0 needs.
        #[derive(Deserialize)]
        struct Version {
            codebase_version: String,
        }
        let v: Version =
            serde_json::from_str(text).map_err(|error| LeRobotError::Info { path: path.clone(), error })?;
        if v.codebase_version != CODEBASE_VERSION {
            return Err(LeRobotError::Version { path, found: v.codebase_version });
        }
        let info: Self =
            serde_json::from_str(text).map_err(|error| LeRobotError::Info { path: path.clone(), error })?;
        info.validate().map_err(|problem| LeRobotError::Meta { path, problem })?;
        Ok(info)
    }

    /// What the rest of the reader relies on: a positive, finite rate; feature shapes whose product is a size a
    /// frame can have; path templates that stay inside the dataset's folder (for every video key).
    pub fn validate(&self) -> Result<(), String> {
        if !(self.fps.is_finite() && self.fps > 0.0 && self.fps <= MAX_FPS) {
            return Err(format!("fps is {}, must be a rate in (0, {MAX_FPS}] frames per second", self.fps));
        }
        for (key, f) in &self.features {
            let n = f.shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).filter(|&n| n <= MAX_FEATURE_VALUES);
            if n.is_none() {
                return Err(format!(
                    "feature `{key}` has shape {:?}: more than {MAX_FEATURE_VALUES} values a frame",
                    f.shape
                ));
            }
        }
        let err = |e: LeRobotError| e.to_string();
        Self::relative_path(&self.data_path, None, 0, 0).map_err(err)?;
        for key in self.features.iter().filter(|(_, f)| f.is_video()).map(|(k, _)| k) {
            let template = self.video_path.as_deref().ok_or(format!("video feature `{key}` but no video_path"))?;
            Self::relative_path(template, Some(key), 0, 0).map_err(err)?;
        }
        Ok(())
    }

    pub fn feature(&self, key: &str) -> Result<&Feature, LeRobotError> {
        self.features.get(key).ok_or_else(|| LeRobotError::MissingKey {
            key: key.to_owned(),
            available: self.features.keys().cloned().collect::<Vec<_>>().join(", "),
        })
    }

    /// A file's path: a `data_path` or `video_path` template filled in. The templates use Python's format
    /// syntax; v3.0's name exactly these placeholders, and anything else left in braces is an error.
    pub fn file_path(
        &self,
        root: &Path,
        template: &str,
        video_key: Option<&str>,
        chunk: i64,
        file: i64,
    ) -> Result<PathBuf, LeRobotError> {
        Ok(root.join(Self::relative_path(template, video_key, chunk, file)?))
    }

    /// The template filled in: a path inside the dataset's folder, or why not.
    fn relative_path(template: &str, video_key: Option<&str>, chunk: i64, file: i64) -> Result<PathBuf, LeRobotError> {
        let filled = template
            .replace("{video_key}", video_key.unwrap_or(""))
            .replace("{chunk_index:03d}", &format!("{chunk:03}"))
            .replace("{file_index:03d}", &format!("{file:03}"));
        let bad = |problem: String| LeRobotError::Template { template: template.to_owned(), problem };
        if filled.contains('{') {
            return Err(bad("placeholders other than video_key, chunk_index:03d, file_index:03d".into()));
        }
        // Only names inside the dataset's folder: no `..`, no absolute path (which `join` would take instead of
        // the root), whatever the template or a video key says.
        let rel = Path::new(&filled);
        if filled.is_empty() || !rel.components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir)) {
            return Err(bad(format!("makes the path {filled:?}, which leaves the dataset's folder (or names none)")));
        }
        Ok(rel.to_owned())
    }
}
