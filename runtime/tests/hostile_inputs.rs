//! Hostile inputs marsd used to accept and then panic on (issue 33, section 5): configurations whose times
//! overflow a `Duration` once the loops run, and recordings `marsd replay` indexed or sliced past their end. Each
//! is now refused before anything moves or is read, with an error that names the problem.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, Int64Array, RecordBatch};
use mars_lerobot::table::Table;
use mars_lerobot::writer::{DatasetSpec, DatasetWriter, VectorSpec};
use mars_runtime::policy::recorded_actions::RecordedActions;
use mars_runtime::tools::replay::{ReplayArgs, run};
use parquet::arrow::ArrowWriter;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The shipped config with `line` in place of the line that starts with `key =`, and `extra` appended.
fn config(dir: &Path, name: &str, key: &str, line: &str, extra: &str) -> PathBuf {
    let text = std::fs::read_to_string(root().join("configs/marsd.toml")).unwrap();
    let old = text.lines().find(|l| l.starts_with(&format!("{key} ="))).unwrap_or_else(|| panic!("{key}"));
    let path = dir.join(name);
    std::fs::write(&path, format!("{}\n{extra}\n", text.replace(old, line))).unwrap();
    path
}

/// Each of these parsed before and made marsd panic once its threads ran (`Duration::from_secs_f64` of 1e300 or of
/// a negative number); now marsd refuses to start, exit status 2, naming the key, before opening any port.
#[test]
fn marsd_refuses_times_that_would_panic_its_running_loops_with_status_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The writer's delay is converted when a recording starts: the config records.
    let record = format!("seed = 0\nrecord = {:?}", d.join("recording").display().to_string());
    let cases = [
        ("handshake_timeout_s", config(d, "a.toml", "handshake_timeout_s", "handshake_timeout_s = 1e300", "")),
        ("histograms.interval_s", config(d, "b.toml", "interval_s", "interval_s = 1e300", "")),
        (
            "faults.record_writer_delay_ms",
            config(d, "c.toml", "seed", &record, "[faults]\nrecord_writer_delay_ms = -1.0"),
        ),
    ];
    for (key, cfg) in &cases {
        let out = Command::new(env!("CARGO_BIN_EXE_marsd"))
            .current_dir(root())
            .args(["--config", &cfg.display().to_string(), "--robot", &format!("hostile-{}", std::process::id())])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        println!("{key}: exit {:?}: {}", out.status.code(), err.trim());
        assert_eq!(out.status.code(), Some(2), "{key}: {err}");
        assert!(err.contains("refusing to start") && err.contains(key), "{key}: {err}");
        assert!(!err.contains("panicked"), "{key}: {err}");
    }
}

/// A recording as `marsd --record` writes one for the FR3's Pick Cup (8 values of state and action, the run's
/// calls and step counts), with `recorded` episodes of 5 frames, whose meta/mars.json lists `listed` episodes.
fn recording(dir: &Path, recorded: usize, listed: usize) -> PathBuf {
    let root = dir.join("rec");
    let names = |n: usize, p: &str| (0..n).map(|i| format!("{p}{i}")).collect::<Vec<_>>();
    let spec = DatasetSpec {
        fps: 10,
        robot_type: "fr3".into(),
        vectors: vec![
            VectorSpec { key: "observation.state".into(), names: names(8, "q") },
            VectorSpec { key: "action".into(), names: names(8, "a") },
            VectorSpec { key: "mars.call".into(), names: names(1, "call") },
            VectorSpec { key: "mars.k".into(), names: vec!["requested".into(), "used".into()] },
        ],
        cameras: vec![],
    };
    let mut w = DatasetWriter::create(&root, spec).unwrap();
    let rest = [0.0f32, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.04];
    for _ in 0..recorded {
        for t in 0..5 {
            let call = [if t == 0 { 1.0f32 } else { 0.0 }];
            w.add_frame(&[&rest[..], &rest[..], &call[..], &[3.0, 3.0][..]], &[]).unwrap();
        }
        w.end_episode("pick cup").unwrap();
    }
    let checkpoint = root_abs("assets/checkpoints/fr3_pick_cup/mars");
    let episodes: Vec<_> =
        (0..listed).map(|i| serde_json::json!({"marsd_episode": i, "success": true, "rest": rest})).collect();
    w.set_extra_meta("mars.json", serde_json::json!({"seed": 0, "checkpoint": checkpoint, "episodes": episodes}));
    w.finish().unwrap();
    root
}

fn root_abs(p: &str) -> PathBuf {
    std::fs::canonicalize(root().join(p)).unwrap()
}

/// meta/mars.json listed more episodes than the dataset holds: `marsd replay --episode 2` indexed past the end
/// (`replay.rs:114`), and so did `marsd --replay-actions` (`recorded_actions.rs:69`).
#[test]
fn a_replay_of_an_episode_the_recording_lacks_is_an_error_naming_both_counts() {
    let dir = tempfile::tempdir().unwrap();
    let rec = recording(dir.path(), 2, 3);
    let e = run(&ReplayArgs { dataset: rec.clone(), episode: 2, checkpoint: None }).unwrap_err();
    let msg = format!("{e:#}");
    assert!(msg.contains("lists 3 episodes but the dataset has 2"), "{msg}");
    let msg = format!("{:#}", RecordedActions::load(&rec, 2).unwrap_err());
    assert!(msg.contains("lists 3 episodes but the dataset has 2"), "{msg}");
    // The episodes it has replay.
    let report = run(&ReplayArgs { dataset: rec, episode: 1, checkpoint: None }).unwrap();
    assert_eq!(report.calls, 1);
}

/// The recording's metadata declares a camera (as a Push-T recording does) and the checkpoint takes a state only:
/// replay sliced the observation past its end (`replay.rs:138`). Now refused before any frame is read or decoded.
#[test]
fn a_recording_with_a_camera_against_a_state_only_checkpoint_is_refused_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let rec = recording(dir.path(), 2, 2);
    add_camera(&rec, "observation.images.top", 96);
    let e = run(&ReplayArgs { dataset: rec, episode: 0, checkpoint: None }).unwrap_err();
    let msg = format!("{e:#}");
    assert!(msg.contains("observation has 27656 values") && msg.contains("takes 8"), "{msg}");
}

/// Declares a `side`×`side` video feature `key` in the dataset's metadata, with each episode's range in one file.
fn add_camera(root: &Path, key: &str, side: usize) {
    let info_path = root.join("meta/info.json");
    let mut info: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&info_path).unwrap()).unwrap();
    info["features"][key] =
        serde_json::json!({"dtype": "video", "shape": [side, side, 3], "names": ["height", "width", "channels"]});
    info["video_path"] = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4".into();
    std::fs::write(&info_path, serde_json::to_string_pretty(&info).unwrap()).unwrap();
    let path = root.join("meta/episodes/chunk-000/file-000.parquet");
    let batch = Table::read(&path, None).unwrap().batches()[0].clone();
    let n = batch.num_rows();
    let mut fields: Vec<_> = batch.schema().fields().iter().map(|f| f.as_ref().clone()).collect();
    let mut columns: Vec<ArrayRef> = batch.columns().to_vec();
    let zeros: ArrayRef = Arc::new(Int64Array::from(vec![0; n]));
    let from: ArrayRef = Arc::new(Float64Array::from_iter_values((0..n).map(|i| i as f64 * 0.5)));
    let to: ArrayRef = Arc::new(Float64Array::from_iter_values((0..n).map(|i| i as f64 * 0.5 + 0.5)));
    for (c, a) in [("chunk_index", &zeros), ("file_index", &zeros), ("from_timestamp", &from), ("to_timestamp", &to)] {
        fields.push(arrow_schema::Field::new(format!("videos/{key}/{c}"), a.data_type().clone(), false));
        columns.push(a.clone());
    }
    let batch = RecordBatch::try_new(Arc::new(arrow_schema::Schema::new(fields)), columns).unwrap();
    let mut w = ArrowWriter::try_new(std::fs::File::create(&path).unwrap(), batch.schema(), None).unwrap();
    w.write(&batch).unwrap();
    w.close().unwrap();
}
