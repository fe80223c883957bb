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
use mars_rt::{RtStatus, Ticker, monotonic_ns, setup_realtime};
use tracing::{info, warn};

use crate::backend::{Backend, BackendError};
use crate::control::{ErrorCounts, HalControl};
use crate::events::EventLogger;
use crate::profile::Profile;

/// Ticks before the allocation count starts (iceoryx2 and the histograms settle in the first ones).
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
}

/// How the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    Duration,
    Signal,
    /// The backend failed for good; the arm had been braked to rest.
    BackendFailed(BackendError),
}

/// Loop timing and safety counters, printed at exit.
pub struct Report {
    pub ticks: u64,
    pub ended: Ended,
    pub realtime: RtStatus,
    /// Wake-up lateness past each tick's deadline (µs).
    pub wake_late_us: Histogram<u64>,
    /// Work per tick: read, commands, filter, backend, publish (µs).
    pub work_us: Histogram<u64>,
    /// Whole periods skipped because the loop fell behind.
    pub overruns: u64,
    pub rejected: u64,
    pub clamped: u64,
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
    /// costs iceoryx2 one pooled block); `None` when the binary does not count allocations.
    pub allocations_after_warmup: Option<(Counts, u64)>,
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p);
        let ended = match self.ended {
            Ended::Duration => "its duration ended".to_string(),
            Ended::Signal => "a termination request".to_string(),
            Ended::BackendFailed(e) => format!("{e} (braked to rest first)"),
        };
        writeln!(f, "mars-hal: {} ticks, ended by {ended}", self.ticks)?;
        writeln!(
            f,
            "  real-time: core {:?}, SCHED_FIFO {:?}, memory locked {:?}",
            self.realtime.core, self.realtime.sched_fifo, self.realtime.memory_locked
        )?;
        writeln!(
            f,
            "  wake-up lateness µs: p50 {} p99 {} p99.9 {} max {}; {} overruns",
            q(&self.wake_late_us, 0.5),
            q(&self.wake_late_us, 0.99),
            q(&self.wake_late_us, 0.999),
            self.wake_late_us.max(),
            self.overruns
        )?;
        writeln!(
            f,
            "  work per tick µs:    p50 {} p99 {} p99.9 {} max {}",
            q(&self.work_us, 0.5),
            q(&self.work_us, 0.99),
            q(&self.work_us, 0.999),
            self.work_us.max()
        )?;
        writeln!(
            f,
            "  commands: {} rejected, {} clamped, {} wrong schema, {} late for their tick; {} gripper moves",
            self.rejected, self.clamped, self.schema_refusals, self.late_commands, self.gripper_moves
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
                "  loop allocations after warm-up: {} system-allocator calls, {} pooled blocks for {sent} frames sent",
                c.system, c.pooled
            )?,
            None => writeln!(f, "  loop allocations: not counted (no counting allocator in this binary)")?,
        }
        write!(
            f,
            "  {} state frames dropped by fault injection, {} log events dropped",
            self.dropped_frames, self.events_dropped
        )
    }
}

/// Runs the HAL until the duration ends, a termination request, or a fatal backend error (after braking to
/// rest). Refuses to start (a [`crate::control::StartError`] in the error chain, nothing commanded) when the
/// first measurement is unusable.
pub fn run(profile: &Profile, backend: &mut dyn Backend, opts: &RunOptions) -> anyhow::Result<Report> {
    // 1. Read before anything else: the first setpoint is the measured position, or nothing is commanded.
    let first = backend.read().map_err(crate::control::StartError::Read)?;
    let mut control = HalControl::start(profile, &first)?;

    let ns = RobotNamespace::new(&opts.robot)?;
    let (node, cleaned) = create_node(&format!("mars-hal-{}", opts.robot))?;
    if cleaned > 0 {
        info!("cleaned up {cleaned} dead iceoryx2 node(s)");
    }
    let state_out = StateWriter::new(&node, &ns)?;
    let commands = CommandReader::new(&node, &ns)?;
    // Liveness: a WaitSet watch on the controller's heartbeat tells within milliseconds when its process died (in
    // addition to the command timeout); ours is beaten by a thread of its own while this loop's tick count grows.
    let controller = PeerWatch::controller(&ns)?;
    let ticks = Arc::new(AtomicU64::new(0));
    let progress = ticks.clone();
    let heartbeat = HeartbeatThread::start(&opts.robot, Side::Hal, &format!("mars-hal-{}", opts.robot), move || {
        progress.load(Ordering::Acquire)
    })
    .context("starting the liveness heartbeat")?;
    // Termination requests set a flag the loop reads. Registered after the ports: iceoryx2 installs its own
    // SIGINT/SIGTERM handlers when a node is made (replacing what was there), and signal-hook chains to them.
    let term = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, term.clone()).context("registering the termination handler")?;
    }
    let (mut ev, logger) = EventLogger::start(1024, Duration::from_millis(20), |e| warn!("{e}"))?;
    let realtime = setup_realtime("hal", opts.core, opts.rt_priority, opts.lock_memory);
    if opts.core.is_some() && realtime.core.is_none() {
        anyhow::bail!("could not pin the HAL loop to core {:?}", opts.core);
    }
    alloc_count::init_rt_pool();
    let mut wake_late_us = Histogram::new_with_bounds(1, 10_000_000, 3)?;
    let mut work_us = Histogram::new_with_bounds(1, 10_000_000, 3)?;
    let (n, timeout_ms) = (profile.joints, profile.command_timeout_ms as u64);
    info!(robot = %opts.robot, rate_hz = profile.rate_hz, joints = n, start = ?&first.position[..n], "mars-hal running");

    let mut ticker = Ticker::new(Duration::from_secs_f64(profile.period_s()));
    let start = Instant::now();
    let (mut tick, mut sent, mut dropped_frames, mut losses_seen) = (0u64, 0u64, 0u64, 0u64);
    let mut at_warmup: Option<(Counts, u64)> = None;
    // Tick 0 reports the measurement the start was judged on; every later tick reads anew.
    let mut first = Some(first);
    let ended = loop {
        let wake = ticker.wait();
        let woke = Instant::now();
        wake_late_us.saturating_record(wake.late_ns / 1000);
        // Frames carry CLOCK_MONOTONIC time, which the controller shares: it computes state ages from it.
        let now_ns = monotonic_ns();
        control.begin_tick(now_ns);

        // 1. Measure.
        control.on_read(first.take().map_or_else(|| backend.read(), Ok), &mut ev);
        // 2. Commands: every frame is judged (so every bad one is counted); the newest valid one wins.
        loop {
            match commands.receive() {
                Ok(None) => break,
                Ok(Some(cmd)) => control.on_command(&cmd, &mut ev),
                Err(e) => {
                    control.on_receive_error(e, &mut ev);
                    if matches!(e, FrameReceiveError::Port(_)) {
                        break;
                    }
                }
            }
        }
        let losses = controller.losses();
        if losses != losses_seen {
            losses_seen = losses;
            control.on_controller_lost(controller.peer(), &mut ev);
        }
        // 3. Setpoint (filtered) → backend.
        let step = control.step(timeout_ms, &mut ev);
        let (applied, gripper) = (backend.apply(step.setpoint), step.gripper);
        control.on_apply(applied, &mut ev);
        if let Some(g) = gripper {
            let moved = backend.move_gripper(g);
            control.on_gripper(moved, &mut ev);
        }
        let injected = backend.loop_faults();
        if injected.crash {
            // Injected crash: die like a segfault would, without unwinding, reporting or releasing anything.
            eprintln!("mars-hal: injected crash at tick {tick}");
            std::process::abort();
        }

        // 4. State frame.
        let st = control.state_frame(now_ns);
        if !injected.late.is_zero() {
            std::thread::sleep(injected.late);
        }
        if injected.drop_frame {
            dropped_frames += 1;
        } else {
            // iceoryx2 allocates one small block per sample: from the real-time pool, and only here.
            let result = {
                let _pool = RtPoolScope::enter();
                state_out.send(&st)
            };
            sent += u64::from(result.is_ok());
            control.on_sent(result, &mut ev);
        }
        if !injected.stall.is_zero() {
            ev.send(crate::events::LoopEvent::InjectedStall { ms: injected.stall.as_millis() as u64, tick });
            std::thread::sleep(injected.stall);
        }
        tick += 1;
        ticks.store(tick, Ordering::Release);
        work_us.saturating_record(woke.elapsed().as_micros() as u64);
        if tick == WARMUP_TICKS {
            at_warmup = alloc_count::thread_counts().map(|c| (c, sent));
        }

        if let Some(e) = control.exit_reason() {
            break Ended::BackendFailed(e);
        }
        if opts.duration.is_some_and(|d| start.elapsed() >= d) {
            break Ended::Duration;
        }
        if term.load(Ordering::Acquire) || opts.stop.as_ref().is_some_and(|s| s.load(Ordering::Acquire)) {
            break Ended::Signal;
        }
    };
    let allocations_after_warmup = at_warmup.zip(alloc_count::thread_counts()).map(|((c0, sent0), c1)| {
        (Counts { system: c1.system - c0.system, pooled: c1.pooled - c0.pooled }, sent - sent0)
    });
    if ended == Ended::Signal {
        info!("termination requested");
    }
    drop(ev);
    let events_dropped = logger.finish();
    if events_dropped > 0 {
        warn!("{events_dropped} log events were dropped: the logger fell behind the loop");
    }
    // Stopped after the loop: the controller sees this HAL leave.
    heartbeat.finish();
    let f = control.filter();
    Ok(Report {
        ticks: tick,
        ended,
        realtime,
        wake_late_us,
        work_us,
        overruns: ticker.missed_total(),
        rejected: f.rejected,
        clamped: f.clamped,
        schema_refusals: control.schema_refusals,
        late_commands: control.late_commands,
        position_guard_hits: f.position_guard_hits,
        infeasible_steps: f.infeasible_steps,
        errors: control.errors,
        gripper_moves: control.gripper().moves_sent,
        dropped_frames,
        events_dropped,
        allocations_after_warmup,
    })
}
