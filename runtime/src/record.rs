//! Recording a run as a LeRobot v3.0 dataset (`marsd --record DIR`), without the real-time loops ever waiting
//! on it.
//!
//! The policy loop fills one preallocated frame per policy period (what the policy saw, the action in force, our
//! own columns) and hands it to the writer thread through a wait-free ring; an empty frame comes back through a
//! second ring. No frame free (the writer fell behind): the period is dropped and counted, the loop goes on.
//! The writer thread gathers each episode, writes it only if it has every period (a dataset's frames are
//! `1 / fps` apart: a gap would put every later frame at the wrong time), and counts the episodes it had to
//! leave out. At the end it finishes the dataset (it appears at its path in one rename).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use mars_lerobot::writer::{CameraSpec, DatasetSpec, DatasetWriter, VectorSpec};
use serde::Serialize;

/// Frames in flight between the loop and the writer: 2 s at 10 Hz (the writer encodes video; a 1 s stall of it
/// costs nothing).
pub const POOL_FRAMES: usize = 20;

/// One policy period.
#[derive(Debug, Clone, Default)]
pub struct RecordFrame {
    pub episode: u64,
    /// The period's index in its episode.
    pub frame: u64,
    /// The observation's state part as the policy saw it (no image).
    pub state: Vec<f32>,
    /// The action in force in this period (the current chunk's).
    pub action: Vec<f32>,
    /// The camera's RGB8 frame, when the task has one.
    pub image: Vec<u8>,
    /// Our columns, per chunk: ‖w‖∞, K requested and used, inference and encode time (ms), and 1.0 on the
    /// period the policy was called in.
    pub w_inf: f32,
    pub k: [f32; 2],
    pub latency_ms: [f32; 2],
    pub call: f32,
    /// The HAL's word on the period's state frame: its status bits, fault bits and hold reason
    /// (`mars_ipc::status`, `mars_ipc::fault`, `HoldReason`; whole numbers, exact in float32).
    pub hal: [f32; 3],
    /// When the HAL stamped the state frame, from the episode's start (s): the period's state is the robot's
    /// at this time, which the loop's wake-up moves by a few ms (what `mars-hil replay` aligns on).
    pub state_time_s: f32,
}

/// How an episode ended, sent when it does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeEnd {
    pub episode: u64,
    /// Periods the loop recorded (or tried to): the writer must have all of them.
    pub frames: u64,
    pub success: bool,
    /// The grasp (or approach) the episode took, by the task's monitor, if it took one.
    pub mode: Option<usize>,
    /// The action history's padding before the first chunk (`rest[..rest_len]`): replay starts from it.
    pub rest: [f32; crate::servo::chunk::MAX_ACTION],
    pub rest_len: usize,
}

/// The file of our own in the dataset's `meta/`: the run's seed, checkpoint and, per dataset episode, marsd's
/// episode number and its history padding — with the recorded frames, what `marsd replay` needs.
pub const META_FILE: &str = "mars.json";

/// The seed of the policy's noise for the call made in period `frame` of `episode`: marsd reseeds the engine
/// before every call, so one call can be replayed without the ones before it.
pub fn call_seed(run_seed: u64, episode: u64, frame: u64) -> u64 {
    // splitmix64's finaliser over the three, so nearby calls get unrelated streams.
    let mut z = run_seed ^ episode.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ frame.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// What the recording did, for the report.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct RecordReport {
    pub path: PathBuf,
    pub episodes_written: u64,
    pub frames_written: u64,
    /// Periods the loop could not hand over (no free frame: the writer behind).
    pub frames_dropped: u64,
    /// Episodes left out because a period was dropped or the run stopped inside them.
    pub episodes_incomplete: u64,
    /// The error that stopped the writer, if any (the run itself goes on).
    pub error: Option<String>,
}

/// What the dataset holds: sizes, names, the task in words.
#[derive(Debug, Clone)]
pub struct RecordSetup {
    pub path: PathBuf,
    pub fps: u32,
    pub robot_type: String,
    pub task: String,
    pub state_names: Vec<String>,
    pub action_names: Vec<String>,
    /// (key, height, width) of the camera, if any.
    pub camera: Option<(String, u32, u32)>,
    /// Fault injection: the writer sleeps this long per frame (a disk or encoder that cannot keep up).
    pub writer_delay: Duration,
    /// The run's seed, checkpoint and configuration file, for `meta/mars.json`.
    pub seed: u64,
    pub checkpoint: PathBuf,
    pub config: PathBuf,
}

/// The policy loop's end: wait-free, allocation-free after `start`.
pub struct Recorder {
    free: rtrb::Consumer<Box<RecordFrame>>,
    filled: rtrb::Producer<Box<RecordFrame>>,
    ends: rtrb::Producer<EpisodeEnd>,
    dropped: Arc<AtomicU64>,
}

impl Recorder {
    /// Hands over one period, filled by `fill` in a preallocated frame; false if it was dropped (no frame free).
    pub fn record(&mut self, fill: impl FnOnce(&mut RecordFrame)) -> bool {
        let Ok(mut f) = self.free.pop() else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        };
        fill(&mut f);
        // Never full: the ring holds as many frames as exist.
        if self.filled.push(f).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        true
    }

    /// The episode ended after `frames` periods. (If even this small ring is full the episode reads as
    /// incomplete and is left out.)
    pub fn end_episode(&mut self, end: EpisodeEnd) {
        let _ = self.ends.push(end);
    }
}

/// The writer thread's handle: `finish` stops it once it has drained everything and returns the report.
pub struct RecordWriter {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<RecordReport>,
}

/// Creates the dataset (refused if `path` exists: a recording never overwrites) and starts the writer thread.
pub fn start(setup: RecordSetup) -> anyhow::Result<(Recorder, RecordWriter)> {
    let mut spec = DatasetSpec {
        fps: setup.fps,
        robot_type: setup.robot_type.clone(),
        vectors: vec![
            VectorSpec { key: "observation.state".into(), names: setup.state_names.clone() },
            VectorSpec { key: "action".into(), names: setup.action_names.clone() },
        ],
        cameras: Vec::new(),
    };
    let ours: [(&str, &[&str]); 6] = [
        ("mars.w_inf", &["w_inf"]),
        ("mars.k", &["requested", "used"]),
        ("mars.latency_ms", &["inference", "encode"]),
        ("mars.call", &["call"]),
        ("mars.hal", &["status_bits", "fault_bits", "hold_reason"]),
        ("mars.state_time_s", &["s"]),
    ];
    spec.vectors.extend(
        ours.iter().map(|(k, n)| VectorSpec { key: (*k).into(), names: n.iter().map(|s| (*s).to_owned()).collect() }),
    );
    let image_len = setup.camera.as_ref().map_or(0, |(_, h, w)| (h * w * 3) as usize);
    if let Some((key, height, width)) = &setup.camera {
        spec.cameras.push(CameraSpec { key: key.clone(), height: *height, width: *width });
    }
    let (mut free_in, free_out) = rtrb::RingBuffer::new(POOL_FRAMES);
    let (filled_in, filled_out) = rtrb::RingBuffer::new(POOL_FRAMES);
    let (ends_in, ends_out) = rtrb::RingBuffer::new(64);
    for _ in 0..POOL_FRAMES {
        let f = RecordFrame {
            state: vec![0.0; setup.state_names.len()],
            action: vec![0.0; setup.action_names.len()],
            image: vec![0; image_len],
            ..Default::default()
        };
        free_in.push(Box::new(f)).expect("the ring holds the pool");
    }
    let dropped = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let dropped2 = dropped.clone();
    // The writer is made on its own thread (FFmpeg's contexts stay on the thread that made them); whether it
    // could be made comes back before `start` returns, so a path that exists stops marsd before anything moves.
    let (made_tx, made_rx) = std::sync::mpsc::channel();
    let thread = std::thread::Builder::new().name("marsd-record".into()).spawn(move || {
        let writer = match DatasetWriter::create(&setup.path, spec) {
            Ok(w) => {
                let _ = made_tx.send(Ok(()));
                w
            }
            Err(e) => {
                let _ = made_tx.send(Err(e));
                return RecordReport { error: Some("not started".into()), ..Default::default() };
            }
        };
        let job = Job {
            setup,
            writer,
            free: free_in,
            filled: filled_out,
            ends: ends_out,
            dropped: dropped2,
            arrived: Vec::new(),
            meta_episodes: Vec::new(),
            report: RecordReport::default(),
        };
        job.run(&stop2)
    })?;
    made_rx.recv().map_err(|_| anyhow::anyhow!("the recording thread died at start"))??;
    Ok((Recorder { free: free_out, filled: filled_in, ends: ends_in, dropped }, RecordWriter { stop, thread }))
}

impl RecordWriter {
    pub fn finish(self) -> RecordReport {
        self.stop.store(true, Ordering::Release);
        self.thread.join().unwrap_or_else(|_| RecordReport {
            error: Some("the recording thread panicked".into()),
            ..Default::default()
        })
    }
}

struct Job {
    setup: RecordSetup,
    writer: DatasetWriter,
    free: rtrb::Producer<Box<RecordFrame>>,
    filled: rtrb::Consumer<Box<RecordFrame>>,
    ends: rtrb::Consumer<EpisodeEnd>,
    dropped: Arc<AtomicU64>,
    /// Ends received whose episode is not closed yet.
    arrived: Vec<EpisodeEnd>,
    /// Per written episode, what `meta/mars.json` keeps of it.
    meta_episodes: Vec<serde_json::Value>,
    /// `error` set: writing failed, nothing more is written.
    report: RecordReport,
}

/// The episode being gathered (the writer thread may allocate: it is not a real-time thread).
struct Gathering {
    episode: u64,
    frames: Vec<RecordFrame>,
    /// A period's number was skipped.
    gap: bool,
}

impl Job {
    fn run(mut self, stop: &AtomicBool) -> RecordReport {
        self.report.path = self.setup.path.clone();
        let mut open: Option<Gathering> = None;
        loop {
            // Read the stop flag before draining: everything pushed before it was set is then seen.
            let stopping = stop.load(Ordering::Acquire);
            while let Ok(end) = self.ends.pop() {
                self.arrived.push(end);
            }
            let mut got = false;
            while let Ok(f) = self.filled.pop() {
                got = true;
                if !self.setup.writer_delay.is_zero() {
                    std::thread::sleep(self.setup.writer_delay);
                }
                if let Some(done) = open.take_if(|g| g.episode != f.episode) {
                    self.close(done);
                }
                let g = open.get_or_insert_with(|| Gathering { episode: f.episode, frames: Vec::new(), gap: false });
                g.gap |= f.frame != g.frames.len() as u64;
                g.frames.push((*f).clone());
                // Back to the loop's pool.
                let _ = self.free.push(f);
            }
            // An episode whose end has arrived and whose frames are all here is written now, not at the next one.
            let arrived = &self.arrived;
            if let Some(done) =
                open.take_if(|g| arrived.iter().any(|e| e.episode == g.episode && e.frames <= g.frames.len() as u64))
            {
                self.close(done);
            }
            if stopping && !got {
                break;
            }
            if !got {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        if let Some(g) = open.take() {
            self.close(g);
        }
        let mut report = std::mem::take(&mut self.report);
        report.frames_dropped = self.dropped.load(Ordering::Relaxed);
        if report.error.is_none() && report.episodes_written > 0 {
            let meta = serde_json::json!({
                "seed": self.setup.seed,
                "checkpoint": self.setup.checkpoint,
                "config": self.setup.config,
                "fps": self.setup.fps,
                "episodes": self.meta_episodes,
            });
            self.writer.set_extra_meta(META_FILE, meta);
            if let Err(e) = self.writer.finish() {
                report.error = Some(e.to_string());
            }
        } else if report.episodes_written == 0 {
            self.writer.abandon();
            report.error.get_or_insert_with(|| "no complete episode: nothing written".into());
        }
        report
    }

    /// Writes a gathered episode if it is complete (its end seen, every period there) and writing has not failed,
    /// else counts it.
    fn close(&mut self, g: Gathering) {
        let end = self.arrived.iter().position(|e| e.episode == g.episode).map(|i| self.arrived.remove(i));
        let complete = !g.gap && end.is_some_and(|e| e.frames == g.frames.len() as u64) && !g.frames.is_empty();
        let report = &mut self.report;
        if !complete || report.error.is_some() {
            report.episodes_incomplete += 1;
            return;
        }
        let written = g.frames.iter().try_for_each(|f| {
            let vectors: [&[f32]; 8] =
                [&f.state, &f.action, &[f.w_inf], &f.k, &f.latency_ms, &[f.call], &f.hal, &[f.state_time_s]];
            let images: Vec<&[u8]> = if f.image.is_empty() { vec![] } else { vec![&f.image] };
            self.writer.add_frame(&vectors, &images)
        });
        match written.and_then(|()| self.writer.end_episode(&self.setup.task)) {
            Ok(()) => {
                let end = end.expect("a complete episode has its end");
                self.meta_episodes.push(serde_json::json!({
                    "marsd_episode": end.episode,
                    "success": end.success,
                    "mode": end.mode,
                    "rest": &end.rest[..end.rest_len],
                }));
                report.episodes_written += 1;
                report.frames_written += g.frames.len() as u64;
            }
            Err(e) => {
                tracing::error!("recording {}: {e}; nothing more is recorded", self.setup.path.display());
                report.error = Some(e.to_string());
            }
        }
    }
}
