//! What the loop has to say, said off the loop thread.
//!
//! Formatting and writing a log line takes a lock and a `write` syscall that can block; a refused-command line
//! per tick at 1 kHz would do both a thousand times a second inside the control loop. So the loop only pushes a
//! small `Copy` value into a ring preallocated at start, and a logger thread drains it and logs. The ring is
//! `rtrb`'s single-producer/single-consumer ring: the HAL loop thread is its only producer, the logger thread its
//! only consumer, and a push is wait-free (it never waits for the consumer, even one preempted mid-pop, unlike a
//! multi-producer queue's slot hand-over). If the ring is full the event is dropped and counted, never waited for.

use crate::backend::BackendError;
use crate::safety::Refusal;
use crate::takeover::StartError;
use mars_ipc::liveness::Peer;
use mars_ipc::{FrameReceiveError, FrameSendError, SchemaMismatch};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

/// One thing worth a log line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LoopEvent {
    Refused {
        seq: u64,
        refusal: Refusal,
    },
    ReservedSession {
        seq: u64,
    },
    /// A command followed after clamping (the clamp policy): the limit it met. Only the first few are reported;
    /// all are counted.
    Clamped {
        seq: u64,
        reason: Refusal,
        /// The frame the command answered, and the newest frame the HAL had built.
        answered: u64,
        newest: u64,
        /// Frames since the setpoint was last re-synchronised to the robot's (fci), if ever.
        since_robot_resync: Option<u64>,
    },
    /// Only the first wrong-schema frame is reported; the rest are counted in the exit report.
    WrongSchema(SchemaMismatch),
    ControllerLost(Peer),
    CommandTimeout {
        ms: u64,
    },
    InjectedStall {
        ms: u64,
        tick: u64,
    },
    /// The first of a run of backend errors (the run's length comes with [`LoopEvent::BackendRecovered`]).
    Backend {
        error: BackendError,
        tick: u64,
    },
    BackendRecovered {
        errors: u64,
        tick: u64,
    },
    ReceiveFailed(FrameReceiveError),
    SendFailed(FrameSendError),
    /// An error ended the active session: the arm brakes to rest and holds.
    HoldingOnError,
    /// The backend failed for good: braking to rest, then the process exits.
    Fatal(BackendError),
    /// ros2: no feedback from the robot within the timeout (the arm's, or the gripper's when `arm` is false).
    FeedbackLost {
        arm: bool,
        age_ms: f64,
        timeout_ms: f64,
    },
    /// ros2: the feedback is back and the HAL took the arm over from its measured pose.
    FeedbackBack,
    /// ros2: the feedback is back but the arm cannot be taken over yet (only the first refusal of a run).
    RetakeRefused(StartError),
}

impl std::fmt::Display for LoopEvent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoopEvent::Refused { seq, refusal } => write!(f, "refused command {seq}: {refusal}"),
            LoopEvent::ReservedSession { seq } => write!(f, "refused command {seq}: session id 0 is reserved"),
            LoopEvent::Clamped { seq, reason, answered, newest, since_robot_resync } => {
                write!(f, "clamped command {seq} (answering frame {answered}, the newest {newest}")?;
                if let Some(k) = since_robot_resync {
                    write!(f, "; {k} frames after a resync to the robot's setpoint")?;
                }
                write!(f, ") to the limits: {reason}")
            }
            LoopEvent::WrongSchema(m) => write!(f, "refusing commands: {m}"),
            LoopEvent::ControllerLost(peer) => {
                write!(f, "the controller's process is gone ({peer:?}): braking to rest and holding")
            }
            LoopEvent::CommandTimeout { ms } => {
                write!(f, "no valid command for {ms} ms: braking to rest and holding; send a new session id to resume")
            }
            LoopEvent::InjectedStall { ms, tick } => write!(f, "injected stall of {ms} ms at tick {tick}"),
            LoopEvent::Backend { error, tick } => write!(f, "tick {tick}: {error}"),
            LoopEvent::BackendRecovered { errors, tick } => {
                write!(f, "tick {tick}: the backend works again after {errors} failed call(s)")
            }
            LoopEvent::ReceiveFailed(e) => write!(f, "receiving commands failed: {e}"),
            LoopEvent::SendFailed(e) => write!(f, "publishing the state failed: {e}"),
            LoopEvent::HoldingOnError => write!(
                f,
                "an error ended the controller's session: braking to rest and holding; a new session resumes once \
                 the errors stop"
            ),
            LoopEvent::Fatal(e) => write!(f, "{e}: braking to rest, then mars-hal exits"),
            LoopEvent::FeedbackLost { arm, age_ms, timeout_ms } => write!(
                f,
                "no {} feedback from the robot for {age_ms:.1} ms (timeout {timeout_ms} ms): holding; published the \
                 stop target (the last measured position) and nothing after it until the feedback is back",
                if *arm { "arm" } else { "gripper" }
            ),
            LoopEvent::FeedbackBack => {
                write!(f, "the robot's feedback is back: the HAL took the arm over from its measured pose")
            }
            LoopEvent::RetakeRefused(e) => {
                write!(f, "the robot's feedback is back but the arm cannot be taken over yet ({e}); holding it")
            }
        }
    }
}

struct Shared {
    dropped: AtomicU64,
    stop: AtomicBool,
}

/// The loop's end (the ring's producer): `send` never blocks or allocates.
pub struct EventSender {
    ring: rtrb::Producer<LoopEvent>,
    shared: Arc<Shared>,
}

impl EventSender {
    pub fn send(&mut self, event: LoopEvent) {
        if self.ring.push(event).is_err() {
            self.shared.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Events lost to a full queue so far.
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }
}

/// The logger thread; `finish` drains what is left and stops it.
pub struct EventLogger {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl EventLogger {
    /// A queue of `capacity` events and a thread that passes each to `sink` (e.g. a `tracing::warn!`), checking
    /// every `poll`.
    pub fn start(
        capacity: usize,
        poll: Duration,
        mut sink: impl FnMut(LoopEvent) + Send + 'static,
    ) -> std::io::Result<(EventSender, EventLogger)> {
        let shared = Arc::new(Shared { dropped: AtomicU64::new(0), stop: AtomicBool::new(false) });
        let (producer, mut consumer) = rtrb::RingBuffer::new(capacity.max(1));
        let worker = shared.clone();
        let thread = std::thread::Builder::new().name("mars-hal-log".into()).spawn(move || {
            loop {
                let stopping = worker.stop.load(Ordering::Acquire);
                while let Ok(e) = consumer.pop() {
                    sink(e);
                }
                if stopping {
                    break;
                }
                std::thread::sleep(poll);
            }
        })?;
        Ok((EventSender { ring: producer, shared: shared.clone() }, EventLogger { shared, thread: Some(thread) }))
    }

    /// Logs everything still queued, then joins the thread; returns how many events were dropped.
    pub fn finish(mut self) -> u64 {
        self.stop();
        self.shared.dropped.load(Ordering::Relaxed)
    }

    fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for EventLogger {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn every_event_reaches_the_sink_in_order_and_finish_drains_the_queue() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let sink_seen = seen.clone();
        let (mut tx, logger) =
            EventLogger::start(64, Duration::from_millis(50), move |e| sink_seen.lock().unwrap().push(e)).unwrap();
        for seq in 0..10 {
            tx.send(LoopEvent::ReservedSession { seq });
        }
        assert_eq!(logger.finish(), 0);
        let seen = seen.lock().unwrap();
        assert_eq!(*seen, (0..10).map(|seq| LoopEvent::ReservedSession { seq }).collect::<Vec<_>>());
    }

    #[test]
    fn a_full_queue_drops_and_counts_instead_of_blocking() {
        // A sink that is stuck until released: the sender must still return at once.
        let gate = Arc::new(Mutex::new(()));
        let held = gate.lock().unwrap();
        let sink_gate = gate.clone();
        let (mut tx, logger) =
            EventLogger::start(4, Duration::from_millis(1), move |_| drop(sink_gate.lock())).unwrap();
        let t0 = std::time::Instant::now();
        for seq in 0..100 {
            tx.send(LoopEvent::ReservedSession { seq });
        }
        assert!(t0.elapsed() < Duration::from_millis(500), "send blocked");
        // At most the queue's 4 plus the one the stuck sink holds got through.
        assert!(tx.dropped() >= 95, "dropped {}", tx.dropped());
        drop(held);
        assert!(logger.finish() >= 95);
    }

    #[test]
    fn events_read_as_sentences() {
        let e = LoopEvent::CommandTimeout { ms: 20 };
        assert!(e.to_string().contains("no valid command for 20 ms"));
    }
}
