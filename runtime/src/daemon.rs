//! `marsd` as a whole: check everything before anything moves, start the servo and policy threads, be a good
//! systemd citizen from the main (non-real-time) thread, and write the report at the end.
//!
//! The main thread owns everything that may allocate or block: signal handling (flags set by signal-hook),
//! systemd notifications (`READY=1` after the HAL handshake, `WATCHDOG=1` only while both loops make progress
//! and nothing tripped — the sd-notify crate allocates and opens a socket per call), log lines for trips as
//! soon as the servo publishes them, and the handshake timeout. The iceoryx2 liveness heartbeat beats from a
//! thread of its own ([`mars_ipc::heartbeat_thread`]), only while the servo loop advances.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use mars_engine::{Engine, EngineConfig};
use mars_ipc::{HeartbeatThread, PeerView, Route, Side};
use mars_profile::Profile;
use tracing::{error, info, warn};

use crate::config::DaemonConfig;
use crate::observe::scene_link::SceneLink;
use crate::policy::recorded_actions::RecordedActions;
use crate::policy::{PolicyChannels, PolicyLoop};
use crate::report::Summary;
use crate::report::latency::{Channel, Collector};
use crate::rt::RtStatus;
use crate::servo::ServoTick;
use crate::servo::chunk::{MAX_ACTION, MAX_CHUNK, TimedChunk};
use crate::servo::servo_loop::{ServoChannels, ServoLoopConfig, ServoReport, ServoWire, run_servo};
use crate::shared::{Observed, Status};
use crate::task::HilTask;

/// Exit statuses, so a supervisor (or a test) can tell outcomes apart.
pub mod exit {
    /// Clean: the episodes ran, or SIGTERM/SIGINT brought the arm to rest.
    pub const OK: u8 = 0;
    /// Something failed at run time outside the watchdog (I/O, threads).
    pub const FAILURE: u8 = 1;
    /// Bad configuration, profile, task or checkpoint: refused before anything moved.
    pub const BAD_SETUP: u8 = 2;
    /// The watchdog tripped: the arm was brought to rest and held; the reason is in the log.
    pub const TRIPPED: u8 = 3;
    /// No HAL answered within the handshake timeout; nothing was commanded.
    pub const NO_HAL: u8 = 4;
}

/// Everything loaded and checked, nothing started.
pub struct Prepared {
    pub cfg: DaemonConfig,
    pub profile: Profile,
    pub task: HilTask,
    pub engine: Engine,
    /// A recorded episode's chunks to run instead of the engine's ([`Prepared::replaying`]).
    pub replay: Option<RecordedActions>,
    /// `[remote]`: the inference host, joined (and its clock measured) before the loops start.
    pub remote: Option<crate::policy::remote::Remote>,
}

impl Prepared {
    /// Runs episode `n` of a dataset marsd recorded with the run's chunks instead of the engine's: one episode,
    /// the run's seed (so the same start pose).
    pub fn replaying(mut self, dataset: &Path, n: usize) -> anyhow::Result<Self> {
        anyhow::ensure!(
            self.cfg.policy.ask_ahead_periods == 0,
            "replay: not with policy.ask_ahead_periods > 0 (a recording holds whole chunks)"
        );
        let r = RecordedActions::load(dataset, n).with_context(|| format!("replaying {}", dataset.display()))?;
        anyhow::ensure!(
            r.action_dim() == self.engine.action_dim(),
            "{}: its actions have {} values, the task's {}",
            dataset.display(),
            r.action_dim(),
            self.engine.action_dim()
        );
        self.cfg.seed = r.seed;
        self.cfg.episodes = 1;
        self.replay = Some(r);
        Ok(self)
    }
}

/// Loads and cross-checks the profile, task and checkpoint. Any error here means nothing moved.
pub fn prepare(mut cfg: DaemonConfig) -> anyhow::Result<Prepared> {
    // Again: the command line may have changed what the file said.
    cfg.validate(&cfg.source.display().to_string())?;
    let profile = Profile::load(&cfg.profile)?;
    profile.validate()?;
    let task = HilTask::load(&cfg.task, &profile).with_context(|| format!("task {}", cfg.task.display()))?;
    let engine_cfg =
        EngineConfig { seed: cfg.seed, injected_step_delay: cfg.engine_step_delay(), ..EngineConfig::default() };
    let engine = Engine::load(&cfg.checkpoint, engine_cfg)
        .with_context(|| format!("checkpoint {}", cfg.checkpoint.display()))?;
    let ck = cfg.checkpoint.display();
    anyhow::ensure!(
        engine.obs_dim() == task.obs_dim() && engine.action_dim() == task.action_dim(),
        "checkpoint {ck} maps {} observations to {} actions; the task needs {} → {}",
        engine.obs_dim(),
        engine.action_dim(),
        task.obs_dim(),
        task.action_dim()
    );
    anyhow::ensure!(
        engine.chunk_len() <= MAX_CHUNK && engine.action_dim() <= MAX_ACTION,
        "checkpoint {ck}: chunks of {} actions × {} values exceed the handoff's {MAX_CHUNK} × {MAX_ACTION}",
        engine.chunk_len(),
        engine.action_dim()
    );
    let ahead = cfg.policy.ask_ahead_periods;
    // A chunk asked ahead is settled before the next is asked: at most (C − 1)/2 periods ahead.
    anyhow::ensure!(
        2 * ahead < engine.chunk_len(),
        "policy.ask_ahead_periods = {ahead}: at most {} for the checkpoint's chunk of {} actions (a chunk is settled \
         before the next is asked)",
        (engine.chunk_len() - 1) / 2,
        engine.chunk_len()
    );
    let auto_ahead = cfg.remote.as_ref().is_some_and(|r| r.auto_ask_ahead);
    anyhow::ensure!(
        (ahead == 0 && !auto_ahead) || cfg.record.is_none(),
        "record: not with policy.ask_ahead_periods > 0 or [remote] auto_ask_ahead yet (a recorded chunk is a whole \
         one, executed from its start)"
    );
    if let Some(path) = &cfg.record {
        anyhow::ensure!(
            !path.exists(),
            "record: {} exists; a recording never overwrites (give a new path)",
            path.display()
        );
        let camera = matches!(task, HilTask::PushT(_));
        anyhow::ensure!(
            !camera || mars_lerobot::video::SUPPORTED,
            "record: the task's camera: {}",
            mars_lerobot::video::NO_VIDEO
        );
    }
    let rate = task.policy_rate_hz();
    anyhow::ensure!(
        (cfg.policy.rate_hz - rate).abs() < 1e-9,
        "policy.rate_hz = {} but the task's demos were recorded at {rate} Hz",
        cfg.policy.rate_hz
    );
    let mut remote = match &cfg.remote {
        Some(r) => Some(crate::policy::remote::Remote::connect(&cfg, r).context("[remote]")?),
        None => None,
    };
    if let Some(r) = remote.as_mut().filter(|_| auto_ahead) {
        // At most (C − 1)/2, as checked above for a value the file gives.
        cfg.policy.ask_ahead_periods = r.choose_ask_ahead(&cfg.policy, engine.chunk_len().saturating_sub(1) / 2);
    }
    Ok(Prepared { cfg, profile, task, engine, replay: None, remote })
}

pub struct Outcome {
    pub exit: u8,
    pub summary: Summary,
}

/// Runs the loops to the end and writes the report into `cfg.out`.
pub fn run(p: Prepared) -> anyhow::Result<Outcome> {
    let Prepared { cfg, profile, task, engine, replay, remote } = p;
    let mode_names = task.mode_names();
    // The report draws with the task's geometry (Push-T's camera view); the task itself moves to the policy thread.
    let task_view = task.clone();
    std::fs::create_dir_all(&cfg.out).with_context(|| format!("creating {}", cfg.out.display()))?;
    let status = Arc::new(Status::default());
    let network = live_on_network(&cfg, remote.as_ref());
    let (collector, servo_rec, policy_rec) = start_collector(&cfg, &profile, &task, &status, network)?;

    // Policy thread → servo thread (see `shared`).
    let (requests_in, requests_out) = rtrb::RingBuffer::new(16);
    let (chunk_in, chunk_out) = triple_buffer::triple_buffer(&TimedChunk::default());
    let (obs_in, obs_out) = triple_buffer::triple_buffer(&Observed::default());
    let session = session_id();
    let tick = match &task {
        HilTask::Pick(_) => ServoTick::new(&cfg, &profile, session)?,
        // Push-T acts on the table: the servo turns its (x, y) into joints.
        HilTask::PushT(t) => ServoTick::new(&cfg, &profile, session)?.with_effector(t.effector()),
    };
    let loop_cfg = ServoLoopConfig {
        period: Duration::from_secs_f64(profile.period_s()),
        interval: cfg.histogram_interval(),
        max_consecutive_send_errors: cfg.watchdog.max_consecutive_send_errors,
    };

    // Before anything moves: a recording that cannot start (its path exists) stops marsd here.
    let (recording, record_writer) = match &cfg.record {
        Some(path) => {
            let (r, w) = crate::record::start(record_setup(&cfg, &profile, &task, path))
                .with_context(|| format!("recording to {}", path.display()))?;
            (Some(r), Some(w))
        }
        None => (None, None),
    };
    let servo_ch =
        ServoChannels { chunks: chunk_out, observed: obs_in, requests: requests_out, status: status.clone() };
    let (servo, hal_watch) = start_servo(&cfg, tick, servo_ch, servo_rec, loop_cfg)?;
    let heartbeat = match start_heartbeat(&cfg, &status) {
        Ok(h) => h,
        Err(e) => {
            // Nothing was commanded yet: the servo loop ends at once on a stop request before the handshake.
            status.stop_requested.store(true, Ordering::Release);
            let _ = servo.join();
            return Err(e);
        }
    };
    // After the wire is open: `ServoWire::open` makes iceoryx2 install its own handlers, which replace whatever
    // is there, and signal-hook chains to a handler installed before it.
    let term = on_termination_signals()?;

    let policy_ch =
        PolicyChannels { chunks: chunk_in, observed: obs_out, requests: requests_in, status: status.clone() };
    let parts = PolicyParts { engine, task, ch: policy_ch, rec: policy_rec, recording, replay, remote };
    let policy = match start_policy(&cfg, parts, status.clone()) {
        Ok(p) => p,
        Err(e) => {
            let _ = servo.join();
            return Err(e.context("opening the task's camera and scene"));
        }
    };

    // The main thread logs a trip: at the watchers' priority while the loops run, so a busy machine cannot delay
    // the report; back to the normal scheduler for the summary and plots.
    let supervisor_rt = crate::rt::setup_realtime("supervisor", None, Some(cfg.watchdog.priority), false);
    let no_hal = supervise(&status, &term, &servo, &hal_watch, cfg.handshake_timeout());
    crate::rt::back_to_sched_other();
    let servo_joined = servo.join();
    // Stopped once the servo loop has ended (its last command, the hold, is sent): the HAL sees us leave.
    let heartbeat = heartbeat.finish();
    let (servo_report, servo_rt) = servo_joined
        .map_err(|_| anyhow::anyhow!("the servo thread panicked"))?
        .context("the servo thread could not open the wire")?;
    let (policy_report, policy_rt) = policy
        .join()
        .map_err(|_| anyhow::anyhow!("the policy thread panicked"))?
        .context("the policy thread could not open the task's camera and scene")?;
    let totals = collector.finish();
    let record = record_writer.map(crate::record::RecordWriter::finish);

    if let Some(v) = servo_report.first_violation {
        tracing::error!("the first command refused by the final limit check: {v:?}");
    }
    if let Some(e) = servo_report.first_smoothing_error {
        tracing::error!("the jerk-limited smoother refused: {e}");
    }
    let run = crate::report::RunFacts { realtime: vec![servo_rt, policy_rt, supervisor_rt], heartbeat };
    let mut summary = Summary::new(&cfg, &mode_names, &servo_report, &policy_report, totals, run);
    summary.record = record;
    summary.trip_seen_ns = Some(status.trip_seen_ns.load(Ordering::Acquire)).filter(|&t| t != 0);
    let written = summary.write(&cfg.out, &policy_report, &task_view)?;
    println!("{summary}");
    println!("  wrote {}", written.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "));
    let exit = if no_hal {
        exit::NO_HAL
    } else if summary.trip.is_some() {
        exit::TRIPPED
    } else {
        exit::OK
    };
    Ok(Outcome { exit, summary })
}

/// The latency collector (and the live view it feeds) and its recorders for the servo and the policy loop.
fn start_collector(
    cfg: &DaemonConfig,
    profile: &Profile,
    task: &HilTask,
    status: &Arc<Status>,
    network: Option<mars_remote::live::LivePublisher>,
) -> anyhow::Result<(Collector, crate::report::latency::Recorder, crate::report::latency::Recorder)> {
    let live = crate::report::live::publisher(crate::report::live::LiveSetup {
        robot: cfg.robot.clone(),
        status: status.clone(),
        period_ns: (profile.period_s() * 1e9) as u64,
        inference_budget_ns: ((cfg.policy.lead_ms - cfg.policy.handoff_margin_ms).max(0.0) * 1e6) as u64,
        camera: match task {
            HilTask::PushT(t) => Some(t.cfg.camera.name.clone()),
            HilTask::Pick(_) => None,
        },
        network,
    });
    let collector = Collector::start_with(&cfg.out, Duration::from_millis(50), Some(live))?;
    let servo_rec = collector.recorder("servo", &servo_channels(), 8);
    let policy_rec = collector.recorder(
        "policy",
        &[Channel::Inference, Channel::KRequested, Channel::KUsed, Channel::Encode, Channel::CameraAge, Channel::WInf],
        8,
    );
    Ok((collector, servo_rec, policy_rec))
}

/// With `[remote]`, the live frames' publisher on the Zenoh network; a run without it (said once) loses only that.
fn live_on_network(
    cfg: &DaemonConfig,
    remote: Option<&crate::policy::remote::Remote>,
) -> Option<mars_remote::live::LivePublisher> {
    let (remote, rc) = (remote?, cfg.remote.as_ref()?);
    remote.live_publisher(rc, &cfg.robot).map_err(|e| tracing::warn!("live frames not on the network: {e:#}")).ok()
}

/// The liveness heartbeat, beating only while the servo's tick counter advances: a syscall the servo thread does
/// not make itself.
fn start_heartbeat(cfg: &DaemonConfig, status: &Arc<Status>) -> anyhow::Result<HeartbeatThread> {
    let ticks = status.clone();
    let progress = move || ticks.ticks.load(Ordering::Acquire);
    let watch_prio = cfg.watchdog.priority;
    HeartbeatThread::start_then(&cfg.robot, Side::Controller, &format!("marsd-{}", cfg.robot), progress, move || {
        crate::rt::setup_realtime("heartbeat", None, Some(watch_prio), false);
    })
    .context("opening the liveness heartbeat")
}

/// The flag SIGTERM and SIGINT set. Signals only set flags; the main thread turns them into a safe stop. A second
/// SIGINT/SIGTERM while stopping exits at once (status 1); the HAL then brakes on command loss.
fn on_termination_signals() -> anyhow::Result<Arc<AtomicBool>> {
    let term = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register_conditional_shutdown(sig, 1, term.clone())?;
        signal_hook::flag::register(sig, term.clone())?;
    }
    Ok(term)
}

/// The servo thread's end: its report and real-time setup (`None`: it could not open the wire).
type ServoThread = std::thread::JoinHandle<Option<(ServoReport, RtStatus)>>;
/// The policy thread's end (`None`: it could not open the task's camera and scene).
type PolicyThread = std::thread::JoinHandle<Option<(crate::policy::PolicyReport, RtStatus)>>;

/// Starts the servo thread, which opens the wire itself (iceoryx2's ports stay on the thread that made them);
/// returns once it is open, with a view of its HAL liveness watch.
fn start_servo(
    cfg: &DaemonConfig,
    tick: ServoTick,
    ch: ServoChannels,
    rec: crate::report::latency::Recorder,
    loop_cfg: ServoLoopConfig,
) -> anyhow::Result<(ServoThread, PeerView)> {
    let (core, priority, lock) = (cfg.servo.core, cfg.servo.priority, cfg.servo.lock_memory);
    let (robot, watch_priority) = (cfg.robot.clone(), cfg.watchdog.priority);
    let (opened_tx, opened_rx) = std::sync::mpsc::channel::<anyhow::Result<PeerView>>();
    let servo = std::thread::Builder::new()
        .name("marsd-servo".into())
        .spawn(move || {
            let wire = match ServoWire::open(&robot, watch_priority) {
                Ok(w) => {
                    let _ = opened_tx.send(Ok(w.hal.view()));
                    w
                }
                Err(e) => {
                    let _ = opened_tx.send(Err(e));
                    return None;
                }
            };
            let rt = crate::rt::setup_realtime("servo", core, Some(priority), lock);
            Some((run_servo(tick, wire, ch, rec, loop_cfg), rt))
        })
        .context("spawning the servo thread")?;
    let hal_watch = opened_rx.recv().context("the servo thread died while opening the wire")??;
    Ok((servo, hal_watch))
}

/// What the policy thread is started with; it opens the rest (the scene) itself.
struct PolicyParts {
    engine: Engine,
    task: HilTask,
    ch: PolicyChannels,
    rec: crate::report::latency::Recorder,
    recording: Option<crate::record::Recorder>,
    replay: Option<RecordedActions>,
    remote: Option<crate::policy::remote::Remote>,
}

/// Starts the policy thread; returns once it has opened Push-T's camera and scene (on that thread: iceoryx2's
/// ports stay on their thread). A failure to open them stops the servo loop before anything moved, like a bad
/// configuration; the caller then joins the servo thread.
fn start_policy(cfg: &DaemonConfig, parts: PolicyParts, status: Arc<Status>) -> anyhow::Result<PolicyThread> {
    let cfg = cfg.clone();
    let (scene_tx, scene_rx) = std::sync::mpsc::channel::<anyhow::Result<()>>();
    let thread = std::thread::Builder::new()
        .name("marsd-policy".into())
        .spawn(move || {
            let PolicyParts { engine, task, ch, rec, recording, replay, remote } = parts;
            let scene = match &task {
                HilTask::PushT(t) => match SceneLink::open(&cfg.robot, t, recording.is_some()) {
                    Ok(s) => Some(s),
                    Err(e) => {
                        let _ = scene_tx.send(Err(e));
                        status.stop_requested.store(true, Ordering::Release);
                        return None;
                    }
                },
                HilTask::Pick(_) => None,
            };
            let _ = scene_tx.send(Ok(()));
            let rt = crate::rt::setup_realtime("policy", cfg.policy.core, Some(cfg.policy.priority), false);
            let (last_image, view_image) = (Vec::new(), Vec::new());
            let policy = PolicyLoop {
                engine,
                task,
                ch,
                rec,
                scene,
                next_interval_ns: 0,
                recording,
                last_image,
                view_image,
                replay,
                remote,
            };
            Some((policy.run(&cfg), rt))
        })
        .context("spawning the policy thread")?;
    if let Err(e) = scene_rx.recv().unwrap_or(Ok(())) {
        let _ = thread.join();
        return Err(e);
    }
    Ok(thread)
}

/// The recording's dataset: the policy's state and action (named per joint), Push-T's camera, the task's name.
fn record_setup(cfg: &DaemonConfig, profile: &Profile, task: &HilTask, path: &Path) -> crate::record::RecordSetup {
    let (state_names, action_names, camera) = match task {
        HilTask::Pick(t) => {
            let mut names: Vec<String> = (0..t.joints()).map(|j| format!("joint_{j}")).collect();
            names.push("gripper".into());
            (names.clone(), names, None)
        }
        HilTask::PushT(t) => {
            let xy = vec!["x".to_owned(), "y".to_owned()];
            let size = t.cfg.camera.size;
            (xy.clone(), xy, Some((format!("observation.images.{}", t.cfg.camera.name), size, size)))
        }
    };
    crate::record::RecordSetup {
        path: path.to_owned(),
        fps: task.policy_rate_hz().round() as u32,
        robot_type: profile.name.clone(),
        task: task.name().to_owned(),
        state_names,
        action_names,
        camera,
        writer_delay: cfg.record_writer_delay(),
        seed: cfg.seed,
        // Absolute, so `marsd replay` finds it from anywhere on this machine (`--checkpoint` elsewhere).
        checkpoint: std::fs::canonicalize(&cfg.checkpoint).unwrap_or_else(|_| cfg.checkpoint.clone()),
        config: std::fs::canonicalize(&cfg.source).unwrap_or_else(|_| cfg.source.clone()),
    }
}

/// Says once per change how marsd learns that the HAL died: a dead HAL stops the arm either way, but the
/// registry route names the death only at a missed deadline, milliseconds later.
fn log_liveness_route(route: Route, logged: &mut Route) {
    if route == *logged {
        return;
    }
    *logged = route;
    match route {
        Route::Unknown => {}
        Route::Pidfd => {
            info!("HAL liveness: its process is held by pidfd, its end seen the moment the kernel reports it")
        }
        Route::Registry => warn!(
            "HAL liveness: its process cannot be held by pidfd (another pid namespace?); its death is looked up in \
             iceoryx2's node registry at each missed heartbeat deadline"
        ),
    }
}

/// The main thread's loop until the servo thread ends: signals, systemd, trip logging, handshake timeout.
/// Returns true if no HAL ever answered.
fn supervise(
    status: &Status,
    term: &AtomicBool,
    servo: &std::thread::JoinHandle<Option<(ServoReport, RtStatus)>>,
    hal_watch: &PeerView,
    handshake_timeout: Duration,
) -> bool {
    let started = Instant::now();
    let watchdog = sd_notify::watchdog_enabled();
    let mut last_ping = Instant::now();
    let (mut last_ticks, mut last_beats) = (0, 0);
    let (mut ready_sent, mut stop_logged, mut no_hal) = (false, false, false);
    let mut logged_trip = None;
    let mut logged_route = Route::Unknown;
    while !servo.is_finished() {
        std::thread::sleep(Duration::from_millis(2));
        if term.load(Ordering::Acquire) && !status.stop_requested.load(Ordering::Acquire) {
            status.stop_requested.store(true, Ordering::Release);
            if !stop_logged {
                info!("termination requested: bringing the arm to rest");
                stop_logged = true;
                let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
            }
        }
        let hal_ready = status.hal_ready.load(Ordering::Acquire);
        if hal_ready && !ready_sent {
            ready_sent = true;
            info!(after_ms = started.elapsed().as_millis() as u64, "HAL handshake done: ready");
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
        }
        log_liveness_route(hal_watch.route(), &mut logged_route);
        if !hal_ready && !no_hal && started.elapsed() > handshake_timeout {
            error!(
                "no usable state frame from a HAL within {handshake_timeout:?}: is mars-hal running with the same --robot and profile?"
            );
            no_hal = true;
            status.stop_requested.store(true, Ordering::Release);
        }
        if let Some(trip) = status.trip()
            && logged_trip != Some(trip)
        {
            logged_trip = Some(trip);
            status.trip_seen_ns.store(crate::rt::monotonic_ns(), Ordering::Release);
            error!(reason = %trip, "watchdog trip: stopping the arm with a jerk-limited brake and holding");
        }
        // systemd's watchdog is fed only while the servo loop makes progress and nothing tripped.
        if let Some(w) = watchdog
            && last_ping.elapsed() >= w / 2
        {
            let ticks = status.ticks.load(Ordering::Acquire);
            let beats = status.policy_beats.load(Ordering::Acquire);
            if ticks > last_ticks && beats > last_beats && status.trip().is_none() {
                let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            }
            last_ticks = ticks;
            last_beats = beats;
            last_ping = Instant::now();
        }
    }
    no_hal
}

/// The servo thread's histograms, with each chunk's observation capture (Push-T's camera frame, a state task's
/// state frame) → its first command.
fn servo_channels() -> Vec<Channel> {
    vec![
        Channel::WakeJitter,
        Channel::TickCompute,
        Channel::StateAge,
        Channel::StateToCommand,
        Channel::CaptureToCommand,
    ]
}

/// A session id no other controller run uses: the HAL never resumes a session that stopped.
fn session_id() -> u64 {
    let t = mars_ipc::clock::monotonic_ns();
    (t ^ (u64::from(std::process::id()) << 40)) | 1
}

/// The configuration `marsd` actually runs with: the file, then the command line's overrides.
pub fn load_config(
    path: &Path,
    robot: Option<String>,
    episodes: Option<usize>,
    out: Option<PathBuf>,
) -> anyhow::Result<DaemonConfig> {
    let mut cfg = DaemonConfig::load(path)?;
    if let Some(r) = robot {
        cfg.robot = r;
    }
    if let Some(e) = episodes {
        cfg.episodes = e;
    }
    if let Some(o) = out {
        cfg.out = o;
    }
    Ok(cfg)
}
