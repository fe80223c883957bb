//! The policy thread: the episodes ([`PolicyLoop`]), each chunk inferred by the engine or replayed from a recording
//! ([`recorded_actions`]), the results kept in bounded memory ([`tally`]).
//!
//! The policy loop: runs the episodes. For each: ask the servo to move to the start pose, then, once per policy
//! period, watch the task's progress and — every `chunk_len` periods — build the observation and the history of
//! the last `chunk_len` actions, call the engine with the time left until the servo needs the chunk, stamp the
//! chunk's actions with their due times and hand it over without locks.
//!
//! Timing of chunk n (Δ = policy period, C = chunk length, t0 = episode start, lead = inference budget):
//! inference starts at t0 + n·C·Δ, the chunk is needed at that time + lead (when the servo starts moving
//! toward its first action), and its action i is due at t0 + lead + (n·C + i + 1)·Δ. So the next inference
//! overlaps the execution of the current chunk, and a chunk one lead late costs nothing but smoothness.
//!
//! Asked a periods ahead (`[policy] ask_ahead_periods`, for an inference host whose round trip is over the lead):
//! chunks are asked every S = C − a periods, at k = n·S; the chunk is needed a periods later than above, its first
//! a rows are due while the previous chunk is still executing (they are committed: the call is guided toward them,
//! `Engine::infer_after`), and rows a..C are handed over, due from t0 + lead + (k + a + 1)·Δ on.

pub mod handover;
pub mod recorded_actions;
pub mod remote;
pub mod tally;
pub mod timeline;

use std::ops::RangeInclusive;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use mars_engine::Engine;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::{MAX_JOINTS, SceneAction, ScenePhase};
use serde::Serialize;

use crate::config::Continuity;
use crate::config::DaemonConfig;
use crate::observe::scene_link::SceneLink;
use crate::policy::remote::{Ask, Settled};
use crate::policy::timeline::Timeline;
use crate::report::latency::{Channel, Recorder};
use crate::report::plots::EpisodeTrace;
use crate::report::traces::{TRACE_CAPACITY, TraceRing};
use crate::rt::Ticker;
use crate::servo::chunk::TimedChunk;
use crate::servo::watchdog::{Streak, Trip};
use crate::shared::{Observed, Phase, Request, Status};
use crate::task::pick::{DoneReason, EpisodeMonitor, Progress};
use crate::task::{HilTask, PushTHil};

pub use crate::policy::tally::EpisodeResult;

/// How many late chunks a report times.
pub const LATE_CHUNKS_KEPT: usize = 16;

/// A chunk ready after the servo needed it (CLOCK_MONOTONIC ns, the HAL's frame clock).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LateChunk {
    /// When the policy loop woke to compute it (observation, then inference).
    pub woke_ns: u64,
    /// When the servo needed it.
    pub need_ns: u64,
    /// When it was ready.
    pub ready_ns: u64,
}

/// Totals of the policy loop.
#[derive(Debug, Clone, Default, Serialize)]
pub struct PolicyReport {
    /// Totals over every episode, and the last `traces_kept` results.
    pub episodes: crate::policy::tally::EpisodeTally,
    /// The last `traces_kept` episodes' traces, oldest first.
    #[serde(skip)]
    pub traces: Vec<EpisodeTrace>,
    /// Traces dropped because only the last `traces_kept` are kept.
    pub traces_dropped: u64,
    pub inferences: u64,
    /// Calls whose K was cut by the deadline (k_used < k_requested).
    pub capped: u64,
    /// Chunks ready after the servo needed them.
    pub late_chunks: u64,
    /// Policy periods the loop slept through (a stall of its thread or of the machine): skipped, not caught up.
    pub policy_missed_periods: u64,
    /// The first [`LATE_CHUNKS_KEPT`] of them, timed: what a stall of the machine must cover to explain each.
    pub late_chunk_times: Vec<LateChunk>,
    /// Calls that could not fit even K = 1; their chunks were dropped.
    pub over_budget: u64,
    pub engine_errors: u64,
    /// Push-T: the camera's frames as the policy judged them (used, superseded, refused by reason), and the
    /// chunks skipped because no usable frame was there.
    pub camera: Option<CameraReport>,
    /// `[remote]`: the chunks the inference host computed, those the local engine took over, and why.
    pub remote: Option<crate::policy::remote::RemoteReport>,
    /// The policy's actions across each chunk handover, before the servo's smoothing.
    pub handover_jerk: crate::policy::handover::HandoverJerk,
}

/// The camera as the policy loop saw it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct CameraReport {
    pub service: String,
    pub counts: crate::observe::camera::CameraCounts,
    /// Inferences skipped for want of a usable frame (the previous chunk kept).
    pub no_frame: u64,
    /// The first refusal, in words.
    pub first_refusal: Option<String>,
}

pub struct PolicyChannels {
    pub chunks: triple_buffer::Input<TimedChunk>,
    pub observed: triple_buffer::Output<Observed>,
    /// Producer end; the servo thread consumes (see [`crate::shared`]).
    pub requests: rtrb::Producer<Request>,
    pub status: Arc<Status>,
}

/// The watchdog's streaks of the policy loop, across episodes.
struct ChunkFaults {
    /// Chunks ready after the servo needed them.
    late: Streak,
    /// Calls that could not fit even one ODE step.
    over: Streak,
    /// Inferences with no usable camera frame.
    no_frame: Streak,
}

/// How an episode's end is judged.
enum Judge {
    /// Pick Cup: the measured arm reached a grasp, then the retreat.
    Arm(EpisodeMonitor),
    /// Push-T: the scene's referee saw the block home (its frames), or time ran out.
    Scene { timeout_s: f64, silent_limit_ns: u64 },
}

pub struct PolicyLoop {
    pub engine: Engine,
    pub task: HilTask,
    pub ch: PolicyChannels,
    pub rec: Recorder,
    /// Push-T: the camera and the scene (opened on this thread).
    pub scene: Option<SceneLink>,
    /// When the recorder's interval ends (0: at the first inference), so the live view and the interval log see
    /// the policy's channels while the run goes on, not only at its end.
    pub next_interval_ns: u64,
    /// `--record`: every policy period handed to the dataset writer (wait-free; dropped and counted if it lags).
    pub recording: Option<crate::record::Recorder>,
    /// While recording Push-T: the camera frame the last observation used (sized at the first episode).
    pub last_image: Vec<u8>,
    /// While recording Push-T: the camera's newest frame at this period (the recording's own view of it), what a
    /// period without a call records.
    pub view_image: Vec<u8>,
    /// `--replay-actions`: a recorded episode's chunks instead of the engine's (see [`crate::policy::recorded_actions`]).
    pub replay: Option<crate::policy::recorded_actions::RecordedActions>,
    /// `[remote]`: the inference host asked first for every chunk (see [`crate::policy::remote`]).
    pub remote: Option<crate::policy::remote::Remote>,
}

/// Where and when a chunk's actions are due, and when it was made (see [`TimedChunk`]).
struct ChunkStamp {
    episode: u64,
    seq: u64,
    period_ns: u64,
    first_due_ns: u64,
    ready_ns: u64,
    capture_ns: u64,
}

/// What the recording keeps of the chunk in force: its actions, where it started, our columns.
struct InForce {
    actions: Vec<f32>,
    /// The period the chunk's first action belongs to.
    first_k: u64,
    w_inf: f32,
    k: [f32; 2],
    latency_ms: [f32; 2],
    /// The camera frame the chunk was computed from (Push-T), RGB8.
    image: Vec<u8>,
}

/// One episode's state, carried from one policy period to the next.
struct EpisodeRun {
    episode: u64,
    /// When the episode started (CLOCK_MONOTONIC ns): period k is due at t0 + k periods.
    t0: u64,
    /// Actions per chunk, and numbers per action.
    c: usize,
    d: usize,
    period_ns: u64,
    /// The engine's observation input, written by each call's observation.
    obs: Vec<f32>,
    /// The engine's history input: the C actions due before the chunk asked (at the start, the rest pose).
    history: Vec<f32>,
    /// Chunks are asked every `stride` = C − `ahead` periods (`[policy] ask_ahead_periods`); the next at
    /// `next_ask`.
    ahead: usize,
    stride: usize,
    next_ask: u64,
    /// The first `ahead` rows of the chunk asked: the previous chunk's, due before this one is handed over.
    committed: Vec<f32>,
    /// Every action handed over, by the period it is due in.
    timeline: Timeline,
    /// Four rows around a handover, read from the timeline.
    around_handover: Vec<f32>,
    /// The last call's chunk (C·D), the engine's or the host's.
    chunk_out: Vec<f32>,
    /// The call whose request is with the inference host (its inputs stay in `obs`, `history`, `committed`).
    in_flight: Option<InFlightCall>,
    /// The recording's state column.
    state: Vec<f32>,
    /// A replay's chunk (empty unless replaying).
    replayed: Vec<f32>,
    in_force: InForce,
    trace: crate::report::plots::EpisodeTrace,
    /// Chunks published this episode (`seq` of the last), the sum of their K, how many were late.
    seq: u64,
    chunks: u64,
    k_sum: u64,
    late: u64,
    /// max |w| of the last call, traced with the arm's position.
    w_inf: f32,
    missed_at_start: u64,
}

impl EpisodeRun {
    /// When the chunk asked in period `k` must be ready: the lead before its first handed-over action.
    fn need_ns(&self, cfg: &DaemonConfig, k: u64) -> u64 {
        self.t0 + (cfg.policy.lead_ms * 1e6) as u64 + (k + self.ahead as u64) * self.period_ns
    }

    /// The committed rows a call is guided toward: none when the chunk drops them instead.
    fn committed_for(&self, continuity: Continuity) -> &[f32] {
        match continuity {
            Continuity::Guided => &self.committed,
            Continuity::DropLate => &[],
        }
    }

    /// The arm's measured position (and the last call's max |w|) into the plots' trace, while it has room.
    fn trace_position(&mut self, o: &Observed, n: usize) {
        if self.trace.q.len() < TRACE_CAPACITY {
            let mut q = [0.0; MAX_JOINTS];
            q[..n].copy_from_slice(&o.position[..n]);
            self.trace.q.push(q);
            self.trace.w_inf.push(self.w_inf);
        }
    }
}

/// A call whose chunk is not published yet: what publishing it needs.
#[derive(Clone, Copy)]
struct InFlightCall {
    call: Call,
    seed: u64,
    started_ns: u64,
    handoff_ns: u64,
}

/// One engine call of an episode: the period it is made in, when it woke, when its chunk is needed, and the
/// capture time of the observation it sees (its camera frame's, or its state frame's).
#[derive(Clone, Copy)]
struct Call {
    k: u64,
    now: u64,
    need_ns: u64,
    capture_ns: u64,
}

impl PolicyLoop {
    pub fn run(mut self, cfg: &DaemonConfig) -> PolicyReport {
        let mut report = PolicyReport {
            episodes: crate::policy::tally::EpisodeTally::new(self.task.mode_names().len(), cfg.traces_kept),
            late_chunk_times: Vec::with_capacity(LATE_CHUNKS_KEPT),
            ..Default::default()
        };
        let episodes = if cfg.episodes == 0 { u64::MAX } else { cfg.episodes as u64 };
        if !self.wait_for(|s| s.hal_ready.load(Ordering::Acquire)) {
            return report;
        }
        let mut faults = ChunkFaults {
            late: Streak::new(cfg.watchdog.max_consecutive_late_chunks),
            over: Streak::new(cfg.watchdog.max_consecutive_over_budget),
            no_frame: Streak::new(cfg.watchdog.max_consecutive_late_chunks),
        };
        let mut traces = TraceRing::new(cfg.traces_kept);
        // A replay runs the recorded episode alone, under its own number (its start pose comes from it).
        let numbers = match &self.replay {
            Some(r) => r.marsd_episode..=r.marsd_episode,
            None => 1..=episodes,
        };
        for episode in numbers {
            let seed = cfg.seed.wrapping_add(episode);
            let Some((pose_v, gripper, rest)) = self.set_up(episode, seed) else { break };
            let mut pose = [0.0; MAX_JOINTS];
            pose[..pose_v.len()].copy_from_slice(&pose_v);
            if !self.request(Request::MoveTo { episode, pose, gripper }) {
                break;
            }
            if !self.wait_for(|s| s.phase() == Phase::Ready && s.episode.load(Ordering::Acquire) == episode) {
                break;
            }
            if !self.start_scene(episode) {
                break;
            }
            match self.episode(cfg, episode, &rest, &mut faults, &mut traces, &mut report) {
                Some(result) => report.episodes.add(result),
                None => break,
            }
        }
        self.request(Request::Finish);
        report.traces_dropped = traces.dropped();
        report.traces = traces.into_vec();
        if let Some(s) = &self.scene {
            let c = report.camera.get_or_insert_with(CameraReport::default);
            c.service = s.camera.service().to_owned();
            c.counts = s.camera.check.counts;
        }
        report.remote = self.remote.take().map(crate::policy::remote::Remote::finish);
        report
    }

    /// The episode's start: the joint pose to move to, the gripper width, and the action history's padding.
    /// Push-T first has the scene reset the block (`None`: it did not answer, tripped; or the loop must stop).
    fn set_up(&mut self, episode: u64, seed: u64) -> Option<(Vec<f64>, f64, Vec<f32>)> {
        match &self.task {
            HilTask::Pick(t) => {
                let pose = t.start_pose(seed);
                let rest = t.rest_action(&pose);
                Some((pose, t.cfg.gripper_open, rest))
            }
            HilTask::PushT(t) => {
                let (pose, rest, timeout) = (t.start_pose.clone(), t.rest_action(), t.cfg.scene_timeout_s);
                self.ask_scene(SceneAction::Reset, episode, seed, ScenePhase::Reset, timeout)?;
                // The pusher is the flange: the gripper stays as it is.
                Some((pose, self.ch.observed.read().gripper, rest))
            }
        }
    }

    /// Push-T: at the start pose, the scene puts the pusher down and the episode begins. True for other tasks.
    fn start_scene(&mut self, episode: u64) -> bool {
        match &self.task {
            HilTask::PushT(t) => {
                let timeout = t.cfg.scene_timeout_s;
                self.ask_scene(SceneAction::Run, episode, 0, ScenePhase::Running, timeout).is_some()
            }
            HilTask::Pick(_) => true,
        }
    }

    /// Sends `action` to the scene until it reports `phase` for `episode` (a request sent before the scene's
    /// subscriber connected is lost, so it is repeated every 100 ms); trips [`Trip::SceneLost`] after `timeout_s`.
    fn ask_scene(
        &mut self,
        action: SceneAction,
        episode: u64,
        seed: u64,
        phase: ScenePhase,
        timeout_s: f64,
    ) -> Option<()> {
        let deadline = monotonic_ns() + (timeout_s * 1e9) as u64;
        let mut next_ask = 0;
        loop {
            let scene = self.scene.as_mut().expect("a Push-T task has its scene opened");
            let now = monotonic_ns();
            if now >= next_ask {
                scene.request(action, episode, seed);
                next_ask = now + 100_000_000;
            }
            if scene.is(episode, phase) {
                return Some(());
            }
            if now >= deadline {
                tracing::error!("the scene did not answer {action:?} for episode {episode} within {timeout_s} s");
                self.request(Request::Trip(Trip::SceneLost));
                return None;
            }
            if self.must_stop() {
                return None;
            }
            self.ch.status.policy_beats.fetch_add(1, Ordering::Relaxed);
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Runs one episode from the start pose; `None` if the loop must stop (signal or trip).
    fn episode(
        &mut self,
        cfg: &DaemonConfig,
        episode: u64,
        rest: &[f32],
        faults: &mut ChunkFaults,
        traces: &mut TraceRing,
        report: &mut PolicyReport,
    ) -> Option<EpisodeResult> {
        let mut judge = self.judge();
        let n = self.engine_joints();
        let mut run = self.start_episode(cfg, episode, rest, traces);
        let mut ticker = Ticker::starting_at(run.t0, Duration::from_nanos(run.period_ns));
        loop {
            let wake = ticker.wait();
            self.ch.status.policy_beats.fetch_add(1, Ordering::Relaxed);
            if self.must_stop() {
                return None;
            }
            // The period by the clock, not by wakes counted: after a stall the Ticker skipped periods, and a count
            // would put every later deadline that many periods early (calls over budget or late, then a trip).
            let k = (wake.deadline_ns - run.t0) / run.period_ns;
            report.policy_missed_periods += wake.missed;
            self.inject_stall(cfg, episode, k);
            let now = wake.now_ns();
            let o = *self.ch.observed.read();
            let t_s = (now - run.t0) as f64 * 1e-9;
            let progress = match &mut judge {
                Judge::Arm(m) => m.update(&o.position[..n], o.gripper, t_s),
                Judge::Scene { timeout_s, silent_limit_ns } => {
                    self.scene_progress(episode, t_s, *timeout_s, *silent_limit_ns)?
                }
            };
            run.trace_position(&o, n);
            if let Progress::Done { success, mode, reason } = progress {
                if run.in_flight.take().is_some() {
                    self.remote.as_mut().expect("a call in flight has a host").abandon();
                }
                self.end_recorded_episode(episode, k, success, mode, rest);
                return Some(self.end_episode(run, now, success, mode, reason, traces));
            }
            if self.recording.is_some() {
                self.state_of(&o, &mut run.state);
                if let Some(scene) = self.scene.as_mut() {
                    scene.newest_for_recording(&mut self.view_image);
                }
            }
            if run.in_flight.is_some() {
                let next_period_ns = run.t0 + (k + 1) * run.period_ns;
                self.settle_chunk(cfg, &mut run, next_period_ns, &o, faults, report)?;
            }
            if self.replay.is_some() {
                self.replay_periods(cfg, &mut run, k - wake.missed..=k, &o);
                continue;
            }
            // A chunk is asked every `stride` periods, or at the first wake after a stall that slept through that.
            if k < run.next_ask {
                self.record_period(&run, k, false, &o);
                continue;
            }
            run.next_ask = k + run.stride as u64;
            let need_ns = run.need_ns(cfg, k);
            let capture_ns = match self.observe(&o, &mut run.obs, &mut run.trace, report) {
                Ok(c) => {
                    faults.no_frame.good();
                    c
                }
                Err(()) => {
                    // No usable image: keep executing the previous chunk, as for a call over budget.
                    self.record_period(&run, k, false, &o);
                    self.trip_if(faults.no_frame.bad(), Trip::NoCameraFrame)?;
                    continue;
                }
            };
            let call = Call { k, now, need_ns, capture_ns };
            self.infer_chunk(cfg, &mut run, call, &o, faults, report)?;
        }
    }

    /// `[faults] policy_stall_ms`: the loop sleeps once, in the configured period of episode 1 (marsd's first).
    fn inject_stall(&self, cfg: &DaemonConfig, episode: u64, k: u64) {
        let (stall, at) = cfg.policy_stall();
        if episode == 1 && k == at && !stall.is_zero() {
            std::thread::sleep(stall);
        }
    }

    /// How this task's episodes end.
    fn judge(&self) -> Judge {
        match &self.task {
            HilTask::Pick(t) => Judge::Arm(t.monitor()),
            HilTask::PushT(t) => {
                Judge::Scene { timeout_s: t.cfg.timeout_s, silent_limit_ns: (t.cfg.scene_timeout_s * 1e9) as u64 }
            }
        }
    }

    /// An episode's state at its start: the rest pose as the chunk in force, nothing called yet.
    fn start_episode(&mut self, cfg: &DaemonConfig, episode: u64, rest: &[f32], traces: &mut TraceRing) -> EpisodeRun {
        let (c, d) = (self.engine.chunk_len(), self.engine.action_dim());
        let history: Vec<f32> = rest.iter().copied().cycle().take(c * d).collect();
        let ahead = cfg.policy.ask_ahead_periods;
        let in_force = InForce {
            actions: history.clone(),
            first_k: 0,
            w_inf: 0.0,
            k: [0.0; 2],
            latency_ms: [0.0; 2],
            image: vec![0; self.image_len()],
        };
        if self.recording.is_some() && self.last_image.len() != self.image_len() {
            self.last_image = vec![0; self.image_len()];
            self.view_image = vec![0; self.image_len()];
        }
        let trace = traces.start();
        let t0 = monotonic_ns();
        EpisodeRun {
            episode,
            t0,
            c,
            d,
            period_ns: cfg.policy_period_ns(),
            obs: vec![0.0; self.engine.obs_dim()],
            history,
            ahead,
            stride: c - ahead,
            next_ask: 0,
            committed: vec![0.0; ahead * d],
            timeline: Timeline::new(&rest[..d], 2 * c),
            around_handover: vec![0.0; 4 * d],
            chunk_out: vec![0.0; c * d],
            in_flight: None,
            state: vec![0.0; self.state_dim()],
            replayed: vec![0.0; if self.replay.is_some() { c * d } else { 0 }],
            in_force,
            trace,
            seq: 0,
            chunks: 0,
            k_sum: 0,
            late: 0,
            w_inf: 0.0,
            missed_at_start: self.ch.status.missed_periods.load(Ordering::Relaxed),
        }
    }

    /// The episode's result, its trace kept for the plots.
    fn end_episode(
        &mut self,
        mut run: EpisodeRun,
        now: u64,
        success: bool,
        mode: Option<usize>,
        reason: DoneReason,
        traces: &mut TraceRing,
    ) -> EpisodeResult {
        run.trace.mode = mode;
        run.trace.success = success;
        // The scene as the episode ended, for the camera strip (the policy's last view can be 0.8 s older).
        if let Some(frame) = self.scene.as_mut().and_then(|s| s.camera.newest_for_display()) {
            run.trace.keep_frame(frame.pixels());
        }
        traces.push(run.trace);
        let missed = self.ch.status.missed_periods.load(Ordering::Relaxed);
        EpisodeResult {
            episode: run.episode,
            success,
            mode,
            reason: Some(reason),
            duration_s: (now - run.t0) as f64 * 1e-9,
            chunks: run.chunks,
            mean_k_used: if run.chunks > 0 { run.k_sum as f64 / run.chunks as f64 } else { 0.0 },
            late_chunks: run.late,
            servo_missed_periods: missed.saturating_sub(run.missed_at_start),
        }
    }

    /// A replay through the `periods` a wake covers (a stall's skipped ones too, published late): the run's own
    /// chunk where it made a call, none where it made none; past the recording's end its last action, every
    /// `stride` periods. Only the wake's own period is recorded (skipped ones leave a gap, as in a run).
    fn replay_periods(&mut self, cfg: &DaemonConfig, run: &mut EpisodeRun, periods: RangeInclusive<u64>, o: &Observed) {
        let k = *periods.end();
        let mut published = false;
        for j in periods {
            let replay = self.replay.as_ref().expect("a replay");
            let due = replay.made_call(j) || (replay.past_end(j) && j % run.stride as u64 == 0);
            if due && replay.chunk_at(j, &mut run.replayed) {
                self.publish_replayed(run, j, run.need_ns(cfg, j));
                published = true;
            }
        }
        self.record_period(run, k, published, o);
    }

    /// The replayed chunk (in `run.replayed`) for a call in period `k`, handed to the servo.
    fn publish_replayed(&mut self, run: &mut EpisodeRun, k: u64, need_ns: u64) {
        run.seq += 1;
        let ready_ns = monotonic_ns();
        let (episode, seq, period_ns) = (run.episode, run.seq, run.period_ns);
        let first_due_ns = need_ns + period_ns;
        // Computed from no camera frame now: no capture → command to measure.
        let stamp = ChunkStamp { episode, seq, period_ns, first_due_ns, ready_ns, capture_ns: 0 };
        Self::publish(&mut self.ch.chunks, &stamp, &run.replayed, run.d);
        run.timeline.write(k as i64 + 1, &run.replayed);
        if self.recording.is_some() {
            run.in_force.actions.copy_from_slice(&run.replayed);
            run.in_force.first_k = k;
            run.in_force.image.copy_from_slice(&self.view_image);
        }
        run.chunks += 1;
    }

    /// The chunk asked at `call.k`: of the inference host if there is one (sent, and settled now if its reply or
    /// its decision falls within this period, else at a later period), else of the local engine within what is
    /// left of its budget; published. `None` if the loop must stop (a trip was asked for).
    fn infer_chunk(
        &mut self,
        cfg: &DaemonConfig,
        run: &mut EpisodeRun,
        call: Call,
        o: &Observed,
        faults: &mut ChunkFaults,
        report: &mut PolicyReport,
    ) -> Option<()> {
        let k = call.k;
        let handoff_ns = call.need_ns - (cfg.policy.handoff_margin_ms * 1e6) as u64;
        // A seed per call: `marsd replay` reproduces any one call from the recording alone.
        let seed = crate::record::call_seed(cfg.seed, run.episode, k);
        let flight = InFlightCall { call, seed, started_ns: monotonic_ns(), handoff_ns };
        run.timeline.read(k as i64 + 1 - run.c as i64, &mut run.history);
        run.timeline.read(k as i64 + 1, &mut run.committed);
        if let Some(remote) = self.remote.as_mut() {
            let committed = run.committed_for(cfg.policy.continuity);
            let (episode, observation, history) = (run.episode, &run.obs[..], &run.history[..]);
            let capture_ns = call.capture_ns;
            let ask = Ask { episode, period: k, seed, capture_ns, handoff_ns, observation, history, committed };
            if remote.send(&ask) {
                run.in_flight = Some(flight);
                return self.settle_chunk(cfg, run, run.t0 + (k + 1) * run.period_ns, o, faults, report);
            }
            if remote.rests_on_miss() {
                return self.rest(run, k, o);
            }
        }
        self.local_chunk(cfg, run, flight, o, faults, report)
    }

    /// The call in flight: its host's chunk published if it came by `until_ns`, the local engine's (or none, the arm
    /// resting) if the host's time ran out, nothing yet otherwise.
    fn settle_chunk(
        &mut self,
        cfg: &DaemonConfig,
        run: &mut EpisodeRun,
        until_ns: u64,
        o: &Observed,
        faults: &mut ChunkFaults,
        report: &mut PolicyReport,
    ) -> Option<()> {
        let remote = self.remote.as_mut().expect("a call in flight has a host");
        let rests = remote.rests_on_miss();
        match remote.settle(until_ns) {
            Settled::Waiting => Some(()),
            Settled::Host(reply) => {
                let flight = run.in_flight.take().expect("a call in flight");
                let result = Ok(Inferred::hosted(&reply, &mut run.chunk_out));
                self.publish_chunk(cfg, run, flight, result, o, faults, report)
            }
            Settled::Missed => {
                let flight = run.in_flight.take().expect("a call in flight");
                if rests {
                    return self.rest(run, flight.call.k, o);
                }
                self.local_chunk(cfg, run, flight, o, faults, report)
            }
        }
    }

    /// `[remote] on_miss = "rest"`: no chunk for the call of period `k`. The servo finishes the chunk it has and
    /// holds its last action (the smoother brings the arm to rest there, within the jerk limits); the timeline
    /// holds it too, so the next call's history is the held pose. Not a fault: nothing is counted toward a trip,
    /// and the host's chunks resume at the first call it answers.
    fn rest(&mut self, run: &EpisodeRun, k: u64, o: &Observed) -> Option<()> {
        self.record_period(run, k, false, o);
        Some(())
    }

    /// The local engine's chunk for `flight`, within what is left until its handoff.
    fn local_chunk(
        &mut self,
        cfg: &DaemonConfig,
        run: &mut EpisodeRun,
        flight: InFlightCall,
        o: &Observed,
        faults: &mut ChunkFaults,
        report: &mut PolicyReport,
    ) -> Option<()> {
        let budget = Duration::from_nanos(flight.handoff_ns.saturating_sub(monotonic_ns()));
        self.engine.reseed(flight.seed);
        let committed = run.committed_for(cfg.policy.continuity);
        let result = self.engine.infer_after(&run.obs, &run.history, committed, budget);
        let result = result.map(|out| Inferred::local(out, &mut run.chunk_out));
        self.publish_chunk(cfg, run, flight, result, o, faults, report)
    }

    /// The call's chunk (in `run.chunk_out`) handed to the servo, past its committed rows, and counted.
    #[allow(clippy::too_many_arguments)]
    fn publish_chunk(
        &mut self,
        cfg: &DaemonConfig,
        run: &mut EpisodeRun,
        flight: InFlightCall,
        result: Result<Inferred, mars_engine::EngineError>,
        o: &Observed,
        faults: &mut ChunkFaults,
        report: &mut PolicyReport,
    ) -> Option<()> {
        let InFlightCall { call: Call { k, now, need_ns, capture_ns }, started_ns: started, .. } = flight;
        let joints = self.engine_joints().min(run.d);
        let ready = monotonic_ns();
        self.rec.record(Channel::Inference, ready - started);
        report.inferences += 1;
        let Ok(out) = result else {
            report.engine_errors += 1;
            return self.trip_if(true, Trip::EngineError);
        };
        let interval_ns = (cfg.histograms.interval_s * 1e9) as u64;
        let counts = (out.encode.as_nanos() as u64, out.k_requested, out.k_used);
        record_call(&mut self.rec, &mut self.next_interval_ns, interval_ns, counts, ready);
        report.capped += u64::from(out.capped);
        if out.over_budget {
            // Not even one step fitted: keep executing the previous chunk.
            report.over_budget += 1;
            self.record_period(run, k, false, o);
            return self.trip_if(faults.over.bad(), Trip::InferenceOverBudget);
        }
        faults.over.good();
        run.w_inf = out.w_inf;
        self.rec.record(Channel::WInf, Channel::w_inf_units(run.w_inf));
        run.seq += 1;
        let (episode, seq, period_ns) = (run.episode, run.seq, run.period_ns);
        let stamp =
            ChunkStamp { episode, seq, period_ns, first_due_ns: need_ns + period_ns, ready_ns: ready, capture_ns };
        // The committed rows are the previous chunk's to execute: only the rows after them are handed over.
        let handed = &run.chunk_out[run.ahead * run.d..];
        Self::publish(&mut self.ch.chunks, &stamp, handed, run.d);
        let first = (k + 1 + run.ahead as u64) as i64;
        run.timeline.write(first, handed);
        if run.chunks > 0 {
            run.timeline.read(first - 2, &mut run.around_handover);
            report.handover_jerk.add(&run.around_handover, run.d, joints, cfg.policy.rate_hz);
        }
        if self.recording.is_some() {
            let f = &mut run.in_force;
            f.actions.copy_from_slice(&run.chunk_out);
            f.first_k = k;
            f.w_inf = run.w_inf;
            f.k = [out.k_requested as f32, out.k_used as f32];
            f.latency_ms = [(ready - started) as f32 * 1e-6, out.encode.as_secs_f32() * 1e3];
        }
        run.chunks += 1;
        run.k_sum += out.k_used as u64;
        run.late += u64::from(ready > need_ns);
        let late = LateChunk { woke_ns: now, need_ns, ready_ns: ready };
        self.trip_if(count_late(late, report, faults), Trip::LateChunks)?;
        if self.recording.is_some() {
            if let Some(pixels) = self.last_pixels() {
                run.in_force.image.copy_from_slice(pixels);
            }
            self.record_period(run, k, true, o);
        }
        Some(())
    }

    /// Asks the servo loop for `trip` if `tripped`; then `None`, so that the policy loop stops.
    fn trip_if(&mut self, tripped: bool, trip: Trip) -> Option<()> {
        if tripped {
            self.request(Request::Trip(trip));
            return None;
        }
        Some(())
    }

    /// Push-T's referee's verdict on `episode` at `t_s` into it; `None`, after asking for a trip, if the referee
    /// went silent or lost the robot's state.
    fn scene_progress(&mut self, episode: u64, t_s: f64, timeout_s: f64, silent_limit_ns: u64) -> Option<Progress> {
        let scene = self.scene.as_mut().expect("a Push-T task has its scene opened");
        let s = *scene.poll();
        if scene.silent_ns(monotonic_ns()) > silent_limit_ns || s.stale_robot != 0 {
            tracing::error!("the scene's referee went silent or lost the robot's state mid-episode");
            self.request(Request::Trip(Trip::SceneLost));
            return None;
        }
        let mine = s.episode == episode;
        let mode = if mine { s.mode() } else { None };
        Some(if mine && s.success != 0 {
            Progress::Done { success: true, mode, reason: DoneReason::GoalReached }
        } else if t_s >= timeout_s {
            Progress::Done { success: false, mode, reason: DoneReason::Timeout }
        } else {
            Progress::Running
        })
    }

    /// Closes `episode` in the recording, if one runs: its `frames`, outcome and the rest pose it started from.
    fn end_recorded_episode(&mut self, episode: u64, frames: u64, success: bool, mode: Option<usize>, rest: &[f32]) {
        if let Some(r) = &mut self.recording {
            let mut end = crate::record::EpisodeEnd {
                episode,
                frames,
                success,
                mode,
                rest: [0.0; crate::servo::chunk::MAX_ACTION],
                rest_len: rest.len(),
            };
            end.rest[..rest.len()].copy_from_slice(rest);
            r.end_episode(end);
        }
    }

    /// Hands a chunk (`C × d` actions) to the servo thread, without locks.
    fn publish(chunks: &mut triple_buffer::Input<TimedChunk>, s: &ChunkStamp, chunk: &[f32], d: usize) {
        let dst = chunks.input_buffer_mut();
        dst.seq = s.episode << 32 | s.seq;
        dst.episode = s.episode;
        dst.period_ns = s.period_ns;
        dst.first_due_ns = s.first_due_ns;
        dst.len = chunk.len() / d;
        dst.ready_ns = s.ready_ns;
        dst.capture_ns = s.capture_ns;
        for (i, a) in chunk.chunks_exact(d).enumerate() {
            for (j, v) in a.iter().enumerate() {
                dst.actions[i][j] = *v as f64;
            }
        }
        chunks.publish();
    }

    /// Hands period `k` to the recording (if any): the state, the action of the chunk in force for it (its last
    /// once the chunk has run out, as the servo holds it), our columns. Wait-free and allocation-free.
    fn record_period(&mut self, run: &EpisodeRun, k: u64, call: bool, o: &Observed) {
        let Some(r) = &mut self.recording else { return };
        let (f, d, episode, t0, state) = (&run.in_force, run.d, run.episode, run.t0, &run.state);
        let c = f.actions.len() / d;
        let i = ((k - f.first_k) as usize).min(c - 1);
        r.record(|frame| {
            frame.episode = episode;
            frame.frame = k;
            frame.state.copy_from_slice(state);
            frame.action.copy_from_slice(&f.actions[i * d..(i + 1) * d]);
            // A call's period: the frame the call saw (so `marsd replay` makes the same call); else the camera's
            // newest frame at this period.
            frame.image.copy_from_slice(if call { &f.image } else { &self.view_image });
            frame.w_inf = f.w_inf;
            frame.k = f.k;
            frame.latency_ms = f.latency_ms;
            frame.call = if call { 1.0 } else { 0.0 };
            frame.hal = [o.status as f32, o.fault as f32, o.hold_reason as f32];
            frame.state_time_s = (o.timestamp_ns as i64 - t0 as i64) as f32 * 1e-9;
        });
    }

    /// The observation's state part (no image) for state `o`: Pick Cup's joints and gripper, Push-T's flange (x, y).
    fn state_of(&self, o: &Observed, out: &mut [f32]) {
        match &self.task {
            HilTask::Pick(t) => t.observation(&o.position[..t.joints()], o.gripper, out),
            HilTask::PushT(t) => {
                let [x, y] = t.flange_xy(&o.position[..7]);
                (out[0], out[1]) = (x as f32, y as f32);
            }
        }
    }

    fn state_dim(&self) -> usize {
        match &self.task {
            HilTask::Pick(t) => t.obs_dim(),
            HilTask::PushT(_) => 2,
        }
    }

    /// Bytes of the camera's frame (0 without a camera).
    fn image_len(&self) -> usize {
        match &self.task {
            HilTask::Pick(_) => 0,
            HilTask::PushT(t) => (t.cfg.camera.size * t.cfg.camera.size * 3) as usize,
        }
    }

    /// The pixels of the frame the last observation used (Push-T, while recording).
    fn last_pixels(&self) -> Option<&[u8]> {
        (!self.last_image.is_empty()).then_some(self.last_image.as_slice())
    }

    /// The robot's joint count.
    fn engine_joints(&self) -> usize {
        match &self.task {
            HilTask::Pick(t) => t.joints(),
            HilTask::PushT(t) => t.start_pose.len(),
        }
    }

    /// Writes the policy's observation for state `o` into `obs`: the measured arm, or for Push-T the flange's
    /// (x, y) and the newest usable camera frame. Returns the observation's capture time: the camera frame's, or for
    /// a task without a camera the state frame's.
    /// `Err` when the camera has no usable frame (counted, and its refusal's reason logged the first time).
    fn observe(
        &mut self,
        o: &Observed,
        obs: &mut [f32],
        trace: &mut crate::report::plots::EpisodeTrace,
        report: &mut PolicyReport,
    ) -> Result<u64, ()> {
        match &self.task {
            HilTask::Pick(t) => {
                t.observation(&o.position[..t.joints()], o.gripper, obs);
                Ok(o.timestamp_ns)
            }
            HilTask::PushT(t) => {
                let scene = self.scene.as_mut().expect("a Push-T task has its scene opened");
                let polled = scene.camera.poll();
                let cam = report.camera.get_or_insert_with(CameraReport::default);
                if let Some(r) = polled.refusal
                    && cam.first_refusal.is_none()
                {
                    tracing::warn!("camera {}: a frame refused because {r}", scene.camera.service());
                    cam.first_refusal = Some(r.to_string());
                }
                let Some(frame) = polled.frame else {
                    cam.no_frame += 1;
                    return Err(());
                };
                let capture = frame.header().timestamp_ns;
                PushTHil::observation(t, &o.position[..7], frame.pixels(), obs);
                if self.last_image.len() == frame.pixels().len() {
                    self.last_image.copy_from_slice(frame.pixels());
                }
                self.rec.record(Channel::CameraAge, monotonic_ns().saturating_sub(capture));
                trace.keep_frame(frame.pixels());
                Ok(capture)
            }
        }
    }

    fn must_stop(&self) -> bool {
        let s = &self.ch.status;
        s.stop_requested.load(Ordering::Acquire)
            || s.trip().is_some()
            || matches!(s.phase(), Phase::Stopping | Phase::Finished)
    }

    /// Polls until `ready` holds; false if the loop must stop first.
    fn wait_for(&self, ready: impl Fn(&Status) -> bool) -> bool {
        loop {
            self.ch.status.policy_beats.fetch_add(1, Ordering::Relaxed);
            if ready(&self.ch.status) {
                return true;
            }
            if self.must_stop() {
                return false;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Queues a request for the servo; false if the queue stayed full (the servo loop is gone).
    fn request(&mut self, r: Request) -> bool {
        for _ in 0..1000 {
            if self.ch.requests.push(r).is_ok() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        false
    }
}

/// One chunk's call, from the local engine or the inference host: what the rest of the loop needs of it.
struct Inferred {
    w_inf: f32,
    k_requested: usize,
    k_used: usize,
    capped: bool,
    over_budget: bool,
    encode: Duration,
}

impl Inferred {
    /// The engine's call, its chunk copied into `chunk`.
    fn local(out: mars_engine::Output<'_>, chunk: &mut [f32]) -> Self {
        chunk.copy_from_slice(out.chunk);
        Self {
            w_inf: out.w.iter().fold(0.0f32, |m, w| m.max(w.abs())),
            k_requested: out.k_requested,
            k_used: out.k_used,
            capped: out.capped,
            over_budget: out.over_budget,
            encode: out.encode,
        }
    }

    /// The host's reply (of the robot's shape, checked by [`remote::Remote::settle`]), its chunk copied into `chunk`.
    fn hosted(r: &mars_remote::wire::Reply, chunk: &mut [f32]) -> Self {
        chunk.copy_from_slice(&r.chunk);
        Self {
            w_inf: r.w_inf,
            k_requested: r.k_requested as usize,
            k_used: r.k_used as usize,
            capped: r.capped,
            over_budget: r.over_budget,
            encode: Duration::from_nanos(r.encode_ns),
        }
    }
}

/// Records one engine call's encode time and steps (`call`: encode ns, K requested, K used), and closes the
/// recorder's interval when it has run out, so the live view sees the policy's channels while the run goes on.
fn record_call(
    rec: &mut Recorder,
    next_interval_ns: &mut u64,
    interval_ns: u64,
    call: (u64, usize, usize),
    ready: u64,
) {
    let (encode_ns, k_requested, k_used) = call;
    rec.record(Channel::Encode, encode_ns);
    rec.record(Channel::KRequested, k_requested as u64);
    rec.record(Channel::KUsed, k_used as u64);
    if ready >= *next_interval_ns {
        if *next_interval_ns != 0 {
            rec.end_interval(ready);
        }
        *next_interval_ns = ready + interval_ns;
    }
}

/// Counts a chunk that was ready after it was needed (keeping the first few's times); whether late chunks came in
/// a row often enough to trip.
fn count_late(chunk: LateChunk, report: &mut PolicyReport, faults: &mut ChunkFaults) -> bool {
    if chunk.ready_ns <= chunk.need_ns {
        faults.late.good();
        return false;
    }
    report.late_chunks += 1;
    if report.late_chunk_times.len() < LATE_CHUNKS_KEPT {
        report.late_chunk_times.push(chunk);
    }
    faults.late.bad()
}
