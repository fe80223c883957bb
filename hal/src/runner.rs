//! The `mars-hal` loop: once per period, take the controller's commands, filter them, step the backend and
//! publish the state; brake and hold when commands stop.

use std::time::{Duration, Instant};

use anyhow::Context;
use hdrhistogram::Histogram;
use mars_ipc::liveness::{Heartbeat, PeerWatch, Side};
use mars_ipc::node::create_node;
use mars_ipc::{
    CommandMode, CommandReader, FrameReceiveError, HoldReason, MAX_JOINTS, RobotNamespace, RobotState, StateWriter,
    status,
};
use tracing::{info, warn};

use crate::backend::Backend;
use crate::events::{EventLogger, LoopEvent};
use crate::profile::Profile;
use crate::safety::SafetyFilter;
use crate::session::{Decision, LoopClock, Mode, Supervisor};

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
}

/// Loop timing and safety counters, printed at exit.
pub struct Report {
    pub ticks: u64,
    /// Wake-up lateness past each tick's deadline (µs).
    pub wake_late_us: Histogram<u64>,
    /// Work per tick: commands, filter, backend, publish (µs).
    pub work_us: Histogram<u64>,
    pub overruns: u64,
    pub rejected: u64,
    pub clamped: u64,
    pub schema_refusals: u64,
    /// Commands that arrived after the tick they answered for (see `RobotState::late_commands`).
    pub late_commands: u64,
    /// Last resorts of the safety filter (see `RobotState::position_guard_hits` / `infeasible_steps`).
    pub position_guard_hits: u64,
    pub infeasible_steps: u64,
    /// State frames not published because of injected drops.
    pub dropped_frames: u64,
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p);
        writeln!(
            f,
            "mars-hal: {} ticks, {} overruns, {} state frames dropped by fault injection",
            self.ticks, self.overruns, self.dropped_frames
        )?;
        writeln!(
            f,
            "  wake-up lateness µs: p50 {} p99 {} p99.9 {} max {}",
            q(&self.wake_late_us, 0.5),
            q(&self.wake_late_us, 0.99),
            q(&self.wake_late_us, 0.999),
            self.wake_late_us.max()
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
            "  commands: {} rejected, {} clamped, {} wrong schema, {} late for their tick",
            self.rejected, self.clamped, self.schema_refusals, self.late_commands
        )?;
        write!(
            f,
            "  safety filter last resorts: {} position-guard stops, {} steps with no feasible acceleration",
            self.position_guard_hits, self.infeasible_steps
        )
    }
}

pub fn run(profile: &Profile, backend: &mut dyn Backend, opts: &RunOptions) -> anyhow::Result<Report> {
    if let Some(core) = opts.core {
        let ok = core_affinity::set_for_current(core_affinity::CoreId { id: core });
        anyhow::ensure!(ok, "could not pin the HAL loop to core {core}");
    }
    if let Some(p) = opts.rt_priority {
        let param = libc::sched_param { sched_priority: p };
        // SAFETY: plain syscall on the calling thread with a valid parameter struct.
        if unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) } != 0 {
            warn!(
                priority = p,
                "SCHED_FIFO refused: the HAL loop runs at normal priority (allow it with LimitRTPRIO in the unit, \
                 or CAP_SYS_NICE)"
            );
        }
    }
    let ns = RobotNamespace::new(&opts.robot)?;
    let (node, cleaned) = create_node(&format!("mars-hal-{}", opts.robot))?;
    if cleaned > 0 {
        info!("cleaned up {cleaned} dead iceoryx2 node(s)");
    }
    let state_out = StateWriter::new(&node, &ns)?;
    let commands = CommandReader::new(&node, &ns)?;
    // Liveness: our heartbeat for the controller, and a WaitSet watch on the controller's heartbeat that tells
    // within milliseconds when its process died (in addition to the command timeout).
    let mut heartbeat = Heartbeat::new(&node, &ns, Side::Hal)?;
    let controller = PeerWatch::controller(&ns)?;
    let mut losses_seen = 0;

    let n = profile.joints;
    let period = Duration::from_secs_f64(profile.period_s());
    let mut filter = SafetyFilter::new(profile, &profile.home);
    let mut supervisor = Supervisor::new(profile.timeout_ns());
    // Silence of the controller is judged in the loop's own time (see `LoopClock`): two periods at most per tick.
    let mut loop_clock = LoopClock::new(2 * period.as_nanos() as u64);
    let mut target: Option<[f64; MAX_JOINTS]> = None;
    let mut gripper = profile.gripper_min;
    let mut last_command_seq = 0;
    let mut schema_refusals = 0u64;
    let mut report = Report {
        ticks: 0,
        wake_late_us: Histogram::new_with_bounds(1, 10_000_000, 3)?,
        work_us: Histogram::new_with_bounds(1, 10_000_000, 3)?,
        overruns: 0,
        rejected: 0,
        clamped: 0,
        schema_refusals: 0,
        late_commands: 0,
        position_guard_hits: 0,
        infeasible_steps: 0,
        dropped_frames: 0,
    };
    info!(robot = %opts.robot, rate_hz = profile.rate_hz, joints = n, "mars-hal running");

    // Log lines are formatted and written by a logger thread, never in the loop (see `events`).
    let (events, logger) = EventLogger::start(1024, Duration::from_millis(20), |e| warn!("{e}"))?;
    let start = Instant::now();
    let mut deadline = start;
    loop {
        let woke = Instant::now();
        report.wake_late_us.saturating_record(woke.saturating_duration_since(deadline).as_micros() as u64);
        // Frames carry CLOCK_MONOTONIC time, which the controller shares: it computes state ages from it.
        let now_ns = mars_ipc::clock::monotonic_ns();
        let loop_ns = loop_clock.tick(now_ns);

        // 1. Commands: every frame is judged (so every bad one is counted); the newest valid one wins.
        loop {
            match commands.receive() {
                Ok(None) => break,
                Ok(Some(cmd)) => match filter.admit(&cmd) {
                    Err(refusal) => events.send(LoopEvent::Refused { seq: cmd.seq, refusal }),
                    Ok(t) => {
                        let hold = cmd.mode == CommandMode::Hold as u32;
                        if cmd.session == 0 {
                            filter.rejected += 1;
                            events.send(LoopEvent::ReservedSession { seq: cmd.seq });
                        } else if supervisor.on_command(cmd.session, hold, loop_ns) == Decision::Follow {
                            // The newest frame published so far is `report.ticks`: a command answering an
                            // older one missed the tick it was meant for (the cause of a clamp is then
                            // timing, not content, and the controller should count it as such).
                            if !hold && cmd.state_seq < report.ticks {
                                report.late_commands += 1;
                            }
                            target = if hold { None } else { Some(t.position) };
                            gripper = t.gripper;
                            last_command_seq = cmd.seq;
                        }
                    }
                },
                Err(FrameReceiveError::Schema(mismatch)) => {
                    schema_refusals += 1;
                    if schema_refusals == 1 {
                        events.send(LoopEvent::WrongSchema(mismatch));
                    }
                }
                Err(e) => return Err(e).context("receiving commands"),
            }
        }
        let losses = controller.losses();
        if losses != losses_seen {
            losses_seen = losses;
            if supervisor.on_controller_lost(loop_ns, 2 * period.as_nanos() as u64) {
                events.send(LoopEvent::ControllerLost(controller.peer()));
                target = None;
            }
        }
        if supervisor.on_tick(loop_ns) {
            events.send(LoopEvent::CommandTimeout { ms: profile.command_timeout_ms as u64 });
            target = None;
        }

        // 2. Setpoint (filtered) → backend → measurement.
        let follow = matches!(supervisor.mode(), Mode::Active { .. });
        let last_resorts_before = (filter.position_guard_hits, filter.infeasible_steps);
        let setpoint = filter.step(if follow { target.as_ref() } else { None });
        backend.apply(setpoint, gripper)?;
        let m = backend.read()?;
        let injected = backend.loop_faults();
        if injected.crash {
            // Injected crash: die like a segfault would, without unwinding, reporting or releasing anything.
            eprintln!("mars-hal: injected crash at tick {}", report.ticks);
            std::process::abort();
        }
        // The measurement is only reported, never fed back into the setpoint: a NaN or frozen sensor cannot
        // move the arm. It is flagged so the controller can refuse the frame.
        let mut fault_bits = m.fault;
        if m.position[..n].iter().chain(&m.velocity[..n]).any(|x| !x.is_finite()) {
            fault_bits |= mars_ipc::fault::NON_FINITE_MEASUREMENT;
        }

        // 3. State frame.
        let (session, hold_reason) = match supervisor.mode() {
            Mode::Idle => (0, HoldReason::NoSession),
            Mode::Active { session } => (session, HoldReason::None),
            Mode::Holding { session, reason } => (session, reason),
        };
        let mut st = RobotState {
            seq: report.ticks + 1,
            timestamp_ns: now_ns,
            session,
            last_command_seq,
            position: m.position,
            velocity: m.velocity,
            effort: m.effort,
            gripper: m.gripper,
            gripper_target: gripper,
            rejected_commands: filter.rejected,
            clamped_commands: filter.clamped,
            late_commands: report.late_commands,
            position_guard_hits: filter.position_guard_hits,
            infeasible_steps: filter.infeasible_steps,
            status: if follow { status::ACTIVE } else { status::HOLDING },
            fault: fault_bits,
            hold_reason: hold_reason as u32,
            num_joints: n as u32,
            ..Default::default()
        };
        st.applied_position[..n].copy_from_slice(filter.position());
        st.applied_velocity[..n].copy_from_slice(filter.velocity());
        st.applied_acceleration[..n].copy_from_slice(filter.acceleration());
        if filter.at_rest() {
            st.status |= status::AT_REST;
        }
        if (filter.position_guard_hits, filter.infeasible_steps) != last_resorts_before {
            st.status |= status::LAST_RESORT;
        }
        if !injected.late.is_zero() {
            std::thread::sleep(injected.late);
        }
        if injected.drop_frame {
            report.dropped_frames += 1;
        } else {
            state_out.send(&st)?;
        }
        if !injected.stall.is_zero() {
            events.send(LoopEvent::InjectedStall { ms: injected.stall.as_millis() as u64, tick: report.ticks });
            std::thread::sleep(injected.stall);
        }
        heartbeat.beat()?;
        report.ticks += 1;
        report.work_us.saturating_record(woke.elapsed().as_micros() as u64);

        if opts.duration.is_some_and(|d| start.elapsed() >= d) {
            break;
        }
        // 4. Sleep to the next deadline; if we are more than a period behind, skip ahead instead of bursting.
        deadline += period;
        let now = Instant::now();
        if now > deadline + period {
            report.overruns += 1;
            deadline = now;
        }
        // Any signal cuts the sleep short (SIGCONT after a SIGSTOP, a debugger, a child's SIGCHLD): only a
        // termination request (SIGTERM, SIGINT) ends the loop; otherwise the next tick comes early, which the
        // deadline arithmetic above absorbs.
        let termination = |r| matches!(r, Err(iceoryx2::node::NodeWaitFailure::TerminationRequest));
        let waited = node.wait(deadline.saturating_duration_since(now));
        if termination(waited) || (waited.is_err() && termination(node.wait(Duration::ZERO))) {
            info!("termination requested");
            break;
        }
    }
    let lost = logger.finish();
    if lost > 0 {
        warn!("{lost} log events were dropped: the logger fell behind the loop");
    }
    report.rejected = filter.rejected;
    report.clamped = filter.clamped;
    report.schema_refusals = schema_refusals;
    report.position_guard_hits = filter.position_guard_hits;
    report.infeasible_steps = filter.infeasible_steps;
    Ok(report)
}
