//! marsd's liveness heartbeat, off the real-time thread.
//!
//! An iceoryx2 `notify` is a syscall; the SCHED_FIFO servo thread must not make one every few ticks. This
//! ordinary (SCHED_OTHER) thread beats instead, but only while the servo loop makes progress: it watches the
//! servo's tick counter ([`Status::ticks`]) and stays silent when it stops advancing, so a stuck servo still
//! looks dead to the HAL's liveness watch. Failed notifications are counted for the report.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use anyhow::Context;
use mars_ipc::liveness::{HEARTBEAT_PERIOD, Side};
use mars_ipc::node::create_node;
use mars_ipc::{Heartbeat, RobotNamespace};

use crate::shared::Status;

/// What the heartbeat thread did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct HeartbeatReport {
    /// Notifications attempted (one per period in which the servo's tick counter advanced).
    pub beats: u64,
    /// Periods without a beat because the servo's tick counter had not moved.
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
    /// Opens the controller's heartbeat (its own iceoryx2 node: ports belong to the thread that made them) and
    /// starts beating while `status.ticks` advances.
    pub fn start(robot: &str, status: Arc<Status>) -> anyhow::Result<Self> {
        let ns = RobotNamespace::new(robot)?;
        let node_name = format!("marsd-{robot}-heartbeat");
        let stop = Arc::new(AtomicBool::new(false));
        let (opened_tx, opened_rx) = std::sync::mpsc::channel::<anyhow::Result<()>>();
        let flag = stop.clone();
        let thread = std::thread::Builder::new()
            .name("marsd-heartbeat".into())
            .spawn(move || {
                let opened = create_node(&node_name)
                    .map_err(anyhow::Error::from)
                    .and_then(|(node, _)| Ok((Heartbeat::new(&node, &ns, Side::Controller)?, node)));
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
                beat_while_progressing(&mut heartbeat, &status, &flag)
            })
            .context("spawning the heartbeat thread")?;
        opened_rx.recv().context("the heartbeat thread died while opening its port")??;
        Ok(Self { stop, thread })
    }

    /// Stops beating (the HAL then sees this controller leave) and returns the counts.
    pub fn finish(self) -> HeartbeatReport {
        self.stop.store(true, Ordering::Release);
        self.thread.join().unwrap_or_default()
    }
}

fn beat_while_progressing(heartbeat: &mut Heartbeat, status: &Status, stop: &AtomicBool) -> HeartbeatReport {
    let mut report = HeartbeatReport::default();
    let mut last_ticks = None;
    while !stop.load(Ordering::Acquire) {
        let ticks = status.ticks.load(Ordering::Acquire);
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
