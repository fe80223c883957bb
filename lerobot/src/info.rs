//! `meta/info.json`: the dataset's version, rate, features (dtype, shape, names) and where its files are.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::LeRobotError;

/// The only layout this crate reads and writes.
pub const CODEBASE_VERSION: &str = "v3.0";

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

    /// Values per frame.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
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
        // The version first, on its own: an older layout may lack the fields v3.0 needs.
        #[derive(Deserialize)]
        struct Version {
            codebase_version: String,
        }
        let v: Version =
            serde_json::from_str(&text).map_err(|error| LeRobotError::Info { path: path.clone(), error })?;
        if v.codebase_version != CODEBASE_VERSION {
            return Err(LeRobotError::Version { path, found: v.codebase_version });
        }
        serde_json::from_str(&text).map_err(|error| LeRobotError::Info { path, error })
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
        let filled = template
            .replace("{video_key}", video_key.unwrap_or(""))
            .replace("{chunk_index:03d}", &format!("{chunk:03}"))
            .replace("{file_index:03d}", &format!("{file:03}"));
        if filled.contains('{') {
            return Err(LeRobotError::Feature {
                key: template.to_owned(),
                problem: "a path template with placeholders other than video_key, chunk_index:03d, file_index:03d"
                    .into(),
            });
        }
        Ok(root.join(filled))
    }
}
