//! The writer splits data and video files as LeRobot does (a new file once the current one would reach its size
//! limit, decided at episode boundaries; a new chunk after `chunks_size` files), records each episode's files and
//! times in the episodes' metadata, and the reader reads such a dataset back value for value.

mod common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use common::{FRAME, IMAGE, fixture_episodes, keys, write};
use mars_lerobot::episodes::FileIndex;
use mars_lerobot::writer::{CameraSpec, DatasetSpec, DatasetWriter, FileLimits, VectorSpec};
use mars_lerobot::{EpisodeFrames, LeRobotDataset, ReadOptions};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

const MIB: f64 = 1024.0 * 1024.0;

/// Every file under `dir`, relative to `root`.
fn files(root: &Path, dir: &str) -> BTreeSet<PathBuf> {
    let mut out = BTreeSet::new();
    let mut stack = vec![root.join(dir)];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.strip_prefix(root).unwrap().to_owned());
            }
        }
    }
    out
}

/// The files episode after episode: (0, 0) first, then the same file or the next one (never back, never skipped).
fn check_sequence(what: &str, files: &[FileIndex], chunks_size: usize) {
    assert_eq!(files[0], FileIndex { chunk: 0, file: 0 }, "{what}");
    for w in files.windows(2) {
        assert!(w[1] == w[0] || w[1] == w[0].next(chunks_size), "{what}: {:?} after {:?}", w[1], w[0]);
    }
}

/// `read` has every episode of `want` value for value: state, action and timestamps exactly, every frame there at
/// its size and within AV1's loss of the frame written.
fn check_read_back(read: &[EpisodeFrames], want: &[EpisodeFrames]) {
    assert_eq!(read.len(), want.len());
    for (a, b) in read.iter().zip(want) {
        assert_eq!((a.index, a.len), (b.index, b.len));
        assert_eq!((&a.state, &a.action, &a.timestamps), (&b.state, &b.action, &b.timestamps), "episode {}", a.index);
        assert_eq!(a.images.len(), 1);
        assert_eq!(a.images[0].len(), a.len * FRAME, "episode {}: {} frames of 64×64×3", a.index, a.len);
        let diff: u64 = a.images[0].iter().zip(&b.images[0]).map(|(p, q)| u64::from(p.abs_diff(*q))).sum();
        let mean = diff as f64 / a.images[0].len() as f64;
        assert!(mean < 3.0, "episode {}: frames {mean:.2} of 255 from those written", a.index);
    }
}

/// The fixture's episodes written at limits of two and a half episodes' size, two files to a chunk: at least three
/// data and three video files, some with several episodes, chunk 1 reached; the episodes' metadata names them,
/// their times restart at 0 in each video file, and the reader gives back every value. The sizes the rules weigh
/// are measured from a write of one episode per file: a data file's row group (the bytes before its footer) and a
/// video file (an episode's own file, copied).
#[test]
fn episodes_split_over_several_data_and_video_files_read_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let episodes = fixture_episodes();
    let tiny = FileLimits { data_files_size_in_mb: 1e-6, video_files_size_in_mb: 1e-6, chunks_size: 1000 };
    let each = write(&dir.path().join("each"), &episodes, tiny);
    let (mut row_group, mut video_file) = (0, 0);
    for f in files(&each, "data") {
        let file = std::fs::File::open(each.join(f)).unwrap();
        let meta = ParquetRecordBatchReaderBuilder::try_new(file).unwrap().metadata().clone();
        row_group = row_group.max(meta.row_group(0).compressed_size() as u64);
    }
    for f in files(&each, "videos") {
        video_file = video_file.max(std::fs::metadata(each.join(f)).unwrap().len());
    }
    println!("the largest episode: {row_group} bytes of rows, {video_file} bytes of video");
    let limits = FileLimits {
        data_files_size_in_mb: 2.5 * row_group as f64 / MIB,
        video_files_size_in_mb: 2.5 * video_file as f64 / MIB,
        chunks_size: 2,
    };
    let root = write(&dir.path().join("split"), &episodes, limits);
    assert!(!root.join("tmp").exists(), "the episodes' own video files are gone");

    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("meta/info.json")).unwrap()).unwrap();
    assert_eq!(info["data_files_size_in_mb"].as_f64().unwrap(), limits.data_files_size_in_mb);
    assert_eq!(info["video_files_size_in_mb"].as_f64().unwrap(), limits.video_files_size_in_mb);
    assert_eq!(info["chunks_size"].as_u64().unwrap(), 2);

    let ds = LeRobotDataset::open(&root).unwrap();
    let data: Vec<FileIndex> = ds.episodes.iter().map(|e| e.data).collect();
    let video: Vec<FileIndex> = ds.episodes.iter().map(|e| e.videos[IMAGE].file).collect();
    println!("data files {data:?}\nvideo files {video:?}");
    check_sequence("data", &data, 2);
    check_sequence("video", &video, 2);
    for (what, files) in [("data", &data), ("video", &video)] {
        let distinct: BTreeSet<_> = files.iter().collect();
        assert!(distinct.len() >= 3, "{what}: {} files", distinct.len());
        assert!(distinct.len() < files.len(), "{what}: no file has two episodes");
        assert!(files.iter().any(|f| f.chunk == 1), "{what}: chunk 1 never reached");
    }
    // The files there are exactly those the episodes name.
    let named_data: BTreeSet<PathBuf> =
        data.iter().map(|f| format!("data/chunk-{:03}/file-{:03}.parquet", f.chunk, f.file).into()).collect();
    let named_video: BTreeSet<PathBuf> =
        video.iter().map(|f| format!("videos/{IMAGE}/chunk-{:03}/file-{:03}.mp4", f.chunk, f.file).into()).collect();
    assert_eq!(files(&root, "data"), named_data);
    assert_eq!(files(&root, "videos"), named_video);
    // Rows: consecutive over the files; times: from 0 in each video file, each episode where the one before ended.
    let mut from_index = 0;
    for (i, e) in ds.episodes.iter().enumerate() {
        let r = e.videos[IMAGE];
        assert_eq!(e.dataset_from_index, from_index);
        from_index += e.length as i64;
        assert!((r.to_s - r.from_s - e.length as f64 / 10.0).abs() < 1e-9, "episode {i}: {r:?}");
        let before = i.checked_sub(1).map(|j| ds.episodes[j].videos[IMAGE]).filter(|b| b.file == r.file);
        assert_eq!(r.from_s, before.map_or(0.0, |b| b.to_s), "episode {i}");
    }

    let (read, report) = ds.read_with(&keys(), (64, 64), &ReadOptions::no_cache()).unwrap();
    check_read_back(&read, &episodes);
    // Each episode is encoded alone and copied whole, so the frames are the same bytes however they are split.
    let each = LeRobotDataset::open(&each).unwrap().read_with(&keys(), (64, 64), &ReadOptions::no_cache()).unwrap();
    assert!(read == each.0, "the same frames as with one episode per file");
    let video_files: BTreeSet<_> = video.iter().collect();
    assert_eq!((report.decoded_files, report.decoded_frames), (video_files.len(), 180), "each file decoded once");
}

/// Below the smallest file every episode starts a file of its own: with 4 files to a chunk, six episodes fill
/// chunk 0 and go on in chunk 1 (chunk-001/file-000, file-001).
#[test]
fn a_limit_below_one_episode_gives_each_episode_its_own_files() {
    let dir = tempfile::tempdir().unwrap();
    let episodes: Vec<EpisodeFrames> = fixture_episodes().into_iter().map(|e| shorten(e, 4)).collect();
    let limits = FileLimits { data_files_size_in_mb: 1e-6, video_files_size_in_mb: 1e-6, chunks_size: 4 };
    let root = write(&dir.path().join("each"), &episodes, limits);
    let ds = LeRobotDataset::open(&root).unwrap();
    let want: Vec<FileIndex> =
        [(0, 0), (0, 1), (0, 2), (0, 3), (1, 0), (1, 1)].map(|(chunk, file)| FileIndex { chunk, file }).to_vec();
    assert_eq!(ds.episodes.iter().map(|e| e.data).collect::<Vec<_>>(), want);
    assert_eq!(ds.episodes.iter().map(|e| e.videos[IMAGE].file).collect::<Vec<_>>(), want);
    assert!(ds.episodes.iter().all(|e| e.videos[IMAGE].from_s == 0.0));
    assert!(root.join("data/chunk-001/file-001.parquet").exists());
    assert!(root.join(format!("videos/{IMAGE}/chunk-001/file-001.mp4")).exists());
    let (read, report) = ds.read_with(&keys(), (64, 64), &ReadOptions::no_cache()).unwrap();
    check_read_back(&read, &episodes);
    assert_eq!(report.decoded_files, 6);
}

/// The first `len` frames of an episode.
fn shorten(mut e: EpisodeFrames, len: usize) -> EpisodeFrames {
    e.len = len;
    e.state.truncate(2 * len);
    e.action.truncate(2 * len);
    e.timestamps.truncate(len);
    e.images[0].truncate(len * FRAME);
    e
}

#[test]
fn limits_that_cannot_hold_a_file_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let spec = DatasetSpec {
        fps: 10,
        robot_type: "fr3".into(),
        vectors: vec![VectorSpec { key: "action".into(), names: vec!["x".into()] }],
        cameras: vec![CameraSpec { key: IMAGE.into(), height: 64, width: 64 }],
    };
    let bad = [
        FileLimits { data_files_size_in_mb: 0.0, ..FileLimits::default() },
        FileLimits { video_files_size_in_mb: f64::NAN, ..FileLimits::default() },
        FileLimits { chunks_size: 0, ..FileLimits::default() },
    ];
    for limits in bad {
        let root = dir.path().join("refused");
        let e = DatasetWriter::create_with_limits(&root, spec.clone(), limits).err().expect("refused");
        assert!(e.to_string().contains("file sizes must be above 0 MB"), "{e}");
        assert!(!root.exists() && !dir.path().join("refused.partial").exists());
    }
    assert_eq!(
        FileLimits::default(),
        FileLimits { data_files_size_in_mb: 100.0, video_files_size_in_mb: 200.0, chunks_size: 1000 }
    );
}
