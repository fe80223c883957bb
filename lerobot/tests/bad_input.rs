//! Every way a dataset can be wrong gives an error that names the file or key and says what was expected, never
//! a panic or a silently shorter dataset. Each case breaks one thing in a copy of the LeRobot-written fixture.

use std::path::Path;

mod common;

use common::{copy, fixture, keys};
use mars_lerobot::{Keys, LeRobotDataset, LeRobotError, ReadOptions};

fn read(root: &Path) -> Result<usize, LeRobotError> {
    let ds = LeRobotDataset::open(root)?;
    Ok(ds.read_with(&keys(), (64, 64), &ReadOptions::no_cache())?.1.frames)
}

fn edit_info(root: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let p = root.join("meta/info.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

fn truncate(path: &Path, keep: f64) {
    let bytes = std::fs::read(path).unwrap();
    std::fs::write(path, &bytes[..(bytes.len() as f64 * keep) as usize]).unwrap();
}

#[cfg(feature = "video")]
#[test]
fn the_fixture_itself_reads() {
    assert_eq!(read(&fixture()).unwrap(), 180);
}

/// A build without FFmpeg reads the vectors of a dataset with videos, and refuses its camera saying how to build
/// one that reads it — never a shorter or blank episode.
#[cfg(not(feature = "video"))]
#[test]
fn without_video_support_the_vectors_read_and_a_camera_is_refused_with_the_remedy() {
    let ds = LeRobotDataset::open(&fixture()).unwrap();
    let vectors = Keys { images: vec![], ..keys() };
    assert_eq!(ds.read_with(&vectors, (64, 64), &ReadOptions::no_cache()).unwrap().1.frames, 180);
    let msg = read(&fixture()).unwrap_err().to_string();
    assert!(msg.contains("file-000.mp4") && msg.contains("--features video"), "{msg}");
}

#[test]
fn an_older_layout_is_refused_with_the_converter_named() {
    let d = copy();
    edit_info(d.path(), |v| v["codebase_version"] = "v2.1".into());
    let e = read(d.path()).unwrap_err();
    assert!(matches!(e, LeRobotError::Version { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("v2.1") && msg.contains("convert_dataset_v21_to_v30"), "{msg}");
}

#[test]
fn a_missing_key_names_the_keys_there_are() {
    let ds = LeRobotDataset::open(&fixture()).unwrap();
    let keys = Keys { state: "observation.joints".into(), ..keys() };
    let e = ds.read_with(&keys, (64, 64), &ReadOptions::no_cache()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, LeRobotError::MissingKey { .. }) && msg.contains("observation.state"), "{msg}");
}

#[test]
fn a_shape_or_dtype_that_does_not_match_the_rows_is_refused() {
    let d = copy();
    edit_info(d.path(), |v| v["features"]["action"]["shape"] = serde_json::json!([3]));
    let msg = read(d.path()).unwrap_err().to_string();
    assert!(msg.contains("a row of 2 values, the feature's shape says 3"), "{msg}");

    let d = copy();
    edit_info(d.path(), |v| v["features"]["observation.state"]["dtype"] = "int64".into());
    let msg = read(d.path()).unwrap_err().to_string();
    assert!(msg.contains("observation.state") && msg.contains("not a float vector"), "{msg}");

    let ds = LeRobotDataset::open(&fixture()).unwrap();
    let keys = Keys { images: vec!["action".into()], ..keys() };
    let msg = ds.read_with(&keys, (64, 64), &ReadOptions::no_cache()).unwrap_err().to_string();
    assert!(msg.contains("only camera streams stored as video"), "{msg}");
}

#[test]
fn a_truncated_parquet_file_is_refused() {
    for file in ["data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet"] {
        let d = copy();
        truncate(&d.path().join(file), 0.6);
        let e = read(d.path()).unwrap_err();
        assert!(matches!(e, LeRobotError::Parquet { .. }), "{file}: {e}");
        assert!(e.to_string().contains(file), "{e}");
    }
}

#[cfg(feature = "video")]
#[test]
fn a_truncated_video_is_refused_not_read_short() {
    let video = "videos/observation.images.top/chunk-000/file-000.mp4";
    // Cut in the middle of the frames (the MP4 index at the front survives), and cut to the first bytes.
    for keep in [0.5, 0.02] {
        let d = copy();
        truncate(&d.path().join(video), keep);
        let e = read(d.path()).unwrap_err();
        let msg = e.to_string();
        println!("keep {keep}: {msg}");
        assert!(msg.contains("file-000.mp4"), "keep {keep}: {msg}");
    }
}

/// The last episode's video range moved 5 s past the end of the file it names.
#[cfg(feature = "video")]
#[test]
fn an_episode_whose_video_range_falls_outside_its_file_is_refused() {
    use arrow_array::{ArrayRef, Float64Array, RecordBatch};
    use parquet::arrow::ArrowWriter;
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    use std::sync::Arc;
    let d = copy();
    let path = d.path().join("meta/episodes/chunk-000/file-000.parquet");
    let batch = {
        let reader = ParquetRecordBatchReaderBuilder::try_new(std::fs::File::open(&path).unwrap()).unwrap();
        let mut batches = reader.build().unwrap().collect::<Result<Vec<_>, _>>().unwrap();
        assert_eq!(batches.len(), 1);
        batches.remove(0)
    };
    let mut columns: Vec<ArrayRef> = batch.columns().to_vec();
    for name in ["videos/observation.images.top/from_timestamp", "videos/observation.images.top/to_timestamp"] {
        let i = batch.schema().index_of(name).unwrap();
        let old = columns[i].as_any().downcast_ref::<Float64Array>().unwrap();
        let last = old.len() - 1;
        columns[i] = Arc::new(Float64Array::from_iter_values(
            old.values().iter().enumerate().map(|(r, &t)| if r == last { t + 5.0 } else { t }),
        ));
    }
    let moved = RecordBatch::try_new(batch.schema(), columns).unwrap();
    let mut w = ArrowWriter::try_new(std::fs::File::create(&path).unwrap(), moved.schema(), None).unwrap();
    w.write(&moved).unwrap();
    w.close().unwrap();
    let e = read(d.path()).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, LeRobotError::Episode { episode: 5, .. }) && msg.contains("falls outside its file"), "{msg}");
}

#[test]
fn missing_rows_or_frames_are_refused() {
    let d = copy();
    edit_info(d.path(), |v| v["total_frames"] = 181.into());
    let msg = read(d.path()).unwrap_err().to_string();
    assert!(msg.contains("meta/info.json says 6 of 181"), "{msg}");
}
