//! A thread of `mars-hil demo` that watches the machine while marsd runs: it reads the HAL's state frames and
//! keeps the gaps in them (a HAL that published nothing for 15 ms, or as long in pauses, means the machine stalled), and samples the
//! hypervisor's steal time every 10 ms. When marsd then trips on a timing check, the demo looks here for a
//! stall around the trip ([`mars_runtime::report::stall::around_trip`]) and says so. Memory is bounded for endless runs.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use mars_ipc::node::create_node;
use mars_ipc::{RobotNamespace, StateReader};

use mars_runtime::report::stall::{self, FrameGap, GapFinder, StealSample};

/// Steal samples kept: the last minute at one per 10 ms (a trip is looked up right after it).
const STEAL_SAMPLES: usize = 6_000;
/// Pauses kept: the most recent ones (a very noisy minute has a few thousand).
const GAPS: usize = 10_000;
const STEAL_EVERY: Duration = Duration::from_millis(10);

#[derive(Debug, Default, Clone)]
pub struct Watched {
    pub gaps: VecDeque<FrameGap>,
    pub steal: VecDeque<StealSample>,
    /// Frames read, to tell "no gap" from "saw nothing".
    pub frames: u64,
}

pub struct StallWatch {
    stop: Arc<AtomicBool>,
    seen: Arc<Mutex<Watched>>,
    handle: Option<JoinHandle<()>>,
}

impl StallWatch {
    /// Starts watching `robot`'s state service (opened by this thread: iceoryx2 ports belong to their thread);
    /// `period_ms`: the HAL's period, so that its pauses ([`stall::PAUSE_PERIODS`]) are kept.
    pub fn start(robot: &str, period_ms: f64) -> anyhow::Result<Self> {
        let ns = RobotNamespace::new(robot)?;
        let stop = Arc::new(AtomicBool::new(false));
        let seen = Arc::new(Mutex::new(Watched::default()));
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (stop2, seen2, name) = (stop.clone(), seen.clone(), format!("demo-stall-watch-{robot}"));
        let handle = std::thread::Builder::new()
            .name("stall-watch".into())
            .spawn(move || {
                let opened = create_node(&name).map_err(anyhow::Error::from).and_then(|(node, _)| {
                    let reader = StateReader::new(&node, &ns)?;
                    Ok((node, reader))
                });
                let (_node, reader) = match opened {
                    Ok(o) => {
                        let _ = ready_tx.send(Ok(()));
                        o
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let mut finder = GapFinder::default();
                let mut next_steal = mars_ipc::clock::monotonic_ns();
                while !stop2.load(Ordering::Acquire) {
                    let mut new_gaps = Vec::new();
                    let mut frames = 0;
                    while let Ok(Some(s)) = reader.receive() {
                        frames += 1;
                        new_gaps.extend(finder.push(s.seq, s.timestamp_ns, stall::PAUSE_PERIODS * period_ms));
                    }
                    let now = mars_ipc::clock::monotonic_ns();
                    let sample = (now >= next_steal)
                        .then(|| {
                            next_steal = now + STEAL_EVERY.as_nanos() as u64;
                            stall::steal_ms().map(|steal_ms| StealSample { at_ns: now, steal_ms })
                        })
                        .flatten();
                    if frames > 0 || sample.is_some() {
                        let mut w = seen2.lock().unwrap_or_else(|p| p.into_inner());
                        w.frames += frames;
                        for g in new_gaps {
                            if w.gaps.len() == GAPS {
                                w.gaps.pop_front();
                            }
                            w.gaps.push_back(g);
                        }
                        if let Some(s) = sample {
                            if w.steal.len() == STEAL_SAMPLES {
                                w.steal.pop_front();
                            }
                            w.steal.push_back(s);
                        }
                    }
                    std::thread::sleep(Duration::from_micros(500));
                }
            })
            .context("starting the stall watch")?;
        ready_rx.recv().context("the stall watch ended before opening its port")??;
        Ok(Self { stop, seen, handle: Some(handle) })
    }

    /// Stops the thread (after one more steal sample) and returns what it saw.
    pub fn finish(mut self) -> Watched {
        std::thread::sleep(STEAL_EVERY * 2);
        self.stop.store(true, Ordering::Release);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
        std::mem::take(&mut *self.seen.lock().unwrap_or_else(|p| p.into_inner()))
    }
}

impl Drop for StallWatch {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
