//! The servo loop: where a state frame enters and a command leaves. Once per HAL period, on an absolute
//! CLOCK_MONOTONIC deadline: read the newest state frame, take the newest chunk and any request, run the
//! [`ServoTick`], send its command, beat the heartbeat, record latencies. Nothing in the loop allocates, locks,
//! prints or blocks (the sleep to the next deadline is the only syscall that waits): `tests/alloc_free_tick.rs`
//! runs it against a live HAL under a counting allocator.

use std::sync::Arc;
use std::time::Duration;

use crossbeam_queue::ArrayQueue;
use iceoryx2::prelude::*;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::liveness::Side;
use mars_ipc::node::create_node;
use mars_ipc::{CommandWriter, Heartbeat, PeerWatch, RobotNamespace, RobotState, StateReader};

use crate::chunk::TimedChunk;
use crate::latency::{Channel, Recorder};
use crate::rt::Ticker;
use crate::servo::{ServoCounters, ServoTick, StopCause, TickInput};
use crate::shared::{Observed, Phase, Request, Status};

/// The servo loop's ends of the wire. iceoryx2's ports are bound to the thread that made them, so the servo
/// thread opens them itself.
pub struct ServoWire {
    pub states: StateReader,
    pub commands: CommandWriter,
    pub heartbeat: Heartbeat,
    pub hal: PeerWatch,
    /// Owns the ports' node; dropped last.
    _node: Node<ipc::Service>,
}

impl ServoWire {
    pub fn open(robot: &str) -> anyhow::Result<Self> {
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
            heartbeat: Heartbeat::new(&node, &ns, Side::Controller)?,
            hal: PeerWatch::hal(&ns)?,
            _node: node,
        })
    }
}

/// The loop's ends of the lock-free channels to the policy thread.
pub struct ServoChannels {
    pub chunks: triple_buffer::Output<TimedChunk>,
    pub observed: triple_buffer::Input<Observed>,
    pub requests: Arc<ArrayQueue<Request>>,
    pub status: Arc<Status>,
}

/// How the loop ended.
#[derive(Debug, Clone, Copy)]
pub struct ServoReport {
    pub cause: Option<StopCause>,
    pub counters: ServoCounters,
    pub frames: crate::frame::FrameCounts,
    pub missed_periods: u64,
    /// Frames refused by the wire for a wrong schema version.
    pub schema_refusals: u64,
    pub send_errors: u64,
    /// Commands the HAL refused / clamped (from its state frames).
    pub hal_rejected: u64,
    pub hal_clamped: u64,
    pub first_violation: Option<crate::limits::Violation>,
    /// Heap allocations on the servo thread from tick [`ALLOC_WARMUP_TICKS`] to the end (`None`: the process
    /// does not run the counting allocator). See [`crate::alloc_count`].
    pub allocations_after_warmup: Option<crate::alloc_count::Counts>,
    pub ticks_counted: u64,
}

/// Ticks after which the servo thread's allocations are counted: iceoryx2 and the first chunk handoff have
/// settled by then; every episode transition (reset, ready, running, stop) comes later.
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

/// How long a stopped loop waits for the liveness watch to explain a stale-state stop (its verdict takes
/// 10–20 ms: the heartbeat deadline plus iceoryx2's dead-node clean-up).
const LIVENESS_GRACE: Duration = Duration::from_millis(100);

pub fn run_servo(
    mut tick: ServoTick,
    mut wire: ServoWire,
    mut ch: ServoChannels,
    mut rec: Recorder,
    period: Duration,
    interval: Duration,
) -> ServoReport {
    let mut ticker = Ticker::new(period);
    let period_ns = period.as_nanos() as u64;
    let losses_at_start = wire.hal.losses();
    let interval_ns = interval.as_nanos() as u64;
    let mut next_interval = monotonic_ns() + interval_ns;
    let (mut schema_refusals, mut send_errors) = (0u64, 0u64);
    let mut allocs_at_warmup: Option<crate::alloc_count::Counts> = None;
    crate::alloc_count::arm_rt_pool();
    loop {
        let wake = ticker.wait();
        let t0 = monotonic_ns();
        rec.record(Channel::WakeJitter, wake.late_ns);

        // Newest state frame: older ones queued behind it are superseded.
        let mut newest: Option<RobotState> = None;
        loop {
            match wire.states.receive() {
                Ok(Some(s)) => newest = Some(s),
                Ok(None) => break,
                Err(_) => {
                    schema_refusals += 1;
                    break;
                }
            }
        }
        if let Some(s) = &newest {
            rec.record(Channel::StateAge, t0.saturating_sub(s.timestamp_ns));
            phase_lock(&mut ticker, s.timestamp_ns, wake.deadline_ns, period_ns);
        }
        let chunk = if ch.chunks.update() { Some(ch.chunks.output_buffer()) } else { None };
        let input = TickInput {
            now_ns: t0,
            missed: wake.missed,
            frame: newest.as_ref(),
            chunk,
            request: ch.requests.pop(),
            stop_requested: ch.status.stop_requested.load(std::sync::atomic::Ordering::Acquire),
            hal_gone: wire.hal.losses() != losses_at_start,
        };
        let out = tick.tick(&input);

        if let Some(cmd) = &out.command {
            if wire.commands.send(cmd).is_err() {
                send_errors += 1;
            } else if newest.is_some() {
                rec.record(Channel::StateToCommand, monotonic_ns().saturating_sub(t0));
            }
        }
        if let Some(obs) = out.observed {
            ch.observed.write(obs);
        }
        let _ = wire.heartbeat.beat();

        let st = &ch.status;
        st.set_phase(tick.phase());
        st.episode.store(tick.episode(), std::sync::atomic::Ordering::Release);
        st.ticks.store(tick.counters.ticks, std::sync::atomic::Ordering::Release);
        if let Some(StopCause::Trip(t)) = tick.stop_cause() {
            st.set_trip(t);
        }
        if out.observed.is_some() && !st.hal_ready.load(std::sync::atomic::Ordering::Relaxed) {
            st.hal_ready.store(true, std::sync::atomic::Ordering::Release);
        }

        let done = monotonic_ns();
        rec.record(Channel::TickCompute, done.saturating_sub(t0));
        if done >= next_interval {
            rec.end_interval(done);
            next_interval += interval_ns;
        }
        if tick.counters.ticks == ALLOC_WARMUP_TICKS {
            allocs_at_warmup = crate::alloc_count::thread_counts();
        }
        if tick.phase() == Phase::Finished {
            break;
        }
    }
    // Frames stop 20 ms after a HAL dies, but its liveness verdict can take as long: if the loop stopped on
    // stale state, give the watch a moment (outside the loop, nothing is commanded any more) to say whether the
    // HAL died — the report should name the cause, not the symptom.
    if matches!(tick.stop_cause(), Some(StopCause::Trip(crate::watchdog::Trip::StaleState))) {
        let until = std::time::Instant::now() + LIVENESS_GRACE;
        while std::time::Instant::now() < until && wire.hal.losses() == losses_at_start {
            std::thread::sleep(Duration::from_millis(1));
        }
        if wire.hal.losses() != losses_at_start {
            tick.blame_hal_death();
            ch.status.set_trip(crate::watchdog::Trip::HalDied);
        }
    }
    let allocations_after_warmup = allocs_at_warmup.zip(crate::alloc_count::thread_counts()).map(|(start, end)| {
        crate::alloc_count::Counts { system: end.system - start.system, pooled: end.pooled - start.pooled }
    });
    ServoReport {
        allocations_after_warmup,
        ticks_counted: tick.counters.ticks.saturating_sub(ALLOC_WARMUP_TICKS),
        cause: tick.stop_cause(),
        counters: tick.counters,
        frames: tick.frames().counts,
        missed_periods: ticker.missed_total(),
        schema_refusals,
        send_errors,
        hal_rejected: tick.hal_limit_counts().0,
        hal_clamped: tick.hal_limit_counts().1,
        first_violation: tick.first_violation,
    }
}
