//! A LeRobot v3.0 dataset on disk: opened (metadata checked), then its episodes read with the features a policy
//! takes — a state vector, an action vector, camera streams decoded to the size the policy's encoder takes (or
//! taken from the decoded-frame [`cache`](crate::cache) when an earlier read decoded them).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::LeRobotError;
use crate::cache::{self, FrameCache, Source};
use crate::episodes::{self, Episode, FileIndex};
use crate::info::{Feature, Info, MAX_IMAGE_SIDE};
use crate::table::Table;
use crate::video;

/// LeRobot's own reader accepts a frame this close to the timestamp it asks for (its `tolerance_s` default).
pub const TOLERANCE_S: f64 = 1e-4;

/// Which features make the policy's observation and action.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Keys {
    pub state: String,
    pub action: String,
    /// Camera streams (video features), in the order the policy's encoder takes them.
    pub images: Vec<String>,
}

/// One episode's frames: `len` rows of each.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeFrames {
    pub index: i64,
    pub len: usize,
    pub tasks: Vec<String>,
    /// `len × state_dim`.
    pub state: Vec<f32>,
    /// `len × action_dim`.
    pub action: Vec<f32>,
    /// Per image key, `len` frames of `height × width × 3` bytes.
    pub images: Vec<Vec<u8>>,
    /// Each frame's `timestamp` column (seconds from the episode's start).
    pub timestamps: Vec<f64>,
}

/// What reading cost (the decoder's throughput is the part a user waits for, the cache the part that spares it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadReport {
    pub frames: usize,
    /// Video frames decoded, and the decoder's time for them: only files not taken from the cache, so that
    /// `decoded_frames / decode_s` stays the decoder's throughput.
    pub decoded_frames: usize,
    pub decode_s: f64,
    /// Video files decoded (every camera has files of its own; each is read once per read).
    pub decoded_files: usize,
    /// Video files whose frames came from the decoded-frame cache, their frames, and the time they took (opening,
    /// checking, and copying the frames out).
    pub cached_files: usize,
    pub cached_frames: usize,
    pub cache_read_s: f64,
    /// The time spent writing decoded frames to the cache for next time.
    pub cache_write_s: f64,
    /// Why the cache could not be used or written, when it could not (reading went on, decoding): each also a
    /// `tracing` warning.
    pub cache_warnings: Vec<String>,
    pub total_s: f64,
}

/// How to read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadOptions {
    /// Take decoded frames from the cache when it has them, and keep what is decoded there for next time.
    pub cache: bool,
    /// The cache's folder; `None`: [`cache::default_dir`] (`$MARS_CACHE_DIR`, else `$XDG_CACHE_HOME/mars/lerobot`,
    /// else `$HOME/.cache/mars/lerobot`).
    pub cache_dir: Option<PathBuf>,
}

impl Default for ReadOptions {
    /// The cache on, in its default folder.
    fn default() -> Self {
        Self { cache: true, cache_dir: None }
    }
}

impl ReadOptions {
    /// No cache: every video file decoded, nothing written.
    pub fn no_cache() -> Self {
        Self { cache: false, cache_dir: None }
    }

    /// The cache in `dir`.
    pub fn cache_in(dir: &Path) -> Self {
        Self { cache: true, cache_dir: Some(dir.to_owned()) }
    }
}

/// A video file's frames, decoded now or mapped from the cache.
enum Frames {
    Decoded(video::DecodedVideo),
    Cached(cache::CachedFrames),
}

impl Frames {
    fn times_s(&self) -> &[f64] {
        match self {
            Self::Decoded(v) => &v.times_s,
            Self::Cached(c) => &c.times_s,
        }
    }

    fn rgb(&self) -> &[u8] {
        match self {
            Self::Decoded(v) => &v.rgb,
            Self::Cached(c) => c.rgb(),
        }
    }
}

pub struct LeRobotDataset {
    pub root: PathBuf,
    pub info: Info,
    pub episodes: Vec<Episode>,
}

impl LeRobotDataset {
    /// Reads and checks the metadata; no data or video yet.
    pub fn open(root: &Path) -> Result<Self, LeRobotError> {
        let info = Info::load(root)?;
        let episodes = episodes::load(root, &info)?;
        Ok(Self { root: root.to_owned(), info, episodes })
    }

    /// The values per frame of a vector feature (float32 or float64, one dimension).
    pub fn vector_len(&self, key: &str) -> Result<usize, LeRobotError> {
        let f = self.info.feature(key)?;
        let bad = |problem: String| LeRobotError::Feature { key: key.to_owned(), problem };
        if !matches!(f.dtype.as_str(), "float32" | "float64") {
            return Err(bad(format!("dtype {}, not a float vector", f.dtype)));
        }
        if f.shape.len() != 1 || f.shape[0] == 0 {
            return Err(bad(format!("shape {:?}, not a vector of at least one value", f.shape)));
        }
        Ok(f.len())
    }

    /// A camera stream's (height, width) as the dataset stores it.
    pub fn image_size(&self, key: &str) -> Result<(u32, u32), LeRobotError> {
        let f: &Feature = self.info.feature(key)?;
        let bad = |problem: String| LeRobotError::Feature { key: key.to_owned(), problem };
        if f.dtype != "video" {
            return Err(bad(format!(
                "dtype {}: only camera streams stored as video are read (LeRobot's default)",
                f.dtype
            )));
        }
        let side = |n: usize| (1..=MAX_IMAGE_SIDE).contains(&n).then_some(n as u32);
        match f.shape[..] {
            [h, w, 3] => match (side(h), side(w)) {
                (Some(h), Some(w)) => Ok((h, w)),
                _ => Err(bad(format!("shape {:?}: images of 1 to {MAX_IMAGE_SIDE} pixels a side", f.shape))),
            },
            _ => Err(bad(format!("shape {:?}, not (height, width, 3)", f.shape))),
        }
    }

    /// Every episode's frames, images decoded to `height × width` (each video file decoded once), through the
    /// decoded-frame cache in its default folder ([`ReadOptions::default`]).
    pub fn read(&self, keys: &Keys, image_hw: (u32, u32)) -> Result<(Vec<EpisodeFrames>, ReadReport), LeRobotError> {
        self.read_with(keys, image_hw, &ReadOptions::default())
    }

    /// [`LeRobotDataset::read`] as `options` say.
    pub fn read_with(
        &self,
        keys: &Keys,
        image_hw: (u32, u32),
        options: &ReadOptions,
    ) -> Result<(Vec<EpisodeFrames>, ReadReport), LeRobotError> {
        let started = Instant::now();
        let (state_dim, action_dim) = (self.vector_len(&keys.state)?, self.vector_len(&keys.action)?);
        for k in &keys.images {
            self.image_size(k)?;
        }
        let mut out: Vec<EpisodeFrames> = self
            .episodes
            .iter()
            .map(|e| EpisodeFrames {
                index: e.index,
                len: e.length,
                tasks: e.tasks.clone(),
                // Sized once the data file shows the rows are there, not by what the metadata claims.
                state: Vec::new(),
                action: Vec::new(),
                images: Vec::with_capacity(keys.images.len()),
                timestamps: Vec::new(),
            })
            .collect();
        self.read_vectors(keys, state_dim, action_dim, &mut out)?;
        let mut report = ReadReport { frames: out.iter().map(|e| e.len).sum(), ..Default::default() };
        let cache =
            if options.cache && !keys.images.is_empty() { self.frame_cache(options, &mut report) } else { None };
        for key in &keys.images {
            self.read_images(key, image_hw, cache.as_ref(), &mut out, &mut report)?;
        }
        report.total_s = started.elapsed().as_secs_f64();
        Ok((out, report))
    }

    /// This dataset's folder in the cache, or `None` with a warning saying why not.
    fn frame_cache(&self, options: &ReadOptions, report: &mut ReadReport) -> Option<FrameCache> {
        let opened = options
            .cache_dir
            .clone()
            .or_else(cache::default_dir)
            .ok_or_else(|| "no folder for it: set MARS_CACHE_DIR, XDG_CACHE_HOME or HOME".to_owned())
            .and_then(|dir| FrameCache::open(&dir, &self.root));
        opened.map_err(|why| warn(report, format!("decoded-frame cache off for this read: {why}"))).ok()
    }

    /// A video file's frames at `height × width`: from the cache when it holds exactly these, else decoded (and
    /// then written to the cache for next time).
    fn video_frames(
        &self,
        path: &Path,
        (height, width): (u32, u32),
        cache: Option<&FrameCache>,
        report: &mut ReadReport,
    ) -> Result<Frames, LeRobotError> {
        let started = Instant::now();
        let rel = path.strip_prefix(&self.root).unwrap_or(path);
        let source = cache.and_then(|_| Source::of(&self.root, rel, (height, width)));
        if let (Some(c), Some(s)) = (cache, &source) {
            match c.load(s) {
                Ok(Some(frames)) => {
                    report.cached_files += 1;
                    report.cached_frames += frames.times_s.len();
                    report.cache_read_s += started.elapsed().as_secs_f64();
                    return Ok(Frames::Cached(frames));
                }
                Ok(None) => {}
                // Stale or damaged: decoded again and replaced below.
                Err(why) => tracing::info!("decoded-frame cache: {why}; decoding again"),
            }
        }
        let started = Instant::now();
        let video = video::decode(path, width, height)?;
        report.decode_s += started.elapsed().as_secs_f64();
        report.decoded_frames += video.times_s.len();
        report.decoded_files += 1;
        if let (Some(c), Some(s)) = (cache, source) {
            let started = Instant::now();
            // A file changed while it was decoded would be cached under the old file's facts: not cached then.
            if Source::of(&self.root, rel, (height, width)).as_ref() == Some(&s)
                && let Err(why) = c.store(&s, &video)
            {
                warn(report, why);
            }
            report.cache_write_s += started.elapsed().as_secs_f64();
        }
        Ok(Frames::Decoded(video))
    }

    fn data_path(&self, f: FileIndex) -> Result<PathBuf, LeRobotError> {
        self.info.file_path(&self.root, &self.info.data_path, None, f.chunk, f.file)
    }

    /// State, action and timestamps from the data files, each file read once.
    fn read_vectors(
        &self,
        keys: &Keys,
        state_dim: usize,
        action_dim: usize,
        out: &mut [EpisodeFrames],
    ) -> Result<(), LeRobotError> {
        let mut by_file: BTreeMap<FileIndex, Vec<usize>> = BTreeMap::new();
        for (i, e) in self.episodes.iter().enumerate() {
            by_file.entry(e.data).or_default().push(i);
        }
        let columns = ["episode_index", "frame_index", "timestamp", keys.state.as_str(), keys.action.as_str()];
        for (file, eps) in by_file {
            let path = self.data_path(file)?;
            let t = Table::read(&path, Some(&columns))?;
            let (episode, frame, time) = (t.i64s("episode_index")?, t.i64s("frame_index")?, t.f64s("timestamp")?);
            let (state, action) = (t.vectors(&keys.state, state_dim)?, t.vectors(&keys.action, action_dim)?);
            // Rows by (episode, frame): LeRobot writes them in order, but nothing in the format promises it.
            let mut rows: Vec<usize> = (0..t.rows()).collect();
            rows.sort_by_key(|&r| (episode[r], frame[r]));
            for i in eps {
                let e = &self.episodes[i];
                let first = rows.partition_point(|&r| episode[r] < e.index);
                let mine: Vec<usize> = rows[first..].iter().copied().take_while(|&r| episode[r] == e.index).collect();
                let bad = |problem: String| LeRobotError::Episode { episode: e.index, problem };
                if mine.len() != e.length {
                    return Err(bad(format!(
                        "{} rows in {}, its metadata says {}",
                        mine.len(),
                        path.display(),
                        e.length
                    )));
                }
                if let Some((k, &r)) = mine.iter().enumerate().find(|&(k, &r)| frame[r] != k as i64) {
                    return Err(bad(format!(
                        "frame_index {} where {k} was due (a missing or repeated frame)",
                        frame[r]
                    )));
                }
                let o = &mut out[i];
                o.state.reserve_exact(mine.len() * state_dim);
                o.action.reserve_exact(mine.len() * action_dim);
                o.timestamps.reserve_exact(mine.len());
                for &r in &mine {
                    o.state.extend_from_slice(&state[r * state_dim..(r + 1) * state_dim]);
                    o.action.extend_from_slice(&action[r * action_dim..(r + 1) * action_dim]);
                    o.timestamps.push(time[r]);
                }
            }
        }
        Ok(())
    }

    /// One camera's frames for every episode: each of its video files decoded once (or taken from the cache),
    /// each frame looked up by time (the episode's start in the file + the row's timestamp), as LeRobot's reader
    /// does.
    fn read_images(
        &self,
        key: &str,
        (height, width): (u32, u32),
        cache: Option<&FrameCache>,
        out: &mut [EpisodeFrames],
        report: &mut ReadReport,
    ) -> Result<(), LeRobotError> {
        let template = self.info.video_path.as_deref().ok_or_else(|| LeRobotError::Feature {
            key: key.to_owned(),
            problem: "a video feature, but meta/info.json has no video_path".into(),
        })?;
        let mut by_file: BTreeMap<FileIndex, Vec<usize>> = BTreeMap::new();
        for (i, e) in self.episodes.iter().enumerate() {
            let range = e.videos.get(key).ok_or_else(|| LeRobotError::Episode {
                episode: e.index,
                problem: format!("no video range for `{key}` in its metadata"),
            })?;
            by_file.entry(range.file).or_default().push(i);
        }
        let frame_len = height as usize * width as usize * 3;
        for (file, eps) in by_file {
            let path = self.info.file_path(&self.root, template, Some(key), file.chunk, file.file)?;
            let video = self.video_frames(&path, (height, width), cache, report)?;
            let copied = Instant::now();
            let (times, rgb) = (video.times_s(), video.rgb());
            let period = 1.0 / self.info.fps;
            let end_s = times.last().map_or(0.0, |t| t + period);
            for i in eps {
                let (e, o) = (&self.episodes[i], &mut out[i]);
                let range = e.videos[key];
                let bad = |problem: String| LeRobotError::Episode { episode: e.index, problem };
                if range.to_s > end_s + TOLERANCE_S {
                    return Err(bad(format!(
                        "`{key}` runs from {} s to {} s of {}, but the file ends at {end_s:.4} s ({} frames): \
                         the range falls outside its file (truncated video?)",
                        range.from_s,
                        range.to_s,
                        path.display(),
                        times.len()
                    )));
                }
                let mut frames = Vec::with_capacity(e.length * frame_len);
                for (t, ts) in o.timestamps.iter().enumerate() {
                    let at = range.from_s + ts;
                    let j = video::frame_at(times, at, TOLERANCE_S).map_err(|nearest| {
                        bad(format!(
                            "`{key}` frame {t} is due at {at:.4} s of {}; the nearest frame there is at {nearest:.4} s",
                            path.display()
                        ))
                    })?;
                    frames.extend_from_slice(&rgb[j * frame_len..(j + 1) * frame_len]);
                }
                o.images.push(frames);
            }
            if matches!(video, Frames::Cached(_)) {
                report.cache_read_s += copied.elapsed().as_secs_f64();
            }
        }
        Ok(())
    }
}

/// A cache problem: said in the report and as a warning, never an error (reading goes on, decoding).
fn warn(report: &mut ReadReport, why: String) {
    tracing::warn!("{why}");
    report.cache_warnings.push(why);
}
