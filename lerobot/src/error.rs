//! What can be wrong with a dataset, said so that the user can fix it (which file, which key, what we expected).

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum LeRobotError {
    #[error("{path}: cannot read: {error}")]
    Read { path: PathBuf, error: std::io::Error },
    #[error("{path} exists; a dataset is never overwritten (give a new path)")]
    Exists { path: PathBuf },
    #[error("{path}: not a LeRobot dataset's metadata: {error}")]
    Info { path: PathBuf, error: serde_json::Error },
    #[error("{path}: {problem}")]
    Meta { path: PathBuf, problem: String },
    #[error(
        "{path}: codebase_version {found}, but this reader takes LeRobot v3.0 datasets. A v2.1 dataset converts with \
         LeRobot's own converter: `python -m lerobot.scripts.convert_dataset_v21_to_v30 --repo-id=<id>` (LeRobot ≥ 0.4)"
    )]
    Version { path: PathBuf, found: String },
    #[error("no feature `{key}` in this dataset (it has: {available})")]
    MissingKey { key: String, available: String },
    #[error("feature `{key}`: {problem}")]
    Feature { key: String, problem: String },
    #[error("path template `{template}`: {problem}")]
    Template { template: String, problem: String },
    #[error("{path}: not a readable parquet file (truncated or corrupt?): {error}")]
    Parquet { path: PathBuf, error: String },
    #[error("{path}: column `{column}`: {problem}")]
    Column { path: PathBuf, column: String, problem: String },
    #[error("episode {episode}: {problem}")]
    Episode { episode: i64, problem: String },
    #[error("{path}: {problem}")]
    Video { path: PathBuf, problem: String },
}

impl LeRobotError {
    pub(crate) fn parquet(path: &std::path::Path, error: impl std::fmt::Display) -> Self {
        Self::Parquet { path: path.to_owned(), error: error.to_string() }
    }

    pub(crate) fn video(path: &std::path::Path, problem: impl Into<String>) -> Self {
        Self::Video { path: path.to_owned(), problem: problem.into() }
    }
}
