//! The servo loop: where a state frame enters and a command leaves. Once per HAL period, on an absolute
//! CLOCK_MONOTONIC deadline: read the newest state frame, take the newest chunk and any request, run the
//! [`ServoTick`], send its command, record latencies. Nothing in the loop allocates (except iceoryx2's one
//! pooled block per sent sample, see [`crate::alloc_count`]), locks, prints or blocks (the sleep to the next
//! deadline is the only syscall that waits): `tests/alloc_free_tick.rs` runs it against a live HAL under a
//! counting allocator. The liveness heartbeat, a syscall, beats from [`mars_ipc::heartbeat_thread`] instead.

use std::sync::Arc;
use std::time::Duration;

use iceoryx2::prelude::*;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::node::create_node;
use mars_ipc::{
    CommandWriter, FrameReceiveError, FrameSendError, JointCommand, PeerWatch, RobotNamespace, RobotState, StateReader,
};

use crate::report::latency::{Channel, LoopCounters, Recorder};
use crate::rt::Ticker;
use crate::servo::chunk::TimedChunk;
use crate::servo::watchdog::SendWatch;
use crate::servo::{HalCounts, ServoCounters, ServoTick, StopCause, TickInput};
use crate::shared::{Observed, Phase, Request, Status};

/// The servo loop's ends of the wire. iceoryx2's ports are bound to the thread that made them, so the servo
/// thread opens them itself.
pub struct ServoWire {
    pub states: StateReader,
    pub commands: CommandWriter,
    pub hal: PeerWatch,
    /// Owns the ports' node; dropped last.
    _node: Node<ipc::Service>,
}

impl ServoWire {
    /// Opens the ports of `robot` and the HAL's liveness watch, that thread at SCHED_FIFO `watch_priority`.
    pub fn open(robot: &str, watch_priority: i32) -> anyhow::Result<Self> {
        let ns = RobotNamespace::new(robot)?;
        let (node, cleaned) = create_node(&format!("marsd-{robot}"))?;
        if cleaned > 0 {
            tracing::info!("cleaned up {cleaned} dead iceoryx2 node(s)");
        }
        // iceoryx2 installs its SIGINT/SIGTERM handlers lazily, at the first termination check of any node or
        // WaitSet in the process, and replaces (does not chain to) the handler in place. Trigger that here,
        // before `daemon::run` registers its handlers (which chain to iceoryx2's): left to the liveness watch
        // thread's first WaitSet call, it could come after them and silently disable SIGTERM/SIGINT.
        let _ = node.wait(Duration::ZERO);
        Ok(Self {
            states: StateReader::new(&node, &ns)?,
            commands: CommandWriter::new(&node, &ns)?,
            hal: PeerWatch::spawn_then(&ns, mars_ipc::Side::Hal, move || {
                crate::rt::setup_realtime("hal-watch", None, Some(watch_priority), false);
            })?,
            _node: node,
        })
    }
}

/// What the servo loop needs of the wire: [`ServoWire`], or a stand-in for the HAL in tests.
pub trait ServoPorts {
    /// The next state frame, if any.
    fn receive_state(&self) -> Result<Option<RobotState>, FrameReceiveError>;
    /// Sends a command; allocation-free on both outcomes (but iceoryx2's block per sample).
    fn send_command(&self, cmd: &JointCommand) -> Result<usize, FrameSendError>;
    /// Deaths and exits of the HAL the liveness watch has seen so far.
    fn hal_losses(&self) -> u64;
}

impl ServoPorts for ServoWire {
    fn receive_state(&self) -> Result<Option<RobotState>, FrameReceiveError> {
        self.states.receive()
    }
    fn send_command(&self, cmd: &JointCommand) -> Result<usize, FrameSendError> {
        self.commands.send(cmd)
    }
    fn hal_losses(&self) -> u64 {
        self.hal.losses()
    }
}

/// The loop's ends of the lock-free channels to the policy thread.
pub struct ServoChannels {
    pub chunks: triple_buffer::Output<TimedChunk>,
    pub observed: triple_buffer::Input<Observed>,
    /// Consumer end; the policy thread produces (see [`crate::shared`]).
    pub requests: rtrb::Consumer<Request>,
    pub status: Arc<Status>,
}

/// How the loop ended.
#[derive(Debug, Clone)]
pub struct ServoReport {
    pub cause: Option<StopCause>,
    pub counters: ServoCounters,
    pub frames: crate::servo::frame::FrameCounts,
    pub missed_periods: u64,
    /// Frames refused by the wire for a wrong schema version.
    pub schema_refusals: u64,
    /// Receive calls that failed in iceoryx2 itself (the port, not the frame).
    pub receive_port_errors: u64,
    pub send_errors: u64,
    /// The HAL's own counters since the handshake (from its state frames).
    pub hal: HalCounts,
    pub first_violation: Option<crate::servo::limits::Violation>,
    /// The smoother's first refusal, which tripped the loop (`Trip::Smoothing`).
    pub first_smoothing_error: Option<crate::servo::smoothing::SmoothingError>,
    /// A task acting on the table: what the servo's IK did with the policy's (x, y) references.
    pub effector: Option<crate::servo::effector::EffectorCounts>,
    /// Heap allocations on the servo thread from [`ALLOC_WARMUP_TICKS`] ticks after the handshake to the end
    /// (`None`: the process does not run the counting allocator, or the loop ended before). See
    /// [`crate::alloc_count`].
    pub allocations_after_warmup: Option<crate::alloc_count::Counts>,
    /// Samples sent over the same span: each may take exactly one pooled block (iceoryx2's bookkeeping).
    pub samples_sent_after_warmup: u64,
    pub ticks_counted: u64,
    /// The first [`CAPTURE_SPANS_KEPT`] adopted chunks, timed: what a stall of the machine must
    /// cover to explain one's capture → command (the histogram has only their lengths).
    pub capture_spans: Vec<CaptureSpan>,
}

/// Adopted chunks whose [`CaptureSpan`] the report keeps: an episode takes tens of chunks.
pub const CAPTURE_SPANS_KEPT: usize = 4096;

/// One adopted chunk: its observation's capture (camera or state frame) and the first command sent from it
/// (CLOCK_MONOTONIC ns).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct CaptureSpan {
    pub capture_ns: u64,
    pub command_ns: u64,
}

/// The loop's timing and its own fault limits.
#[derive(Debug, Clone, Copy)]
pub struct ServoLoopConfig {
    pub period: Duration,
    /// Latency histogram interval.
    pub interval: Duration,
    /// Command sends failing this many times in a row trip [`Trip::SendErrors`].
    pub max_consecutive_send_errors: u64,
}

/// Ticks after the handshake with the HAL (its first usable frame) from which the servo thread's allocations are
/// counted: iceoryx2 and the first chunk handoff have settled by then; every episode transition (reset, ready,
/// running, stop) comes later. Counted from the handshake, not from the loop's start: iceoryx2 sets up its
/// connection to the HAL's ports (allocating) in this loop's first receive and send after they appear, and a HAL
/// may appear long after marsd started — the fci HAL opens its ports only once it has connected to the robot
/// (franka-sim: ~1.5 s), the ros2 HAL once the robot's first feedback came. A peer that connects later still
/// (another subscriber to the commands) costs iceoryx2 the same set-up in the loop, and is counted.
pub const ALLOC_WARMUP_TICKS: u64 = 500;

/// Where in the HAL's period the servo ticks: this long after the HAL stamped its frame. The frame is then
/// published (the HAL's work is ~10 µs), and the command has the rest of the period to reach the HAL before its
/// next tick, so every HAL tick gets exactly one new command — as libfranka's controller answers every robot
/// packet. Two free-running 1 kHz loops would drift through each other's phase, and every slip would hand the
/// HAL two commands in one tick and none in the next.
const PHASE_OFFSET_NS: u64 = 300_000;
/// Fraction of the phase error corrected per tick: smooths the HAL's wake-up jitter out of the lock.
const PHASE_GAIN: f64 = 1.0 / 16.0;

/// Nudges the ticker so that its deadlines fall `PHASE_OFFSET_NS` after the HAL's ticks.
fn phase_lock(ticker: &mut Ticker, frame_ns: u64, deadline_ns: u64, period_ns: u64) {
    // Phase error of this tick's deadline against the frame's tick + offset, wrapped to ±half a period.
    let p = period_ns as i64;
    let raw = (frame_ns + PHASE_OFFSET_NS) as i64 - deadline_ns as i64;
    let err = (raw % p + p + p / 2) % p - p / 2;
    ticker.shift((err as f64 * PHASE_GAIN) as i64);
}

/// How long a stopped loop waits for the liveness watch to explain a stale-state stop. Its verdict comes about a
/// millisecond after the kernel has finished the HAL's process, and that exit alone took 18–95 ms after a
/// SIGKILL here (the HAL's locked memory freed, its files closed; `tests/hil.rs` prints it). Nothing is
/// commanded meanwhile: the HAL, if alive, holds on its own `command_timeout_ms` after the last command.
const LIVENESS_GRACE: Duration = Duration::from_millis(500);

/// State frames the loop could not read: another schema version, or a port error.
#[derive(Default)]
struct ReceiveRefusals {
    schema: u64,
    port_errors: u64,
}

/// The newest state frame: older ones queued behind it are superseded.
fn newest_state(wire: &impl ServoPorts, tick: &mut ServoTick, refusals: &mut ReceiveRefusals) -> Option<RobotState> {
    let mut newest = None;
    loop {
        match wire.receive_state() {
            Ok(Some(s)) => {
                tick.note_frame_timing(&s);
                newest = Some(s);
            }
            Ok(None) => return newest,
            // A frame of another schema version is refused and the next one read; a port error ends this tick's
            // reading (the stale-state watchdog trips if it persists).
            Err(FrameReceiveError::Schema(_)) => refusals.schema += 1,
            Err(FrameReceiveError::Port(_)) => {
                refusals.port_errors += 1;
                return newest;
            }
        }
    }
}

/// Sends a command; true if it went out. The only place the servo thread may allocate: iceoryx2's one block per
/// sample, from the RT pool.
fn send(wire: &impl ServoPorts, cmd: &JointCommand) -> bool {
    let _pool = crate::alloc_count::RtPoolScope::enter();
    wire.send_command(cmd).is_ok()
}

/// What the other threads read of the loop: phase, episode, ticks, missed periods, the trip, the handshake.
fn publish_status(st: &Status, tick: &ServoTick, missed_periods: u64, observed: bool) {
    use std::sync::atomic::Ordering;
    st.set_phase(tick.phase());
    st.episode.store(tick.episode(), Ordering::Release);
    st.ticks.store(tick.counters.ticks, Ordering::Release);
    st.missed_periods.store(missed_periods, Ordering::Relaxed);
    if let Some(StopCause::Trip(t)) = tick.stop_cause() {
        st.set_trip(t);
    }
    if observed && !st.hal_ready.load(Ordering::Relaxed) {
        st.hal_ready.store(true, Ordering::Release);
    }
}

/// Frames stop 20 ms after a HAL dies, but its liveness verdict can take as long: if the loop stopped on stale
/// state, give the watch a moment (outside the loop, nothing is commanded any more) to say whether the HAL died —
/// the report should name the cause, not the symptom.
fn await_liveness_verdict(tick: &mut ServoTick, wire: &impl ServoPorts, st: &Status, losses_at_start: u64) {
    if !matches!(tick.stop_cause(), Some(StopCause::Trip(crate::servo::watchdog::Trip::StaleState))) {
        return;
    }
    let until = std::time::Instant::now() + LIVENESS_GRACE;
    while std::time::Instant::now() < until && wire.hal_losses() == losses_at_start {
        std::thread::sleep(Duration::from_millis(1));
    }
    if wire.hal_losses() != losses_at_start {
        tick.blame_hal_death();
        st.set_trip(crate::servo::watchdog::Trip::HalDied);
    }
}

pub fn run_servo(
    mut tick: ServoTick,
    wire: impl ServoPorts,
    mut ch: ServoChannels,
    mut rec: Recorder,
    cfg: ServoLoopConfig,
) -> ServoReport {
    let mut ticker = Ticker::new(cfg.period);
    let period_ns = cfg.period.as_nanos() as u64;
    let losses_at_start = wire.hal_losses();
    let interval_ns = cfg.interval.as_nanos() as u64;
    let mut next_interval = monotonic_ns() + interval_ns;
    let mut refusals = ReceiveRefusals::default();
    let mut sends = SendWatch::new(cfg.max_consecutive_send_errors);
    // (allocation counts, samples sent, ticks) when the warm-up ended.
    let mut allocs_at_warmup: Option<(crate::alloc_count::Counts, u64, u64)> = None;
    let mut ticks_with_hal = 0u64;
    let mut capture_spans = Vec::with_capacity(CAPTURE_SPANS_KEPT);
    crate::alloc_count::init_rt_pool();
    loop {
        let wake = ticker.wait();
        let t0 = monotonic_ns();
        rec.record(Channel::WakeJitter, wake.late_ns);

        let newest = newest_state(&wire, &mut tick, &mut refusals);
        // A frame is judged by when it was read, not by the tick's wake-up: a thread held up between the two would
        // take a frame published meanwhile for younger than it is (and use a stale one).
        let read_ns = monotonic_ns();
        if let Some(s) = &newest {
            rec.record(Channel::StateAge, read_ns.saturating_sub(s.timestamp_ns));
            phase_lock(&mut ticker, s.timestamp_ns, wake.deadline_ns, period_ns);
        }
        let chunk = if ch.chunks.update() { Some(ch.chunks.output_buffer()) } else { None };
        let input = TickInput {
            now_ns: read_ns,
            missed: wake.missed,
            frame: newest.as_ref(),
            chunk,
            request: ch.requests.pop().ok(),
            stop_requested: ch.status.stop_requested.load(std::sync::atomic::Ordering::Acquire),
            hal_gone: wire.hal_losses() != losses_at_start,
        };
        let out = tick.tick(&input);

        if let Some(cmd) = &out.command {
            let sent = send(&wire, cmd);
            if let Some(trip) = sends.record(sent) {
                tick.trip(trip);
            }
            if sent && newest.is_some() {
                rec.record(Channel::StateToCommand, monotonic_ns().saturating_sub(read_ns));
            }
            if let (true, Some(capture_ns)) = (sent, out.adopted_capture_ns) {
                let command_ns = monotonic_ns();
                rec.record(Channel::CaptureToCommand, command_ns.saturating_sub(capture_ns));
                // Kept within the capacity reserved at start: no allocation.
                if capture_spans.len() < CAPTURE_SPANS_KEPT {
                    capture_spans.push(CaptureSpan { capture_ns, command_ns });
                }
            }
        }
        if let Some(obs) = out.observed {
            ch.observed.write(obs);
        }
        publish_status(&ch.status, &tick, ticker.missed_total(), out.observed.is_some());

        let done = monotonic_ns();
        rec.record(Channel::TickCompute, done.saturating_sub(t0));
        if done >= next_interval {
            rec.end_interval_with(done, LoopCounters { servo: tick.counters, hal: tick.hal_counts() });
            next_interval += interval_ns;
        }
        ticks_with_hal += u64::from(tick.phase() != Phase::WaitingForHal);
        if ticks_with_hal == ALLOC_WARMUP_TICKS {
            allocs_at_warmup = crate::alloc_count::warmed_up().map(|c| (c, sends.sent, tick.counters.ticks));
        }
        if tick.phase() == Phase::Finished {
            break;
        }
    }
    await_liveness_verdict(&mut tick, &wire, &ch.status, losses_at_start);
    let allocations_after_warmup = allocs_at_warmup.zip(crate::alloc_count::loop_ended()).map(|((start, ..), end)| {
        crate::alloc_count::Counts { system: end.system - start.system, pooled: end.pooled - start.pooled }
    });
    ServoReport {
        allocations_after_warmup,
        samples_sent_after_warmup: allocs_at_warmup.map_or(0, |(_, sent, _)| sends.sent - sent),
        ticks_counted: allocs_at_warmup.map_or(0, |(.., ticks)| tick.counters.ticks - ticks),
        cause: tick.stop_cause(),
        counters: tick.counters,
        frames: tick.frames().counts,
        missed_periods: ticker.missed_total(),
        schema_refusals: refusals.schema,
        receive_port_errors: refusals.port_errors,
        send_errors: sends.errors(),
        hal: tick.hal_counts(),
        first_violation: tick.first_violation,
        first_smoothing_error: tick.first_smoothing_error,
        effector: tick.effector().map(|e| e.counts),
        capture_spans,
    }
}
