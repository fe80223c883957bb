//! The `mars-hal` loop: read the robot first, then once per period take the controller's commands, filter
//! them, command the backend and publish the state; brake and hold when commands stop or anything fails.
//!
//! The per-tick logic is [`crate::control`]; this file is the I/O around it, under the same real-time discipline
//! as marsd's servo loop: the loop thread is pinned and SCHED_FIFO when allowed, the process's memory is locked,
//! the loop sleeps on absolute deadlines ([`mars_rt::Ticker`]), logs through a wait-free ring (a logger thread
//! formats), beats its liveness heartbeat from an ordinary thread that watches its tick counter, and allocates
//! nothing per tick but iceoryx2's one block per published sample (served from the real-time pool; see
//! [`mars_rt::alloc_count`], counted in the report).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use hdrhistogram::Histogram;
use mars_ipc::liveness::{PeerWatch, Side};
use mars_ipc::node::create_node;
use mars_ipc::{CommandReader, FrameReceiveError, HeartbeatThread, RobotNamespace, StateWriter};
use mars_rt::alloc_count::{self, Counts, RtPoolScope};
use mars_rt::overlong::{ComputingTick, Longest, OverlongCounts, Stamp, TickAccount};
use mars_rt::{RtStatus, Ticker, monotonic_ns, setup_realtime};
use tracing::{info, warn};

use crate::backend::{Backend, BackendError, Measurement};
use crate::control::{ErrorCounts, HalControl};
use crate::events::{EventLogger, EventSender};
use mars_profile::Profile;

/// Ticks before the allocation count starts (iceoryx2 and the histograms settle in the first ones) — counted again
/// from the first command when a controller connects later: iceoryx2 sets up its connection to the controller's
/// ports (allocating) in this loop's first receive and send after they appear, and a HAL may run long before its
/// controller starts (a service that marsd connects to). The first command comes after both: the controller
/// answers a frame it received. Later connections (a second controller, another subscriber to the states) cost
/// the loop the same set-up, and are counted.
const WARMUP_TICKS: u64 = 500;

pub struct RunOptions {
    /// Robot id of the service namespace (defaults to the profile's name in the CLI).
    pub robot: String,
    /// Stop after this long; `None` runs until SIGINT/SIGTERM.
    pub duration: Option<Duration>,
    /// Pin the loop thread to this core.
    pub core: Option<usize>,
    /// Run the loop thread at this SCHED_FIFO priority (a robot's own control loop is real-time); a refusal
    /// is logged as a warning and the loop runs at normal priority.
    pub rt_priority: Option<i32>,
    /// Lock the process's memory (mlockall) so no page fault stalls the loop; a refusal is logged.
    pub lock_memory: bool,
    /// Ends the loop like a termination request when set (for a HAL run inside another program, e.g. a test).
    pub stop: Option<Arc<AtomicBool>>,
    /// At the end of the duration or on a termination request, first stop following and brake the setpoint to
    /// rest (a real robot is released only at rest); otherwise end at once (the sim).
    pub brake_before_exit: bool,
}

/// How the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    Duration,
    Signal,
    /// The backend failed for good; the arm had been braked to rest.
    BackendFailed(BackendError),
    /// The connection to a real robot broke (nothing can be commanded; the robot's own reflex stops it).
    ConnectionLost,
    /// A motion's first state failed the take-over checks (why): the motion ended there, nothing was commanded and
    /// the robot held the arm itself.
    NotTakenOver(&'static str),
}

/// Loop timing and safety counters, printed at exit.
pub struct Report {
    pub ticks: u64,
    pub ended: Ended,
    pub realtime: RtStatus,
    /// Whether the robot paced the loop (the fci backend) rather than the HAL's timer.
    pub paced_by_robot: bool,
    /// Wake-up lateness past each tick's deadline (µs); when the robot paces the loop, how much longer than one
    /// period after the last state the next one came.
    pub wake_late_us: Histogram<u64>,
    /// Work per tick: read, commands, filter, backend, publish (µs).
    pub work_us: Histogram<u64>,
    /// Whole periods skipped because the loop fell behind.
    pub overruns: u64,
    /// The period a tick must fit in (the profile's; the robot's cycle for fci).
    pub period: Duration,
    /// Ticks that blocked, and the others that took longer than `period` by why (ticks an injected fault delayed
    /// are not counted).
    pub overlong: OverlongCounts,
    pub longest: Option<Longest>,
    /// The first computing ticks with their times (`mars_rt::overlong::COMPUTING_TICKS_KEPT` at most).
    pub computing_ticks: Vec<ComputingTick>,
    pub rejected: u64,
    pub clamped: u64,
    /// Commands whose step from the setpoint was off by timing the HAL found itself (`SafetyFilter::timing_steps`).
    pub timing_steps: u64,
    pub schema_refusals: u64,
    /// Commands that arrived after the tick they answered for (see `RobotState::late_commands`).
    pub late_commands: u64,
    /// Last resorts of the safety filter (see `RobotState::position_guard_hits` / `infeasible_steps`).
    pub position_guard_hits: u64,
    pub infeasible_steps: u64,
    pub errors: ErrorCounts,
    pub gripper_moves: u64,
    /// State frames not published because of injected drops.
    pub dropped_frames: u64,
    /// Log events lost to a full ring.
    pub events_dropped: u64,
    /// The loop thread's heap allocations after warm-up, and the state frames it published meanwhile (each
    /// costs iceoryx2 one pooled block); `None` when the binary does not count allocations. Without those below.
    pub allocations_after_warmup: Option<(Counts, u64)>,
    /// The loop thread's allocations between ticks while the robot had stopped itself (a reflex: the driver's
    /// report of it, the robot's error recovery, a new motion's start), after warm-up; nothing is commanded then.
    pub allocations_while_robot_stopped: Counts,
    /// The robot's own side, from a driver that paced the loop (the fci backend's).
    pub robot: Option<Box<dyn DriverReport>>,
}

/// What a driver whose robot paced the loop adds to the HAL's exit report: lines printed under it, and a JSON
/// object under `robot` in `--report-json`. The loop knows no driver; each driver says what its robot saw.
pub trait DriverReport: std::fmt::Display + Send {
    fn to_json(&self) -> serde_json::Value;
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p);
        let ended = match self.ended {
            Ended::Duration => "its duration ended".to_string(),
            Ended::Signal => "a termination request".to_string(),
            Ended::BackendFailed(e) => format!("{e} (braked to rest first)"),
            Ended::ConnectionLost => "the connection to the robot breaking (see below)".to_string(),
            Ended::NotTakenOver(why) => format!("refusing to take the arm over: {why}"),
        };
        writeln!(f, "mars-hal: {} ticks, ended by {ended}", self.ticks)?;
        writeln!(
            f,
            "  real-time: core {:?}, SCHED_FIFO {:?}, memory locked {:?}",
            self.realtime.core, self.realtime.sched_fifo, self.realtime.memory_locked
        )?;
        writeln!(
            f,
            "  {} p50 {} p99 {} p99.9 {} max {}; {} overruns",
            if self.paced_by_robot { "robot state later than its period µs:" } else { "wake-up lateness µs:" },
            q(&self.wake_late_us, 0.5),
            q(&self.wake_late_us, 0.99),
            q(&self.wake_late_us, 0.999),
            self.wake_late_us.max(),
            self.overruns
        )?;
        writeln!(
            f,
            "  {} p50 {} p99 {} p99.9 {} max {}",
            if self.paced_by_robot { "robot state in → command out µs:" } else { "work per tick µs:   " },
            q(&self.work_us, 0.5),
            q(&self.work_us, 0.99),
            q(&self.work_us, 0.999),
            self.work_us.max()
        )?;
        let o = &self.overlong;
        write!(
            f,
            "  ticks that blocked: {}; others answering later than the {} µs period: {} computing, {} held up (off the \
             CPU, or in the driver and kernel after the tick)",
            o.blocked,
            self.period.as_micros(),
            o.computing,
            o.held_up
        )?;
        if let Some(l) = self.longest {
            write!(
                f,
                "; the longest: tick {}, {} µs ({} µs of the tick's own CPU time)",
                l.tick, l.wall_us, l.tick_cpu_us
            )?;
        }
        writeln!(f)?;
        if !self.computing_ticks.is_empty() {
            // For a test to ask the kernel what else ran on the core then (CLOCK_MONOTONIC ns).
            let ticks: Vec<String> = self
                .computing_ticks
                .iter()
                .map(|c| format!("{}+{}/{}", c.start_ns, c.wall_us, c.tick_cpu_us))
                .collect();
            writeln!(f, "  computing ticks (monotonic start ns+µs taken/µs of CPU): {}", ticks.join(" "))?;
        }
        writeln!(
            f,
            "  commands: {} rejected, {} clamped, {} wrong schema, {} late for their tick, {} more stepping from \
             a setpoint timing moved; {} gripper moves",
            self.rejected,
            self.clamped,
            self.schema_refusals,
            self.late_commands,
            self.timing_steps,
            self.gripper_moves
        )?;
        writeln!(
            f,
            "  safety filter last resorts: {} position-guard stops, {} steps with no feasible acceleration",
            self.position_guard_hits, self.infeasible_steps
        )?;
        let e = &self.errors;
        writeln!(
            f,
            "  errors (each braked and held): backend read {} apply {} gripper {}; ports receive {} send {}",
            e.read, e.apply, e.gripper, e.receive, e.send
        )?;
        match self.allocations_after_warmup {
            Some((c, sent)) => writeln!(
                f,
                "  loop allocations after warm-up: {} system-allocator calls, {} pooled blocks for {sent} frames sent{}",
                c.system,
                c.pooled,
                match self.allocations_while_robot_stopped {
                    Counts { system: 0, pooled: 0 } => String::new(),
                    a => format!(
                        " (and {} system-allocator calls, {} pooled blocks between ticks while the robot had stopped \
                         itself)",
                        a.system, a.pooled
                    ),
                }
            )?,
            None => writeln!(
                f,
                "  loop allocations: not counted (no counting allocator in this binary, or the run ended within its \
                 warm-up)"
            )?,
        }
        write!(
            f,
            "  {} state frames dropped by fault injection, {} log events dropped",
            self.dropped_frames, self.events_dropped
        )?;
        if let Some(r) = &self.robot {
            write!(f, "\n{r}")?;
        }
        Ok(())
    }
}

/// The HAL's side of one run, between the robot's reads: its ports, control logic, counters and histograms. A
/// driver calls [`HalLoop::tick`] once per period — [`run`] after its own absolute-deadline timer (the sim), the
/// fci backend inside the robot's 1 kHz callback (the robot paces the loop) — and [`HalLoop::finish`] at the end.
pub struct HalLoop {
    pub control: HalControl,
    // Ports and their node (kept alive for as long as the ports are used).
    state_out: StateWriter,
    commands: CommandReader,
    controller: PeerWatch,
    _node: iceoryx2::node::Node<iceoryx2::service::ipc::Service>,
    heartbeat: HeartbeatThread,
    ev: EventSender,
    logger: EventLogger,
    term: Arc<AtomicBool>,
    stop: Option<Arc<AtomicBool>>,
    brake_before_exit: bool,
    duration: Option<Duration>,
    started: Instant,
    timeout_ms: u64,
    ticks: Arc<AtomicU64>,
    tick: u64,
    sent: u64,
    dropped_frames: u64,
    losses_seen: u64,
    /// The tick at which the warm-up ends (see [`WARMUP_TICKS`]).
    warmup_ends: u64,
    /// A command has been received (a controller has connected).
    commanded: bool,
    at_warmup: Option<(Counts, u64)>,
    at_last_tick: Option<(Counts, u64)>,
    /// The robot stopped itself after the last tick: the allocations until the next are the reflex path's.
    robot_stopped: bool,
    while_robot_stopped: Counts,
    /// The measurement the start was judged on: tick 0 reports it instead of reading anew.
    first: Option<Measurement>,
    pub realtime: RtStatus,
    /// Lateness of each tick's start: past the timer's deadline, or past the robot's period.
    pub late_us: Histogram<u64>,
    pub work_us: Histogram<u64>,
    /// Ticks that blocked or overran (see [`mars_rt::overlong`]).
    ticks_timed: TickAccount,
}

/// What the loop should do after a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    Continue,
    End(Ended),
}

impl HalLoop {
    /// Takes over the arm as `first` measured it (or refuses: a [`crate::control::StartError`], nothing
    /// commanded), opens the ports, the heartbeat and the logger, and sets the calling thread up for real time.
    pub fn start(profile: &Profile, first: Measurement, opts: &RunOptions) -> anyhow::Result<Self> {
        let control = HalControl::start(profile, &first)?;
        let ns = RobotNamespace::new(&opts.robot)?;
        let (node, cleaned) = create_node(&format!("mars-hal-{}", opts.robot))?;
        if cleaned > 0 {
            info!("cleaned up {cleaned} dead iceoryx2 node(s)");
        }
        let state_out = StateWriter::new(&node, &ns)?;
        let commands = CommandReader::new(&node, &ns)?;
        // Liveness: a WaitSet watch on the controller's heartbeat tells within milliseconds when its process died
        // (in addition to the command timeout); ours is beaten by a thread of its own while the tick count grows.
        let controller = PeerWatch::controller(&ns)?;
        let ticks = Arc::new(AtomicU64::new(0));
        let progress = ticks.clone();
        let heartbeat =
            HeartbeatThread::start(&opts.robot, Side::Hal, &format!("mars-hal-{}", opts.robot), move || {
                progress.load(Ordering::Acquire)
            })
            .context("starting the liveness heartbeat")?;
        // Termination requests set a flag the loop reads. Registered after the ports: iceoryx2 installs its own
        // SIGINT/SIGTERM handlers when a node is made (replacing what was there), and signal-hook chains to them.
        let term = Arc::new(AtomicBool::new(false));
        for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
            signal_hook::flag::register(sig, term.clone()).context("registering the termination handler")?;
        }
        let (ev, logger) = EventLogger::start(1024, Duration::from_millis(20), |e| warn!("{e}"))?;
        let realtime = setup_realtime("hal", opts.core, opts.rt_priority, opts.lock_memory);
        if opts.core.is_some() && realtime.core.is_none() {
            anyhow::bail!("could not pin the HAL loop to core {:?}", opts.core);
        }
        alloc_count::init_rt_pool();
        info!(
            robot = %opts.robot, rate_hz = profile.rate_hz, joints = profile.joints,
            start = ?&first.position[..profile.joints], "mars-hal running"
        );
        Ok(Self {
            control,
            state_out,
            commands,
            controller,
            _node: node,
            heartbeat,
            ev,
            logger,
            term,
            stop: opts.stop.clone(),
            brake_before_exit: opts.brake_before_exit,
            duration: opts.duration,
            started: Instant::now(),
            timeout_ms: profile.command_timeout_ms as u64,
            ticks,
            tick: 0,
            sent: 0,
            dropped_frames: 0,
            losses_seen: 0,
            warmup_ends: WARMUP_TICKS,
            commanded: false,
            at_warmup: None,
            at_last_tick: None,
            robot_stopped: false,
            while_robot_stopped: Counts::default(),
            first: Some(first),
            realtime,
            late_us: Histogram::new_with_bounds(1, 10_000_000, 3)?,
            work_us: Histogram::new_with_bounds(1, 10_000_000, 3)?,
            ticks_timed: TickAccount::new(Duration::from_secs_f64(profile.period_s())),
        })
    }

    /// Ticks so far.
    pub fn ticks(&self) -> u64 {
        self.tick
    }

    /// Takes the arm over again as `m` measures it, a newer measurement than the one it started from (a robot's
    /// first state of a motion): the setpoint is held there, and the next tick reads the backend.
    pub fn take_over_at(&mut self, m: &Measurement) -> Result<(), crate::control::StartError> {
        self.first = None;
        self.control.resume_from(m)
    }

    /// Logs `event` off the loop thread (a driver's own events between ticks: see [`crate::events`]).
    pub fn log(&mut self, event: crate::events::LoopEvent) {
        self.ev.send(event);
    }

    /// The robot stopped itself: hold (see [`HalControl::on_robot_fault`]). Until a tick finds the robot taken
    /// over again, what the thread allocates between ticks is counted apart (see [`Report`]).
    pub fn on_robot_fault(&mut self) {
        self.control.on_robot_fault(&mut self.ev);
        self.robot_stopped = true;
    }

    /// While the robot is stopped: adds what the thread allocated since the last tick ended to the count apart.
    fn count_apart_while_robot_stopped(&mut self) {
        if !self.robot_stopped {
            return;
        }
        if let (Some(_), Some((last, _)), Some(now)) = (self.at_warmup, self.at_last_tick, alloc_count::thread_counts())
        {
            self.while_robot_stopped.system += now.system - last.system;
            self.while_robot_stopped.pooled += now.pooled - last.pooled;
        }
        self.robot_stopped = self.control.robot_fault();
    }

    /// One tick that began at `woke`: read the backend, take the commands, filter, apply, publish the frame.
    /// Allocates nothing but iceoryx2's pooled block for the frame.
    pub fn tick(&mut self, backend: &mut dyn Backend, woke: Stamp) -> Next {
        self.ticks_timed.begin(woke);
        self.count_apart_while_robot_stopped();
        let (control, ev) = (&mut self.control, &mut self.ev);
        // Frames carry CLOCK_MONOTONIC time, which the controller shares: it computes state ages from it.
        let now_ns = monotonic_ns();
        control.begin_tick(now_ns);

        // 1. Measure.
        control.on_read(self.first.take().map_or_else(|| backend.read(), Ok), ev);
        // 2. Commands: every frame is judged (so every bad one is counted); the newest valid one wins.
        loop {
            match self.commands.receive() {
                Ok(None) => break,
                Ok(Some(cmd)) => {
                    control.on_command(&cmd, ev);
                    if !self.commanded {
                        self.commanded = true;
                        self.warmup_ends = self.warmup_ends.max(self.tick + WARMUP_TICKS);
                        self.at_warmup = None;
                    }
                }
                Err(e) => {
                    control.on_receive_error(e, ev);
                    if matches!(e, FrameReceiveError::Port(_)) {
                        break;
                    }
                }
            }
        }
        let losses = self.controller.losses();
        if losses != self.losses_seen {
            self.losses_seen = losses;
            control.on_controller_lost(self.controller.peer(), ev);
        }
        // 3. Setpoint (filtered) → backend.
        let step = control.step(self.timeout_ms, ev);
        let (applied, gripper) = (backend.apply(step.setpoint), step.gripper);
        control.on_apply(applied, ev);
        if let Some(g) = gripper {
            let moved = backend.move_gripper(g);
            control.on_gripper(moved, ev);
        }
        let injected = backend.loop_faults();
        if injected.crash {
            // Injected crash: die like a segfault would, without unwinding, reporting or releasing anything.
            eprintln!("mars-hal: injected crash at tick {}", self.tick);
            std::process::abort();
        }

        // 4. State frame.
        let mut st = control.state_frame(now_ns);
        let timed = self.ticks_timed.counts();
        st.ticks_blocked = timed.blocked;
        st.overlong_ticks_computing = timed.computing;
        st.overlong_ticks_held_up = timed.held_up;
        if !injected.late.is_zero() {
            std::thread::sleep(injected.late);
        }
        if injected.drop_frame {
            self.dropped_frames += 1;
        } else {
            // iceoryx2 allocates one small block per sample: from the real-time pool, and only here.
            let result = {
                let _pool = RtPoolScope::enter();
                self.state_out.send(&st)
            };
            self.sent += u64::from(result.is_ok());
            control.on_sent(result, ev);
        }
        if !injected.stall.is_zero() {
            ev.send(crate::events::LoopEvent::InjectedStall { ms: injected.stall.as_millis() as u64, tick: self.tick });
            std::thread::sleep(injected.stall);
        }
        self.tick += 1;
        self.ticks.store(self.tick, Ordering::Release);
        self.work_us.saturating_record(woke.at.elapsed().as_micros() as u64);
        self.ticks_timed.end(Stamp::now(), !(injected.late.is_zero() && injected.stall.is_zero()));
        if self.tick == self.warmup_ends {
            self.at_warmup = alloc_count::warmed_up().map(|c| (c, self.sent));
        }
        // The counts at the end of every tick: what a driver does after the last one (franka-rs finishing a
        // motion allocates) is not the loop's.
        self.at_last_tick = alloc_count::thread_counts().map(|c| (c, self.sent));
        self.next()
    }

    /// Whether the run ends now: a fatal error at rest, the duration, a termination request (at rest first when
    /// the driver releases a real robot).
    fn next(&mut self) -> Next {
        if let Some(e) = self.control.exit_reason() {
            return Next::End(Ended::BackendFailed(e));
        }
        let ending = if self.duration.is_some_and(|d| self.started.elapsed() >= d) {
            Some(Ended::Duration)
        } else if self.term.load(Ordering::Acquire) || self.stop.as_ref().is_some_and(|s| s.load(Ordering::Acquire)) {
            Some(Ended::Signal)
        } else {
            None
        };
        match ending {
            None => Next::Continue,
            Some(e) if !self.brake_before_exit || self.control.robot_fault() => Next::End(e),
            Some(e) => {
                self.control.begin_stop();
                if self.control.stopped() { Next::End(e) } else { Next::Continue }
            }
        }
    }

    /// Whether a termination was requested (SIGTERM/SIGINT or the options' flag), for drivers that wait between
    /// ticks.
    pub fn stop_requested(&self) -> bool {
        self.term.load(Ordering::Acquire) || self.stop.as_ref().is_some_and(|s| s.load(Ordering::Acquire))
    }

    /// Ends the run: stops the logger and the heartbeat (the controller sees this HAL leave) and reports.
    pub fn finish(mut self, ended: Ended, overruns: u64, robot: Option<Box<dyn DriverReport>>) -> Report {
        self.ticks_timed.finish();
        alloc_count::loop_ended();
        let apart = self.while_robot_stopped;
        let allocations_after_warmup = self.at_warmup.zip(self.at_last_tick).map(|((c0, sent0), (c1, sent1))| {
            let counts =
                Counts { system: c1.system - c0.system - apart.system, pooled: c1.pooled - c0.pooled - apart.pooled };
            (counts, sent1 - sent0)
        });
        if ended == Ended::Signal {
            info!("termination requested");
        }
        drop(self.ev);
        let events_dropped = self.logger.finish();
        if events_dropped > 0 {
            warn!("{events_dropped} log events were dropped: the logger fell behind the loop");
        }
        self.heartbeat.finish();
        let control = &self.control;
        let f = control.filter();
        Report {
            ticks: self.tick,
            ended,
            realtime: self.realtime,
            paced_by_robot: robot.is_some(),
            wake_late_us: self.late_us,
            work_us: self.work_us,
            overruns,
            period: self.ticks_timed.period(),
            overlong: self.ticks_timed.counts(),
            longest: self.ticks_timed.longest(),
            computing_ticks: self.ticks_timed.computing_ticks().to_vec(),
            rejected: f.rejected,
            clamped: f.clamped,
            timing_steps: f.timing_steps,
            schema_refusals: control.schema_refusals,
            late_commands: control.late_commands,
            position_guard_hits: f.position_guard_hits,
            infeasible_steps: f.infeasible_steps,
            errors: control.errors,
            gripper_moves: control.gripper().moves_sent,
            dropped_frames: self.dropped_frames,
            events_dropped,
            allocations_after_warmup,
            allocations_while_robot_stopped: apart,
            robot,
        }
    }
}

/// Runs the HAL on its own absolute-deadline timer (the sim backend) until the duration ends, a termination
/// request, or a fatal backend error (after braking to rest). Refuses to start (a
/// [`crate::control::StartError`] in the error chain, nothing commanded) when the first measurement is unusable.
pub fn run(profile: &Profile, backend: &mut dyn Backend, opts: &RunOptions) -> anyhow::Result<Report> {
    // Read before anything else: the first setpoint is the measured position, or nothing is commanded.
    let first = backend.read().map_err(crate::control::StartError::Read)?;
    let mut hal = HalLoop::start(profile, first, opts)?;
    let mut ticker = Ticker::new(Duration::from_secs_f64(profile.period_s()));
    let ended = loop {
        let wake = ticker.wait();
        let woke = Stamp::now();
        hal.late_us.saturating_record(wake.late_ns / 1000);
        if let Next::End(e) = hal.tick(backend, woke) {
            break e;
        }
    };
    Ok(hal.finish(ended, ticker.missed_total(), None))
}
