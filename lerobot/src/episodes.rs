//! `meta/episodes/chunk-*/file-*.parquet`: per episode its length, which data file holds its rows and, for each
//! camera, which video file holds its frames and from which time to which.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::LeRobotError;
use crate::info::Info;
use crate::table::Table;

/// A file named by chunk and file index (LeRobot packs many episodes into one file).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct FileIndex {
    pub chunk: i64,
    pub file: i64,
}

impl FileIndex {
    /// The file after this one: the file index counts up to `chunks_size - 1`, then the chunk index goes up and
    /// the file index starts again at 0 (LeRobot's `update_chunk_file_indices`).
    pub fn next(self, chunks_size: usize) -> Self {
        if self.file + 1 >= chunks_size as i64 {
            Self { chunk: self.chunk + 1, file: 0 }
        } else {
            Self { chunk: self.chunk, file: self.file + 1 }
        }
    }
}

/// Where in a shared video file an episode's frames are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VideoRange {
    pub file: FileIndex,
    pub from_s: f64,
    pub to_s: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Episode {
    pub index: i64,
    pub length: usize,
    pub tasks: Vec<String>,
    pub data: FileIndex,
    /// The episode's rows have global `index` from..to (exclusive).
    pub dataset_from_index: i64,
    pub dataset_to_index: i64,
    /// Per video key.
    pub videos: BTreeMap<String, VideoRange>,
}

/// Every `*.parquet` under `dir`, sorted (chunk-000/file-000 first).
fn parquet_files(dir: &Path) -> Result<Vec<PathBuf>, LeRobotError> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(d) = stack.pop() {
        let entries = std::fs::read_dir(&d).map_err(|error| LeRobotError::Read { path: d.clone(), error })?;
        for e in entries {
            let p = e.map_err(|error| LeRobotError::Read { path: d.clone(), error })?.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "parquet") {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Reads every episode's metadata, in episode order, and checks it against `info.json`: indices 0..N once
/// each, lengths that add up, a video range for every video feature.
pub fn load(root: &Path, info: &Info) -> Result<Vec<Episode>, LeRobotError> {
    let dir = root.join("meta/episodes");
    let files = parquet_files(&dir)?;
    if files.is_empty() {
        return Err(LeRobotError::Read {
            path: dir,
            error: std::io::Error::new(std::io::ErrorKind::NotFound, "no episodes metadata (*.parquet)"),
        });
    }
    let columns = columns(info);
    let columns: Vec<&str> = columns.iter().map(String::as_str).collect();
    // Not sized by `total_episodes`: that is the file's word, checked against the rows below.
    let mut episodes = Vec::new();
    for path in &files {
        episodes.extend(from_table(&Table::read(path, Some(&columns))?, info)?);
    }
    check(episodes, info)
}

/// The columns of an episodes file that [`from_table`] reads.
pub fn columns(info: &Info) -> Vec<String> {
    let mut columns: Vec<String> = [
        "episode_index",
        "length",
        "tasks",
        "data/chunk_index",
        "data/file_index",
        "dataset_from_index",
        "dataset_to_index",
    ]
    .map(String::from)
    .into();
    for k in video_keys(info) {
        columns
            .extend(["chunk_index", "file_index", "from_timestamp", "to_timestamp"].map(|c| format!("videos/{k}/{c}")));
    }
    columns
}

fn video_keys(info: &Info) -> Vec<&String> {
    info.features.iter().filter(|(_, f)| f.is_video()).map(|(k, _)| k).collect()
}

/// The episodes of one episodes file, each checked on its own (a positive length that its rows span, a time
/// range for every video).
pub fn from_table(t: &Table, info: &Info) -> Result<Vec<Episode>, LeRobotError> {
    let path = &t.path;
    let video_keys = video_keys(info);
    let (index, length, tasks) = (t.i64s("episode_index")?, t.i64s("length")?, t.string_lists("tasks")?);
    let (chunk, file) = (t.i64s("data/chunk_index")?, t.i64s("data/file_index")?);
    let (from, to) = (t.i64s("dataset_from_index")?, t.i64s("dataset_to_index")?);
    let mut videos = Vec::with_capacity(video_keys.len());
    for k in &video_keys {
        let col = |c: &str| format!("videos/{k}/{c}");
        videos.push((
            t.i64s(&col("chunk_index"))?,
            t.i64s(&col("file_index"))?,
            t.f64s(&col("from_timestamp"))?,
            t.f64s(&col("to_timestamp"))?,
        ));
    }
    let mut episodes = Vec::with_capacity(t.rows());
    for r in 0..t.rows() {
        let bad = |problem: String| LeRobotError::Episode { episode: index[r], problem };
        if length[r] <= 0 || from[r] < 0 || to[r].checked_sub(from[r]) != Some(length[r]) {
            return Err(bad(format!(
                "length {} but dataset rows {}..{} in {}",
                length[r],
                from[r],
                to[r],
                path.display()
            )));
        }
        let mut ranges = BTreeMap::new();
        for (k, (c, f, a, b)) in video_keys.iter().zip(&videos) {
            if !(a[r].is_finite() && b[r].is_finite() && a[r] >= 0.0 && a[r] < b[r]) {
                return Err(bad(format!("video `{k}` from {} s to {} s is not a time range", a[r], b[r])));
            }
            let range = VideoRange { file: FileIndex { chunk: c[r], file: f[r] }, from_s: a[r], to_s: b[r] };
            ranges.insert((*k).clone(), range);
        }
        episodes.push(Episode {
            index: index[r],
            length: length[r] as usize,
            tasks: tasks[r].clone(),
            data: FileIndex { chunk: chunk[r], file: file[r] },
            dataset_from_index: from[r],
            dataset_to_index: to[r],
            videos: ranges,
        });
    }
    Ok(episodes)
}

/// The episodes of every file together: in episode order, indices 0..N once each, as many episodes and frames
/// as `info.json` says.
pub fn check(mut episodes: Vec<Episode>, info: &Info) -> Result<Vec<Episode>, LeRobotError> {
    episodes.sort_by_key(|e| e.index);
    for (i, e) in episodes.iter().enumerate() {
        if e.index != i as i64 {
            return Err(LeRobotError::Episode {
                episode: e.index,
                problem: format!(
                    "episode indices must be 0..{} once each; found {} at position {i}",
                    episodes.len(),
                    e.index
                ),
            });
        }
    }
    let frames = episodes.iter().try_fold(0usize, |n, e| n.checked_add(e.length));
    if episodes.len() != info.total_episodes || frames != Some(info.total_frames) {
        let frames = frames.map_or("more than 2⁶⁴".to_owned(), |n| n.to_string());
        return Err(LeRobotError::Episode {
            episode: -1,
            problem: format!(
                "meta/episodes lists {} episodes of {frames} frames, meta/info.json says {} of {}",
                episodes.len(),
                info.total_episodes,
                info.total_frames
            ),
        });
    }
    Ok(episodes)
}
