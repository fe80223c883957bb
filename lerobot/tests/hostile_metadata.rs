//! Metadata that used to panic the reader or be trained on (issue 33, section 5): indices whose difference
//! overflows, feature shapes whose sizes overflow or wrap, a rate of 0 frames per second, path templates that lead
//! out of the dataset's folder. Each is now refused when the dataset is opened, naming what is wrong. Only
//! metadata is read here (no video decoded), so these run in a build without FFmpeg.

use std::path::Path;
use std::sync::Arc;

mod common;

use arrow_array::{ArrayRef, Int64Array, RecordBatch};
use common::copy;
use mars_lerobot::LeRobotDataset;
use mars_lerobot::table::Table;
use parquet::arrow::ArrowWriter;

fn edit_info(root: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let p = root.join("meta/info.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

fn open_err(root: &Path) -> String {
    match LeRobotDataset::open(root) {
        Ok(_) => panic!("{} was accepted", root.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_rate_that_is_not_a_positive_finite_number_is_refused() {
    for fps in [serde_json::json!(0), serde_json::json!(-10), serde_json::json!(1e300)] {
        let d = copy();
        edit_info(d.path(), |v| v["fps"] = fps.clone());
        let e = open_err(d.path());
        assert!(e.contains("fps is") && e.contains("frames per second"), "{fps}: {e}");
    }
}

/// A state of usize::MAX values panicked `mars train --dataset` (`from_dataset.rs:114`); an image of
/// (2³² + 64) × 64 × 3 read as 64 × 64 (`as u32`) and was trained on.
#[test]
fn shapes_whose_sizes_overflow_or_wrap_are_refused() {
    let shapes = [
        ("observation.state", serde_json::json!([usize::MAX])),
        ("observation.images.top", serde_json::json!([(1u64 << 32) + 64, 64, 3])),
        ("action", serde_json::json!([1u64 << 40, 1u64 << 40])),
    ];
    for (key, shape) in shapes {
        let d = copy();
        edit_info(d.path(), |v| v["features"][key]["shape"] = shape.clone());
        let e = open_err(d.path());
        assert!(e.contains(key) && e.contains("values a frame"), "{key} {shape}: {e}");
    }
    // Within the total, a side beyond what a camera has is refused where the image is asked for.
    let d = copy();
    edit_info(d.path(), |v| v["features"]["observation.images.top"]["shape"] = serde_json::json!([8192, 2, 3]));
    let ds = LeRobotDataset::open(d.path()).unwrap();
    let e = ds.image_size("observation.images.top").unwrap_err().to_string();
    assert!(e.contains("1 to 4096 pixels a side"), "{e}");
    let e = ds.vector_len("observation.images.top").unwrap_err().to_string();
    assert!(e.contains("not a float vector"), "{e}");
}

/// A template that names a file outside the dataset's folder was read (and trained on).
#[test]
fn path_templates_that_leave_the_dataset_are_refused() {
    let data = [
        "../other/data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "/tmp/file-{file_index:03d}.parquet",
        "",
    ];
    for t in data {
        let d = copy();
        edit_info(d.path(), |v| v["data_path"] = t.into());
        let e = open_err(d.path());
        assert!(e.contains("leaves the dataset's folder"), "{t:?}: {e}");
    }
    let d = copy();
    edit_info(d.path(), |v| v["video_path"] = "videos/../../{video_key}/file-{file_index:03d}.mp4".into());
    assert!(open_err(d.path()).contains("leaves the dataset's folder"));
    // A video key is a path component too.
    let d = copy();
    edit_info(d.path(), |v| {
        let f = v["features"]["observation.images.top"].clone();
        v["features"]["../../escape"] = f;
    });
    assert!(open_err(d.path()).contains("leaves the dataset's folder"));
}

/// `dataset_to_index - dataset_from_index` overflowed (`episodes.rs:108`, a panic in a debug build).
#[test]
fn episode_indices_whose_difference_overflows_are_refused() {
    for (from, to) in [(i64::MIN, 10), (-5, i64::MAX), (i64::MAX, i64::MIN)] {
        let d = copy();
        set_first_episode_rows(d.path(), from, to);
        let e = open_err(d.path());
        assert!(e.contains("episode 0") && e.contains("dataset rows"), "{from}..{to}: {e}");
    }
}

/// Episode 0's `dataset_from_index` and `dataset_to_index` set to `from` and `to`.
fn set_first_episode_rows(root: &Path, from: i64, to: i64) {
    let path = root.join("meta/episodes/chunk-000/file-000.parquet");
    let batch = Table::read(&path, None).unwrap().batches()[0].clone();
    let mut columns: Vec<ArrayRef> = batch.columns().to_vec();
    for (name, v) in [("dataset_from_index", from), ("dataset_to_index", to)] {
        let i = batch.schema().index_of(name).unwrap();
        let old = columns[i].as_any().downcast_ref::<Int64Array>().unwrap();
        columns[i] = Arc::new(Int64Array::from_iter_values(
            old.values().iter().enumerate().map(|(r, &x)| if r == 0 { v } else { x }),
        ));
    }
    let batch = RecordBatch::try_new(batch.schema(), columns).unwrap();
    let mut w = ArrowWriter::try_new(std::fs::File::create(&path).unwrap(), batch.schema(), None).unwrap();
    w.write(&batch).unwrap();
    w.close().unwrap();
}
