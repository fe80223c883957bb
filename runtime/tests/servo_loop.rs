//! The servo loop against a stand-in for the HAL (`ServoPorts`): the wire faults iceoryx2 rarely produces on
//! demand. Receive errors are counted by class (a wrong schema is a refusal, a port error is a port error), and
//! command sends failing `max_consecutive_send_errors` times in a row stop the loop with `Trip::SendErrors`.

use std::cell::Cell;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use mars_ipc::{FrameReceiveError, FrameSendError, JointCommand, RobotState, SchemaMismatch, status};
use mars_profile::Profile;
use mars_runtime::config::DaemonConfig;
use mars_runtime::report::latency::{Channel, Collector};
use mars_runtime::servo::chunk::TimedChunk;
use mars_runtime::servo::servo_loop::{ServoChannels, ServoLoopConfig, ServoPorts, ServoReport, run_servo};
use mars_runtime::servo::watchdog::Trip;
use mars_runtime::servo::{ServoTick, StopCause};
use mars_runtime::shared::{Observed, Status};

fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().unwrap()
}

const SESSION: u64 = 42;

/// A HAL that answers every receive with whatever `frame` makes of the call count, and sends with `send`.
struct FakeHal<F, S> {
    calls: Cell<u64>,
    frame: F,
    send: S,
}

impl<F, S> ServoPorts for FakeHal<F, S>
where
    F: Fn(u64) -> Result<Option<RobotState>, FrameReceiveError>,
    S: Fn(&JointCommand) -> Result<usize, FrameSendError>,
{
    fn receive_state(&self) -> Result<Option<RobotState>, FrameReceiveError> {
        let n = self.calls.get();
        self.calls.set(n + 1);
        (self.frame)(n)
    }
    fn send_command(&self, cmd: &JointCommand) -> Result<usize, FrameSendError> {
        (self.send)(cmd)
    }
    fn hal_losses(&self) -> u64 {
        0
    }
}

/// Runs the servo loop (on this thread, not real-time) against `hal` until it finishes.
fn run(hal: impl ServoPorts, status: Arc<Status>) -> ServoReport {
    let root = root();
    let cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
    let profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
    let out = std::env::temp_dir().join(format!("mars-servo-loop-test-{}-{}", std::process::id(), status_id(&status)));
    let collector = Collector::start(&out, Duration::from_millis(50)).unwrap();
    let rec = collector.recorder("servo", &[Channel::WakeJitter, Channel::TickCompute, Channel::StateAge], 8);
    let (_requests_in, requests) = rtrb::RingBuffer::new(4);
    let (_chunk_in, chunks) = triple_buffer::triple_buffer(&TimedChunk::default());
    let (observed, _obs_out) = triple_buffer::triple_buffer(&Observed::default());
    let ch = ServoChannels { chunks, observed, requests, status };
    let loop_cfg = ServoLoopConfig {
        period: Duration::from_millis(1),
        interval: Duration::from_secs(1),
        max_consecutive_send_errors: cfg.watchdog.max_consecutive_send_errors,
    };
    let report = run_servo(ServoTick::new(&cfg, &profile, SESSION).unwrap(), hal, ch, rec, loop_cfg);
    collector.finish();
    let _ = std::fs::remove_dir_all(out);
    report
}

fn status_id(s: &Arc<Status>) -> usize {
    Arc::as_ptr(s) as usize
}

/// A frame as the HAL would publish it now: at home, following `session` once it is non-zero.
fn hal_frame(seq: u64, session: u64) -> RobotState {
    let home: [f64; 7] = [0.0, -FRAC_PI_4, 0.0, -3.0 * FRAC_PI_4, 0.0, FRAC_PI_2, FRAC_PI_4];
    let mut s = RobotState {
        seq,
        timestamp_ns: mars_ipc::clock::monotonic_ns(),
        session,
        gripper: 0.07,
        gripper_target: 0.07,
        status: if session == 0 { status::HOLDING } else { status::ACTIVE | status::AT_REST },
        hold_reason: if session == 0 { 1 } else { 0 },
        num_joints: 7,
        ..Default::default()
    };
    s.position[..7].copy_from_slice(&home);
    s.applied_position[..7].copy_from_slice(&home);
    s
}

#[test]
fn receive_errors_are_counted_by_class() {
    let status = Arc::new(Status::default());
    let stop = status.clone();
    let mismatch = SchemaMismatch { found: 99, expected: mars_ipc::SCHEMA_VERSION };
    let port = FrameReceiveError::Port(iceoryx2::port::ReceiveError::ExceedsMaxBorrows);
    // Per tick the loop reads until `None` or a port error: this HAL sends a wrong-schema frame, then a port
    // error, every tick; never a usable frame. After 50 ticks a stop is requested (nothing was commanded).
    let hal = FakeHal {
        calls: Cell::new(0),
        frame: move |n: u64| {
            if n == 100 {
                stop.stop_requested.store(true, Ordering::Release);
            }
            if n.is_multiple_of(2) { Err(FrameReceiveError::Schema(mismatch)) } else { Err(port) }
        },
        send: |_: &JointCommand| panic!("nothing may be commanded without a usable frame"),
    };
    let r = run(hal, status);
    assert!(r.schema_refusals >= 50 && r.receive_port_errors >= 50, "{} {}", r.schema_refusals, r.receive_port_errors);
    assert_eq!(r.schema_refusals, r.receive_port_errors, "one of each per tick");
    assert_eq!((r.counters.commands_sent, r.send_errors), (0, 0));
}

#[test]
fn repeated_send_errors_trip_the_watchdog() {
    let cfg = DaemonConfig::load(&root().join("configs/marsd.toml")).unwrap();
    let limit = cfg.watchdog.max_consecutive_send_errors;
    let status = Arc::new(Status::default());
    // One fresh frame per tick (the loop reads until None: every other call is None), the HAL following us.
    let hal = FakeHal {
        calls: Cell::new(0),
        frame: |n: u64| Ok(n.is_multiple_of(2).then(|| hal_frame(n / 2 + 1, SESSION))),
        send: |_: &JointCommand| Err(FrameSendError::Loan(iceoryx2::port::LoanError::OutOfMemory)),
    };
    let r = run(hal, status.clone());
    assert_eq!(r.cause, Some(StopCause::Trip(Trip::SendErrors)), "{:?}", r.cause);
    assert_eq!(status.trip(), Some(Trip::SendErrors));
    assert!(r.send_errors >= limit, "{} errors, limit {limit}", r.send_errors);
}

#[test]
fn sends_that_fail_fewer_times_in_a_row_than_the_limit_do_not_trip() {
    let cfg = DaemonConfig::load(&root().join("configs/marsd.toml")).unwrap();
    let limit = cfg.watchdog.max_consecutive_send_errors;
    let status = Arc::new(Status::default());
    let stop = status.clone();
    let sent = Cell::new(0u64);
    let hal = FakeHal {
        calls: Cell::new(0),
        frame: move |n: u64| {
            if n == 2000 {
                stop.stop_requested.store(true, Ordering::Release);
            }
            Ok(n.is_multiple_of(2).then(|| hal_frame(n / 2 + 1, SESSION)))
        },
        // Every `limit`-th send succeeds: runs of limit − 1 failures.
        send: move |_: &JointCommand| {
            sent.set(sent.get() + 1);
            if sent.get().is_multiple_of(limit) {
                Ok(1)
            } else {
                Err(FrameSendError::Loan(iceoryx2::port::LoanError::OutOfMemory))
            }
        },
    };
    let r = run(hal, status);
    assert_eq!(r.cause, Some(StopCause::Signal), "{:?}", r.cause);
    assert!(r.send_errors > 5 * limit, "{}", r.send_errors);
}

/// hil.rs's late-frames test (CI, 2026-11-30): with every HAL frame published 5 ms after its stamp and
/// `stale_state_ms` = 3, marsd once used a frame and handshook. Its age was taken at the tick's wake-up, and the
/// thread, held up before it read, received a frame published after that. Here every frame arrives 3 ms into the
/// receive call, stamped 2 ms before the call began: 2 ms old by the wake-up, 5 ms when read. None may be used.
#[test]
fn a_frame_is_judged_stale_by_when_it_was_read_not_by_when_the_tick_woke() {
    let status = Arc::new(Status::default());
    let stop = status.clone();
    let hal = FakeHal {
        calls: Cell::new(0),
        frame: move |n: u64| {
            if n == 100 {
                stop.stop_requested.store(true, Ordering::Release);
            }
            if n % 2 == 1 {
                return Ok(None);
            }
            let began = mars_ipc::clock::monotonic_ns();
            std::thread::sleep(Duration::from_millis(3));
            Ok(Some(RobotState { timestamp_ns: began - 2_000_000, ..hal_frame(n + 1, 0) }))
        },
        send: |_: &JointCommand| panic!("nothing may be commanded on stale frames"),
    };
    let r = run(hal, status);
    assert_eq!(r.frames.used, 0, "{:?}", r.frames);
    assert!(r.frames.stale >= 40, "{:?}", r.frames);
    assert_eq!(r.counters.commands_sent, 0);
}

/// A first state the smoother cannot start from (a joint at 10⁶ rad, finite): the loop commands nothing, trips, and
/// its report keeps the smoother's own reason (the tick cannot log it; marsd logs it at the end).
#[test]
fn a_state_the_smoother_refuses_trips_with_its_reason_and_commands_nothing() {
    let status = Arc::new(Status::default());
    let stop = status.clone();
    let hal = FakeHal {
        calls: Cell::new(0),
        frame: move |n: u64| {
            if n == 400 {
                stop.stop_requested.store(true, Ordering::Release); // so a loop that never trips still ends
            }
            let mut f = hal_frame(n / 2 + 1, 0);
            (f.position[0], f.applied_position[0]) = (1e6, 1e6);
            Ok(n.is_multiple_of(2).then_some(f))
        },
        send: |_: &JointCommand| panic!("nothing may be commanded from a state the smoother refused"),
    };
    let r = run(hal, status);
    assert_eq!(r.cause, Some(StopCause::Trip(Trip::Smoothing)), "{:?}", r.cause);
    let e = r.first_smoothing_error.expect("the smoother's reason is kept");
    assert!(e.to_string().contains("position[0] = 1000000"), "{e}");
}
