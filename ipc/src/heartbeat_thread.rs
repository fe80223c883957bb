//! A side's liveness heartbeat, beaten from an ordinary thread instead of its real-time loop.
//!
//! An iceoryx2 `notify` is a syscall; a SCHED_FIFO loop (the HAL's, marsd's servo) must not make one every few
//! ticks. This ordinary (SCHED_OTHER) thread beats instead, but only while the loop makes progress: it reads the
//! loop's tick counter through `progress` and stays silent when it stops advancing, so a stuck loop still looks
//! dead to the other side's liveness watch. Failed notifications are counted for the report.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use crate::liveness::{HEARTBEAT_PERIOD, Heartbeat, Side};
use crate::names::RobotNamespace;
use crate::node::create_node;
use crate::wire::WireError;

/// What the heartbeat thread did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct HeartbeatReport {
    /// Notifications attempted (one per period in which the loop's tick counter advanced).
    pub beats: u64,
    /// Periods without a beat because the loop's tick counter had not moved.
    pub withheld: u64,
    /// Notifications iceoryx2 refused.
    pub errors: u64,
}

/// The running heartbeat thread.
pub struct HeartbeatThread {
    stop: Arc<AtomicBool>,
    thread: JoinHandle<HeartbeatReport>,
}

impl HeartbeatThread {
    /// Opens `side`'s heartbeat (on an iceoryx2 node of its own, `node_name`: ports belong to the thread that
    /// made them) and starts beating while the counter read by `progress` advances.
    pub fn start(
        robot: &str,
        side: Side,
        node_name: &str,
        progress: impl Fn() -> u64 + Send + 'static,
    ) -> Result<Self, WireError> {
        Self::start_then(robot, side, node_name, progress, || {})
    }

    /// As [`HeartbeatThread::start`], the thread first running `setup` (marsd raises it to a real-time priority
    /// there, so that a busy machine cannot silence a controller that is alive).
    pub fn start_then(
        robot: &str,
        side: Side,
        node_name: &str,
        progress: impl Fn() -> u64 + Send + 'static,
        setup: impl FnOnce() + Send + 'static,
    ) -> Result<Self, WireError> {
        let ns = RobotNamespace::new(robot)?;
        let node_name = node_name.to_owned();
        let stop = Arc::new(AtomicBool::new(false));
        let (opened_tx, opened_rx) = std::sync::mpsc::channel::<Result<(), WireError>>();
        let flag = stop.clone();
        let thread = std::thread::Builder::new()
            .name(format!("{node_name}-heartbeat"))
            .spawn(move || {
                setup();
                let opened =
                    create_node(&node_name).and_then(|(node, _)| Ok((Heartbeat::new(&node, &ns, side)?, node)));
                let (mut heartbeat, _node) = match opened {
                    Ok(h) => {
                        let _ = opened_tx.send(Ok(()));
                        h
                    }
                    Err(e) => {
                        let _ = opened_tx.send(Err(e));
                        return HeartbeatReport::default();
                    }
                };
                beat_while_progressing(&mut heartbeat, &progress, &flag)
            })
            .map_err(|e| WireError::Node(format!("spawning the heartbeat thread: {e}")))?;
        opened_rx.recv().map_err(|_| WireError::Node("the heartbeat thread died while opening its port".into()))??;
        Ok(Self { stop, thread })
    }

    /// Stops beating (the HAL then sees this controller leave) and returns the counts.
    pub fn finish(self) -> HeartbeatReport {
        self.stop.store(true, Ordering::Release);
        self.thread.join().unwrap_or_default()
    }
}

fn beat_while_progressing(
    heartbeat: &mut Heartbeat,
    progress: &impl Fn() -> u64,
    stop: &AtomicBool,
) -> HeartbeatReport {
    let mut report = HeartbeatReport::default();
    let mut last_ticks = None;
    while !stop.load(Ordering::Acquire) {
        let ticks = progress();
        if last_ticks != Some(ticks) {
            last_ticks = Some(ticks);
            report.beats += 1;
            if heartbeat.beat().is_err() {
                report.errors += 1;
            }
        } else {
            report.withheld += 1;
        }
        std::thread::sleep(HEARTBEAT_PERIOD);
    }
    report
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicU64;
    use std::time::{Duration, Instant};

    use crate::{Peer, PeerWatch};

    use super::*;

    /// Polls `cond` for up to `limit`.
    fn within(limit: Duration, cond: impl Fn() -> bool) -> bool {
        let until = Instant::now() + limit;
        while Instant::now() < until {
            if cond() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        cond()
    }

    #[test]
    fn beats_only_while_the_servo_advances_and_leaves_on_finish() {
        let robot = format!("t{}-heartbeat", std::process::id());
        let ns = RobotNamespace::new(&robot).unwrap();
        let hal_view = PeerWatch::controller(&ns).unwrap();
        let ticks = Arc::new(AtomicU64::new(0));
        let counter = ticks.clone();
        let heartbeat =
            HeartbeatThread::start(&robot, Side::Controller, "test", move || counter.load(Ordering::Acquire)).unwrap();

        // A servo that ticks: the HAL sees a live controller.
        let ticking = Arc::new(AtomicBool::new(true));
        let servo = {
            let (ticks, ticking) = (ticks.clone(), ticking.clone());
            std::thread::spawn(move || {
                while ticking.load(Ordering::Acquire) {
                    ticks.fetch_add(1, Ordering::Release);
                    std::thread::sleep(Duration::from_millis(1));
                }
            })
        };
        assert!(within(Duration::from_secs(2), || hal_view.peer() == Peer::Alive), "{:?}", hal_view.peer());
        // The beats go on while the servo ticks (counted below; a busy machine may delay one past the deadline,
        // which the next beat makes good).
        std::thread::sleep(Duration::from_millis(100));
        assert!(within(Duration::from_secs(2), || hal_view.peer() == Peer::Alive), "{:?}", hal_view.peer());

        // The servo stalls (its counter stops): no more beats, and the HAL's watch finds the deadline missed.
        ticking.store(false, Ordering::Release);
        servo.join().unwrap();
        assert!(within(Duration::from_secs(2), || hal_view.peer() == Peer::Late), "{:?}", hal_view.peer());

        let report = heartbeat.finish();
        assert!(report.beats > 10 && report.withheld > 0 && report.errors == 0, "{report:?}");
        assert!(within(Duration::from_secs(2), || hal_view.exits() == 1), "the HAL sees the controller leave");
    }
}
