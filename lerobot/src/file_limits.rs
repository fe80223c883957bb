//! Where a written episode goes: LeRobot's rule for starting a new data or video file, and the files' names.

use crate::episodes::FileIndex;

/// When a new file starts: LeRobot's `data_files_size_in_mb`, `video_files_size_in_mb` (MiB, 1024² bytes, as
/// LeRobot counts them) and `chunks_size` (files per chunk directory), written to `info.json` as set.
///
/// The rule is LeRobot 0.6.1's (`DatasetWriter._save_episode_data` and `_save_episode_video` in
/// `lerobot/datasets/dataset_writer.py`, with `update_chunk_file_indices` from `utils.py`), checked as each episode
/// ends, before it is written:
/// - data: the current file's bytes so far plus the episode's rows at the file's bytes per row so far reach
///   `data_files_size_in_mb` → the episode starts the next file;
/// - video, per camera: the current file's bytes plus the episode's own encoded file's bytes reach
///   `video_files_size_in_mb` → the episode starts the next file (its times from 0 again).
///
/// Where ours differs: the current video file's size is the sum of its episodes' own files (LeRobot measures the
/// concatenated file, a few hundred bytes of headers per episode smaller); and `meta/episodes` stays one file,
/// which LeRobot splits at `data_files_size_in_mb` too (a row of metadata per episode: a dataset would need tens
/// of thousands of episodes to reach 100 MB; both readers read any number of these files).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FileLimits {
    pub data_files_size_in_mb: f64,
    pub video_files_size_in_mb: f64,
    pub chunks_size: usize,
}

impl Default for FileLimits {
    /// LeRobot's defaults (`DEFAULT_DATA_FILE_SIZE_IN_MB`, `DEFAULT_VIDEO_FILE_SIZE_IN_MB`, `DEFAULT_CHUNK_SIZE`).
    fn default() -> Self {
        Self { data_files_size_in_mb: 100.0, video_files_size_in_mb: 200.0, chunks_size: 1000 }
    }
}

const MIB: f64 = 1024.0 * 1024.0;

/// LeRobot's data rule: the file so far plus `episode_rows` at its bytes per row so far reach the limit.
pub(crate) fn data_rolls_over(file_bytes: u64, file_rows: usize, episode_rows: usize, limit_mb: f64) -> bool {
    let size_mb = file_bytes as f64 / MIB;
    let per_row = if file_rows > 0 { size_mb / file_rows as f64 } else { 0.0 };
    size_mb + per_row * episode_rows as f64 >= limit_mb
}

/// LeRobot's video rule: the file so far plus the episode's own file reach the limit.
pub(crate) fn video_rolls_over(file_bytes: u64, episode_bytes: u64, limit_mb: f64) -> bool {
    file_bytes as f64 / MIB + episode_bytes as f64 / MIB >= limit_mb
}

pub(crate) fn data_file(f: FileIndex) -> String {
    format!("data/chunk-{:03}/file-{:03}.parquet", f.chunk, f.file)
}

pub(crate) fn video_file(key: &str, f: FileIndex) -> String {
    format!("videos/{key}/chunk-{:03}/file-{:03}.mp4", f.chunk, f.file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_count_up_and_a_full_chunk_starts_the_next() {
        let f = |chunk, file| FileIndex { chunk, file };
        assert_eq!(f(0, 0).next(1000), f(0, 1));
        assert_eq!(f(0, 998).next(1000), f(0, 999));
        assert_eq!(f(0, 999).next(1000), f(1, 0));
        assert_eq!(f(3, 1).next(2), f(4, 0));
        assert_eq!(f(0, 0).next(1), f(1, 0));
    }

    /// The numbers LeRobot's formulas give (sizes in MiB, `>=`: reaching the limit is enough).
    #[test]
    fn the_rollover_rules_are_lerobots() {
        let mib = 1024 * 1024;
        // Data: 60 MiB in 600 rows so far, 0.1 MiB a row; 400 more rows reach 100, 399 do not.
        assert!(data_rolls_over(60 * mib, 600, 400, 100.0));
        assert!(!data_rolls_over(60 * mib, 600, 399, 100.0));
        // A file of no rows yet weighs only its bytes.
        assert!(!data_rolls_over(4, 0, 1_000_000, 100.0));
        // Video: the file plus the episode's own file.
        assert!(video_rolls_over(150 * mib, 50 * mib, 200.0));
        assert!(!video_rolls_over(150 * mib, 50 * mib - 1, 200.0));
    }
}
