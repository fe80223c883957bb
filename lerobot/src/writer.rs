//! Writing a LeRobot v3.0 dataset: frames in, episode by episode; each episode's rows go to the current data
//! file and each camera's frames to its current video file when the episode ends; at `finish` the files are
//! closed, the episodes' metadata (with their statistics), the tasks, `info.json` and `stats.json` are written
//! and the dataset appears at its path in one rename. Until then it lives beside it in `<name>.partial/`, so a
//! crash never leaves something at the path that looks like a dataset.
//!
//! Files are split as LeRobot splits them ([`FileLimits`]): a new data or video file once the current one would
//! reach its size limit, decided at episode boundaries, so an episode is always in one data file and one video
//! file per camera.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::builder::{Float64Builder, Int64Builder, ListBuilder, StringBuilder};
use arrow_array::{ArrayRef, FixedSizeListArray, Float32Array, Float64Array, Int64Array, RecordBatch, StringArray};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use serde_json::{Value, json};

use crate::LeRobotError;
use crate::episodes::FileIndex;
pub use crate::file_limits::FileLimits;
use crate::file_limits::{data_file, data_rolls_over, video_file, video_rolls_over};
use crate::info::{CODEBASE_VERSION, Feature, Info};
use crate::stats::{FeatureStats, Histogram};
use crate::video_out::{VideoFile, VideoWriter};

/// A float32 vector feature (state, action, or one of our own columns).
#[derive(Debug, Clone, PartialEq)]
pub struct VectorSpec {
    pub key: String,
    /// One name per value.
    pub names: Vec<String>,
}

/// A camera stream, stored as video.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraSpec {
    pub key: String,
    pub height: u32,
    pub width: u32,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DatasetSpec {
    pub fps: u32,
    pub robot_type: String,
    pub vectors: Vec<VectorSpec>,
    pub cameras: Vec<CameraSpec>,
}

const EPISODES_FILE: &str = "meta/episodes/chunk-000/file-000.parquet";
const DATA_PATH: &str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet";
const VIDEO_PATH: &str = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4";
/// The columns every LeRobot frame has besides its features, in LeRobot's order.
const INDEX_COLUMNS: [&str; 4] = ["frame_index", "episode_index", "index", "task_index"];

struct EpisodeRow {
    length: usize,
    task_index: i64,
    from_index: i64,
    data: FileIndex,
    /// Per camera: its video file, and from, to (s) in it.
    videos: Vec<(FileIndex, f64, f64)>,
    /// Per feature, in `feature_order`.
    stats: Vec<FeatureStats>,
}

/// The data file episodes are written to now: one row group per episode, as LeRobot's writer does.
struct DataFile {
    index: FileIndex,
    path: PathBuf,
    writer: ArrowWriter<File>,
    rows: usize,
}

/// A camera's output: the open episode's own file, and the dataset's video file episodes are appended to now.
struct CameraOut {
    episode: Option<VideoWriter>,
    /// Where the open episode is encoded (inside the staging directory, removed once copied).
    episode_path: PathBuf,
    file: Option<(FileIndex, VideoFile)>,
    /// `video.codec` for info.json, from the first episode's encoder.
    codec: Option<&'static str>,
}

pub struct DatasetWriter {
    root: PathBuf,
    staging: PathBuf,
    spec: DatasetSpec,
    limits: FileLimits,
    /// Per vector feature, every frame's values (for `stats.json`).
    vectors: Vec<Vec<f32>>,
    timestamps: Vec<f32>,
    /// Per frame: frame_index, episode_index, index, task_index.
    indices: [Vec<i64>; 4],
    data_schema: SchemaRef,
    data: Option<DataFile>,
    cameras: Vec<CameraOut>,
    /// The open episode's frames so far and its images' histograms.
    open_frames: usize,
    open_hist: Vec<Histogram>,
    all_hist: Vec<Histogram>,
    episodes: Vec<EpisodeRow>,
    tasks: Vec<String>,
    /// Files of our own under `meta/` (LeRobot reads only the files it knows).
    extra_meta: Vec<(String, Value)>,
    /// A write that failed half-way: the files no longer agree with each other, so `finish` refuses.
    failed: Option<String>,
}

impl DatasetWriter {
    /// Starts a dataset that will appear at `root` (which must not exist yet: a recording never overwrites), its
    /// files split at LeRobot's default sizes.
    pub fn create(root: &Path, spec: DatasetSpec) -> Result<Self, LeRobotError> {
        Self::create_with_limits(root, spec, FileLimits::default())
    }

    /// [`DatasetWriter::create`], with files split at `limits`.
    pub fn create_with_limits(root: &Path, spec: DatasetSpec, limits: FileLimits) -> Result<Self, LeRobotError> {
        let exists = |path: &Path| LeRobotError::Read {
            path: path.to_owned(),
            error: std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "already exists; a dataset is never overwritten",
            ),
        };
        if root.exists() {
            return Err(exists(root));
        }
        if spec.fps == 0 || spec.vectors.iter().any(|v| v.names.is_empty()) {
            return Err(LeRobotError::Feature { key: "spec".into(), problem: "fps 0 or a vector of no values".into() });
        }
        let positive = |mb: f64| mb.is_finite() && mb > 0.0;
        if !positive(limits.data_files_size_in_mb)
            || !positive(limits.video_files_size_in_mb)
            || limits.chunks_size == 0
        {
            return Err(LeRobotError::Feature {
                key: "limits".into(),
                problem: format!("{limits:?}: file sizes must be above 0 MB and a chunk must hold a file"),
            });
        }
        let mut staging = root.as_os_str().to_owned();
        staging.push(".partial");
        let staging = PathBuf::from(staging);
        if staging.exists() {
            return Err(exists(&staging));
        }
        mkdir(&staging.join("meta/episodes/chunk-000"))?;
        mkdir(&staging.join("tmp"))?;
        // The first episode's encoders now, so that one this FFmpeg cannot open fails here, before any frame.
        let mut cameras = Vec::with_capacity(spec.cameras.len());
        for (k, c) in spec.cameras.iter().enumerate() {
            let episode_path = staging.join(format!("tmp/camera-{k}-episode.mp4"));
            let episode = match VideoWriter::create(&episode_path, c.width, c.height, spec.fps) {
                Ok(v) => v,
                Err(e) => {
                    drop(cameras);
                    let _ = std::fs::remove_dir_all(&staging);
                    return Err(e);
                }
            };
            cameras.push(CameraOut { episode: Some(episode), episode_path, file: None, codec: None });
        }
        Ok(Self {
            root: root.to_owned(),
            staging,
            limits,
            vectors: vec![Vec::new(); spec.vectors.len()],
            timestamps: Vec::new(),
            indices: Default::default(),
            data_schema: Arc::new(data_schema(&spec)),
            data: None,
            cameras,
            open_frames: 0,
            open_hist: vec![Histogram::default(); spec.cameras.len()],
            all_hist: vec![Histogram::default(); spec.cameras.len()],
            episodes: Vec::new(),
            tasks: Vec::new(),
            extra_meta: Vec::new(),
            failed: None,
            spec,
        })
    }

    /// Appends a frame to the open episode: one slice per vector feature and per camera, in the spec's order.
    pub fn add_frame(&mut self, vectors: &[&[f32]], images: &[&[u8]]) -> Result<(), LeRobotError> {
        let bad = |key: &str, problem: String| LeRobotError::Feature { key: key.to_owned(), problem };
        if vectors.len() != self.spec.vectors.len() || images.len() != self.spec.cameras.len() {
            return Err(bad(
                "frame",
                format!(
                    "{} vectors and {} images, the spec has {} and {}",
                    vectors.len(),
                    images.len(),
                    self.spec.vectors.len(),
                    self.spec.cameras.len()
                ),
            ));
        }
        for (v, s) in vectors.iter().zip(&self.spec.vectors) {
            if v.len() != s.names.len() {
                return Err(bad(&s.key, format!("{} values, the spec names {}", v.len(), s.names.len())));
            }
        }
        for (img, c) in images.iter().zip(&self.spec.cameras) {
            if img.len() != (c.height * c.width * 3) as usize {
                return Err(bad(&c.key, format!("{} bytes, not {}×{}×3", img.len(), c.height, c.width)));
            }
        }
        self.check_not_failed()?;
        if let Err(e) = self.encode(images) {
            self.failed = Some(e.to_string());
            return Err(e);
        }
        for (col, v) in self.vectors.iter_mut().zip(vectors) {
            col.extend_from_slice(v);
        }
        let frame = self.open_frames as i64;
        self.timestamps.push((frame as f64 / f64::from(self.spec.fps)) as f32);
        let row = [frame, self.episodes.len() as i64, self.timestamps.len() as i64 - 1, -1];
        for (col, v) in self.indices.iter_mut().zip(row) {
            col.push(v);
        }
        self.open_frames += 1;
        Ok(())
    }

    /// Each camera's image into its episode's file (opened at the episode's first frame, the first episode's at
    /// `create`).
    fn encode(&mut self, images: &[&[u8]]) -> Result<(), LeRobotError> {
        for ((img, (out, c)), hist) in
            images.iter().zip(self.cameras.iter_mut().zip(&self.spec.cameras)).zip(&mut self.open_hist)
        {
            let video = match &mut out.episode {
                Some(v) => v,
                None => out.episode.insert(VideoWriter::create(&out.episode_path, c.width, c.height, self.spec.fps)?),
            };
            video.push(img)?;
            hist.add(img);
        }
        Ok(())
    }

    fn check_not_failed(&self) -> Result<(), LeRobotError> {
        match &self.failed {
            None => Ok(()),
            Some(e) => Err(LeRobotError::Episode {
                episode: self.episodes.len() as i64,
                problem: format!("an earlier write failed ({e}); nothing more is written (abandon the dataset)"),
            }),
        }
    }

    /// Closes the open episode (at least one frame) under `task`, its instruction in words: its rows go to the
    /// current data file and its frames to each camera's current video file (or to new ones: [`FileLimits`]).
    pub fn end_episode(&mut self, task: &str) -> Result<(), LeRobotError> {
        let length = self.open_frames;
        if length == 0 {
            return Err(LeRobotError::Episode { episode: self.episodes.len() as i64, problem: "no frames".into() });
        }
        self.check_not_failed()?;
        let task_index = match self.tasks.iter().position(|t| t == task) {
            Some(i) => i as i64,
            None => {
                self.tasks.push(task.to_owned());
                self.tasks.len() as i64 - 1
            }
        };
        let from_index = (self.timestamps.len() - length) as i64;
        let rows = from_index as usize..self.timestamps.len();
        self.indices[3][rows.clone()].iter_mut().for_each(|t| *t = task_index);
        let written = self.write_rows(rows.clone()).and_then(|data| Ok((data, self.write_videos(length)?)));
        let (data, videos) = match written {
            Ok(w) => w,
            Err(e) => {
                self.failed = Some(e.to_string());
                return Err(e);
            }
        };
        let mut stats = Vec::new();
        for (col, s) in self.vectors.iter().zip(&self.spec.vectors) {
            let d = s.names.len();
            let values: Vec<f64> = col[rows.start * d..rows.end * d].iter().map(|&v| f64::from(v)).collect();
            stats.push(FeatureStats::of_vectors(&values, d));
        }
        for (open, all) in self.open_hist.iter_mut().zip(&mut self.all_hist) {
            stats.push(FeatureStats::of_images(open, length));
            all.merge(open);
            *open = Histogram::default();
        }
        stats.extend(self.index_stats(rows));
        self.episodes.push(EpisodeRow { length, task_index, from_index, data, videos, stats });
        self.open_frames = 0;
        Ok(())
    }

    /// The episode's rows (`rows`) as a row group of the current data file, or of the next one when they would
    /// bring the current one to the limit.
    fn write_rows(&mut self, rows: std::ops::Range<usize>) -> Result<FileIndex, LeRobotError> {
        let batch = self.data_batch(rows.clone())?;
        let next = match &self.data {
            None => Some(FileIndex { chunk: 0, file: 0 }),
            Some(d) => {
                data_rolls_over(d.writer.bytes_written() as u64, d.rows, rows.len(), self.limits.data_files_size_in_mb)
                    .then(|| d.index.next(self.limits.chunks_size))
            }
        };
        if let Some(index) = next {
            if let Some(d) = self.data.take() {
                d.writer.close().map_err(|e| LeRobotError::parquet(&d.path, e))?;
            }
            let path = self.staging.join(data_file(index));
            mkdir(path.parent().expect("a file in a chunk directory"))?;
            let file = File::create(&path).map_err(|error| LeRobotError::Read { path: path.clone(), error })?;
            let writer = ArrowWriter::try_new(file, self.data_schema.clone(), Some(parquet_properties()))
                .map_err(|e| LeRobotError::parquet(&path, e))?;
            self.data = Some(DataFile { index, path, writer, rows: 0 });
        }
        let d = self.data.as_mut().expect("a data file is open");
        d.writer.write(&batch).map_err(|e| LeRobotError::parquet(&d.path, e))?;
        // The row group goes to the file now, so that its size on disk is the file's size so far.
        d.writer.flush().map_err(|e| LeRobotError::parquet(&d.path, e))?;
        d.rows += rows.len();
        Ok(d.index)
    }

    /// Each camera's episode file closed and copied to the end of the camera's current video file, or into the
    /// next one when it would bring the current one to the limit: per camera its file and from, to (s) in it.
    fn write_videos(&mut self, length: usize) -> Result<Vec<(FileIndex, f64, f64)>, LeRobotError> {
        let fps = f64::from(self.spec.fps);
        let mut out = Vec::with_capacity(self.cameras.len());
        for (cam, spec) in self.cameras.iter_mut().zip(&self.spec.cameras) {
            let episode = cam.episode.take().expect("an episode of frames has each camera's file open");
            cam.codec.get_or_insert(episode.codec);
            let frames = episode.frames();
            debug_assert_eq!(frames as usize, length);
            episode.finish()?;
            let path = &cam.episode_path;
            let bytes =
                std::fs::metadata(path).map_err(|error| LeRobotError::Read { path: path.clone(), error })?.len();
            let next = match &cam.file {
                None => Some(FileIndex { chunk: 0, file: 0 }),
                Some((index, file)) => video_rolls_over(file.bytes(), bytes, self.limits.video_files_size_in_mb)
                    .then(|| index.next(self.limits.chunks_size)),
            };
            if let Some(index) = next {
                if let Some((_, file)) = cam.file.take() {
                    file.finish()?;
                }
                let target = self.staging.join(video_file(&spec.key, index));
                mkdir(target.parent().expect("a file in a chunk directory"))?;
                cam.file = Some((index, VideoFile::create(&target, path, self.spec.fps)?));
            }
            let (index, file) = cam.file.as_mut().expect("a video file is open");
            let from = file.frames();
            file.append(path, frames)?;
            std::fs::remove_file(path).map_err(|error| LeRobotError::Read { path: path.clone(), error })?;
            out.push((*index, from as f64 / fps, (from + frames) as f64 / fps));
        }
        Ok(out)
    }

    /// Statistics of timestamp, frame_index, episode_index, index, task_index over `rows`.
    fn index_stats(&self, rows: std::ops::Range<usize>) -> Vec<FeatureStats> {
        let ts: Vec<f64> = self.timestamps[rows.clone()].iter().map(|&t| f64::from(t)).collect();
        let mut out = vec![FeatureStats::of_vectors(&ts, 1)];
        for col in &self.indices {
            let v: Vec<f64> = col[rows.clone()].iter().map(|&i| i as f64).collect();
            out.push(FeatureStats::of_vectors(&v, 1));
        }
        out
    }

    /// Feature keys in the order the statistics are kept: vectors, cameras, timestamp, the index columns.
    fn feature_order(&self) -> Vec<String> {
        let mut keys: Vec<String> = self.spec.vectors.iter().map(|v| v.key.clone()).collect();
        keys.extend(self.spec.cameras.iter().map(|c| c.key.clone()));
        keys.push("timestamp".into());
        keys.extend(INDEX_COLUMNS.iter().map(|s| (*s).to_owned()));
        keys
    }

    /// Writes every file and moves the dataset into place. An episode still open is an error (end it first).
    pub fn finish(mut self) -> Result<PathBuf, LeRobotError> {
        self.check_not_failed()?;
        if self.open_frames > 0 || self.episodes.is_empty() {
            return Err(LeRobotError::Episode {
                episode: self.episodes.len() as i64,
                problem: format!(
                    "finish with {} episodes and {} frames not in one",
                    self.episodes.len(),
                    self.open_frames
                ),
            });
        }
        if let Some(d) = self.data.take() {
            d.writer.close().map_err(|e| LeRobotError::parquet(&d.path, e))?;
        }
        let mut codecs = Vec::with_capacity(self.cameras.len());
        for cam in &mut self.cameras {
            if let Some((_, file)) = cam.file.take() {
                file.finish()?;
            }
            codecs.push(cam.codec.expect("a camera with an episode has a codec"));
        }
        let tmp = self.staging.join("tmp");
        std::fs::remove_dir_all(&tmp).map_err(|error| LeRobotError::Read { path: tmp, error })?;
        self.write_episodes()?;
        self.write_tasks()?;
        self.write_json_files(&codecs)?;
        for (name, value) in &self.extra_meta {
            self.write_json(&format!("meta/{name}"), value)?;
        }
        std::fs::rename(&self.staging, &self.root)
            .map_err(|error| LeRobotError::Read { path: self.root.clone(), error })?;
        Ok(self.root)
    }

    /// A JSON file of our own written as `meta/<name>` at `finish` (e.g. what replaying the run needs).
    pub fn set_extra_meta(&mut self, name: &str, value: Value) {
        self.extra_meta.retain(|(n, _)| n != name);
        self.extra_meta.push((name.to_owned(), value));
    }

    /// Gives up: nothing is written and the staging directory is removed (a run that recorded no complete
    /// episode leaves nothing behind).
    pub fn abandon(mut self) {
        self.data = None;
        self.cameras.clear();
        let _ = std::fs::remove_dir_all(&self.staging);
    }

    fn write_parquet(&self, rel: &str, batch: &RecordBatch) -> Result<(), LeRobotError> {
        let path = self.staging.join(rel);
        let file = File::create(&path).map_err(|error| LeRobotError::Read { path: path.clone(), error })?;
        let mut w = ArrowWriter::try_new(file, batch.schema(), Some(parquet_properties()))
            .map_err(|e| LeRobotError::parquet(&path, e))?;
        w.write(batch).map_err(|e| LeRobotError::parquet(&path, e))?;
        w.close().map_err(|e| LeRobotError::parquet(&path, e))?;
        Ok(())
    }

    /// The rows `rows` as the data file has them: the vector features, then timestamp and the indices.
    fn data_batch(&self, rows: std::ops::Range<usize>) -> Result<RecordBatch, LeRobotError> {
        let mut columns: Vec<ArrayRef> = Vec::new();
        for (col, s) in self.vectors.iter().zip(&self.spec.vectors) {
            let n = s.names.len();
            let values = Float32Array::from(col[rows.start * n..rows.end * n].to_vec());
            if n == 1 {
                columns.push(Arc::new(values));
                continue;
            }
            let item = Arc::new(Field::new("element", DataType::Float32, true));
            let array = FixedSizeListArray::try_new(item, n as i32, Arc::new(values), None)
                .map_err(|e| LeRobotError::parquet(&self.staging.join("data"), e))?;
            columns.push(Arc::new(array));
        }
        columns.push(Arc::new(Float32Array::from(self.timestamps[rows.clone()].to_vec())));
        for col in &self.indices {
            columns.push(Arc::new(Int64Array::from(col[rows.clone()].to_vec())));
        }
        RecordBatch::try_new(self.data_schema.clone(), columns)
            .map_err(|e| LeRobotError::parquet(&self.staging.join("data"), e))
    }

    fn write_episodes(&self) -> Result<(), LeRobotError> {
        let path = self.staging.join(EPISODES_FILE);
        let n = self.episodes.len();
        let int = |f: &dyn Fn(usize, &EpisodeRow) -> i64| -> ArrayRef {
            Arc::new(Int64Array::from_iter_values(self.episodes.iter().enumerate().map(|(i, e)| f(i, e))))
        };
        let float = |f: &dyn Fn(&EpisodeRow) -> f64| -> ArrayRef {
            Arc::new(Float64Array::from_iter_values(self.episodes.iter().map(f)))
        };
        let mut cols: Vec<(String, ArrayRef)> = vec![("episode_index".into(), int(&|i, _| i as i64))];
        let mut tasks = ListBuilder::new(StringBuilder::new()).with_field(Field::new("element", DataType::Utf8, true));
        for e in &self.episodes {
            tasks.values().append_value(&self.tasks[e.task_index as usize]);
            tasks.append(true);
        }
        cols.push(("tasks".into(), Arc::new(tasks.finish())));
        cols.push(("length".into(), int(&|_, e| e.length as i64)));
        cols.push(("data/chunk_index".into(), int(&|_, e| e.data.chunk)));
        cols.push(("data/file_index".into(), int(&|_, e| e.data.file)));
        cols.push(("dataset_from_index".into(), int(&|_, e| e.from_index)));
        cols.push(("dataset_to_index".into(), int(&|_, e| e.from_index + e.length as i64)));
        for (k, c) in self.spec.cameras.iter().enumerate() {
            cols.push((format!("videos/{}/chunk_index", c.key), int(&|_, e| e.videos[k].0.chunk)));
            cols.push((format!("videos/{}/file_index", c.key), int(&|_, e| e.videos[k].0.file)));
            cols.push((format!("videos/{}/from_timestamp", c.key), float(&|e| e.videos[k].1)));
            cols.push((format!("videos/{}/to_timestamp", c.key), float(&|e| e.videos[k].2)));
        }
        for (f, key) in self.feature_order().iter().enumerate() {
            let image = self.episodes[0].stats[f].image;
            let names: Vec<&str> = self.episodes[0].stats[f].named().iter().map(|(n, _)| *n).collect();
            for (s, name) in names.iter().enumerate() {
                let values = |e: &EpisodeRow| e.stats[f].named()[s].1.to_vec();
                cols.push((format!("stats/{key}/{name}"), stats_column(self.episodes.iter().map(values), image)));
                if *name == "std" {
                    let mut counts =
                        ListBuilder::new(Int64Builder::new()).with_field(Field::new("element", DataType::Int64, true));
                    for e in &self.episodes {
                        counts.values().append_value(e.stats[f].count as i64);
                        counts.append(true);
                    }
                    cols.push((format!("stats/{key}/count"), Arc::new(counts.finish())));
                }
            }
        }
        cols.push(("meta/episodes/chunk_index".into(), int(&|_, _| 0)));
        cols.push(("meta/episodes/file_index".into(), int(&|_, _| 0)));
        let fields: Vec<Field> = cols.iter().map(|(k, a)| Field::new(k, a.data_type().clone(), true)).collect();
        let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), cols.into_iter().map(|(_, a)| a).collect())
            .map_err(|e| LeRobotError::parquet(&path, e))?;
        debug_assert_eq!(batch.num_rows(), n);
        self.write_parquet(EPISODES_FILE, &batch)
    }

    /// `meta/tasks.parquet`: task_index and task, with the task as the pandas index (LeRobot reads it with pandas
    /// and looks tasks up by that index).
    fn write_tasks(&self) -> Result<(), LeRobotError> {
        let path = self.staging.join("meta/tasks.parquet");
        let pandas = json!({
            "index_columns": ["task"],
            "column_indexes": [{"name": null, "field_name": null, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
            "columns": [
                {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": null},
                {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": null}
            ],
            "attributes": {}, "creator": {"library": "mars-lerobot", "version": env!("CARGO_PKG_VERSION")}, "pandas_version": "2.3.3"
        });
        let schema = Schema::new(vec![
            Field::new("task_index", DataType::Int64, true),
            Field::new("task", DataType::Utf8, true),
        ])
        .with_metadata(std::collections::BTreeMap::from([("pandas".to_owned(), pandas.to_string())]));
        let columns: Vec<ArrayRef> = vec![
            Arc::new(Int64Array::from_iter_values(0..self.tasks.len() as i64)),
            Arc::new(StringArray::from_iter_values(&self.tasks)),
        ];
        let batch = RecordBatch::try_new(Arc::new(schema), columns).map_err(|e| LeRobotError::parquet(&path, e))?;
        self.write_parquet("meta/tasks.parquet", &batch)
    }

    fn write_json_files(&self, codecs: &[&str]) -> Result<(), LeRobotError> {
        let mut features = BTreeMap::new();
        for s in &self.spec.vectors {
            let names = json!(s.names);
            features.insert(
                s.key.clone(),
                Feature { dtype: "float32".into(), shape: vec![s.names.len()], names: Some(names), info: None },
            );
        }
        for (c, codec) in self.spec.cameras.iter().zip(codecs) {
            let info = json!({
                "video.height": c.height, "video.width": c.width, "video.codec": codec, "video.pix_fmt": "yuv420p",
                "video.is_depth_map": false, "video.fps": self.spec.fps, "video.channels": 3, "has_audio": false,
            });
            let shape = vec![c.height as usize, c.width as usize, 3];
            let names = Some(json!(["height", "width", "channels"]));
            features.insert(c.key.clone(), Feature { dtype: "video".into(), shape, names, info: Some(info) });
        }
        features
            .insert("timestamp".into(), Feature { dtype: "float32".into(), shape: vec![1], names: None, info: None });
        for k in INDEX_COLUMNS {
            features.insert(k.into(), Feature { dtype: "int64".into(), shape: vec![1], names: None, info: None });
        }
        let frames = self.timestamps.len();
        let info = Info {
            codebase_version: CODEBASE_VERSION.into(),
            fps: f64::from(self.spec.fps),
            features,
            total_episodes: self.episodes.len(),
            total_frames: frames,
            total_tasks: self.tasks.len(),
            chunks_size: self.limits.chunks_size,
            data_files_size_in_mb: Some(self.limits.data_files_size_in_mb),
            video_files_size_in_mb: Some(self.limits.video_files_size_in_mb),
            data_path: DATA_PATH.into(),
            video_path: (!self.spec.cameras.is_empty()).then(|| VIDEO_PATH.into()),
            robot_type: Some(self.spec.robot_type.clone()),
            splits: [("train".to_owned(), format!("0:{}", self.episodes.len()))].into(),
        };
        let mut info_json = serde_json::to_value(&info).expect("info serialises");
        // LeRobot's info.json has fps and its default sizes as integers.
        info_json["fps"] = json!(self.spec.fps);
        for (key, mb) in [
            ("data_files_size_in_mb", self.limits.data_files_size_in_mb),
            ("video_files_size_in_mb", self.limits.video_files_size_in_mb),
        ] {
            if mb.fract() == 0.0 && mb <= u32::MAX as f64 {
                info_json[key] = json!(mb as u32);
            }
        }
        self.write_json("meta/info.json", &info_json)?;
        let mut stats = serde_json::Map::new();
        let all = 0..frames;
        let mut whole: Vec<FeatureStats> = Vec::new();
        for (col, s) in self.vectors.iter().zip(&self.spec.vectors) {
            let values: Vec<f64> = col.iter().map(|&v| f64::from(v)).collect();
            whole.push(FeatureStats::of_vectors(&values, s.names.len()));
        }
        whole.extend(self.all_hist.iter().map(|h| FeatureStats::of_images(h, frames)));
        whole.extend(self.index_stats(all));
        for (key, s) in self.feature_order().into_iter().zip(&whole) {
            stats.insert(key, s.to_json());
        }
        self.write_json("meta/stats.json", &Value::Object(stats))
    }

    fn write_json(&self, rel: &str, v: &Value) -> Result<(), LeRobotError> {
        let path = self.staging.join(rel);
        let text = serde_json::to_string_pretty(v).expect("json serialises");
        std::fs::write(&path, text).map_err(|error| LeRobotError::Read { path, error })
    }
}

fn mkdir(path: &Path) -> Result<(), LeRobotError> {
    std::fs::create_dir_all(path).map_err(|error| LeRobotError::Read { path: path.to_owned(), error })
}

fn parquet_properties() -> parquet::file::properties::WriterProperties {
    parquet::file::properties::WriterProperties::builder().set_compression(parquet::basic::Compression::SNAPPY).build()
}

/// The data files' schema: the vector features as fixed-size lists of float32, then timestamp and the indices,
/// with the `huggingface` metadata LeRobot's loader (through HF datasets) reads the features from.
fn data_schema(spec: &DatasetSpec) -> Schema {
    let mut fields = Vec::new();
    let mut hf = serde_json::Map::new();
    for s in &spec.vectors {
        // LeRobot (through HF datasets) stores a feature of shape (1,) as a plain value, not a list of one.
        if s.names.len() == 1 {
            fields.push(Field::new(&s.key, DataType::Float32, true));
            hf.insert(s.key.clone(), json!({"dtype": "float32", "_type": "Value"}));
            continue;
        }
        let item = Arc::new(Field::new("element", DataType::Float32, true));
        let n = s.names.len() as i32;
        fields.push(Field::new(&s.key, DataType::FixedSizeList(item, n), true));
        hf.insert(
            s.key.clone(),
            json!({"feature": {"dtype": "float32", "_type": "Value"}, "length": n, "_type": "List"}),
        );
    }
    fields.push(Field::new("timestamp", DataType::Float32, true));
    hf.insert("timestamp".into(), json!({"dtype": "float32", "_type": "Value"}));
    for name in INDEX_COLUMNS {
        fields.push(Field::new(name, DataType::Int64, true));
        hf.insert(name.into(), json!({"dtype": "int64", "_type": "Value"}));
    }
    let meta = json!({ "info": { "features": Value::Object(hf) } }).to_string();
    Schema::new(fields).with_metadata(std::collections::BTreeMap::from([("huggingface".to_owned(), meta)]))
}

/// One statistic of one feature for every episode: list<double>, or for a camera list<list<list<double>>>
/// shaped [3][1][1] as LeRobot writes image statistics.
fn stats_column(rows: impl Iterator<Item = Vec<f64>>, image: bool) -> ArrayRef {
    let field = |t: DataType| Field::new("element", t, true);
    if !image {
        let mut b = ListBuilder::new(Float64Builder::new()).with_field(field(DataType::Float64));
        for r in rows {
            b.values().append_slice(&r);
            b.append(true);
        }
        return Arc::new(b.finish());
    }
    let inner = ListBuilder::new(Float64Builder::new()).with_field(field(DataType::Float64));
    let inner_t = DataType::List(Arc::new(field(DataType::Float64)));
    let middle = ListBuilder::new(inner).with_field(field(inner_t.clone()));
    let middle_t = DataType::List(Arc::new(field(inner_t)));
    let mut b = ListBuilder::new(middle).with_field(field(middle_t));
    for r in rows {
        for v in r {
            b.values().values().values().append_value(v);
            b.values().values().append(true);
            b.values().append(true);
        }
        b.append(true);
    }
    Arc::new(b.finish())
}
