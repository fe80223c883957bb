//! The daemon's live view for `marsd top`: on the latency collector's thread, every interval a loop hands over
//! becomes a [`LiveStats`] frame on `mars/<robot>/live`, with the servo loop's status read from its atomics; with
//! `[remote]`, the same frame goes on the Zenoh network as well (`mars_remote::live`).
//!
//! Nothing here runs on a real-time thread. The loops already hand their interval histograms to the collector
//! (to write the interval log); this reads those histograms, the status atomics the daemon's notifier already
//! reads, and the counters the servo loop copies into the set it hands over (once per interval, not per tick).

use std::sync::Arc;
use std::sync::atomic::Ordering;

use hdrhistogram::Histogram;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::node::create_node;
use mars_ipc::{HalLive, LiveChannel, LiveStats, LiveWriter, RobotNamespace, ServoLive};
use tracing::warn;

use crate::report::latency::{Channel, IntervalView, LiveHook, OnInterval};
use crate::shared::Status;

/// What the frames say besides the histograms.
pub struct LiveSetup {
    pub robot: String,
    pub status: Arc<Status>,
    pub period_ns: u64,
    pub inference_budget_ns: u64,
    /// The camera the policy reads, if any (its frames' ages are the `camera_age` channel).
    pub camera: Option<String>,
    /// With `[remote]`: the same frames on the Zenoh network too (`<prefix>/<name>/live`), for a `marsd top
    /// --connect` on another machine.
    pub network: Option<mars_remote::live::LivePublisher>,
}

/// The collector hook that publishes the live view. The port is opened on the collector's thread at the first
/// interval (iceoryx2 ports stay on the thread that made them); if that fails, the run goes on without a live
/// view and says so once.
pub fn publisher(setup: LiveSetup) -> LiveHook {
    Box::new(move || on_interval(setup))
}

fn on_interval(setup: LiveSetup) -> OnInterval {
    let mut frame =
        LiveStats { period_ns: setup.period_ns, inference_budget_ns: setup.inference_budget_ns, ..Default::default() };
    frame.set_camera_name(setup.camera.as_deref().unwrap_or(""));
    let mut port = None;
    let (mut failed, mut network_failed) = (false, false);
    Box::new(move |view: &IntervalView<'_>, starved: u64| {
        if port.is_none() && !failed {
            match open(&setup.robot) {
                Ok(p) => port = Some(p),
                Err(e) => {
                    warn!("live view (marsd top) not available on this machine: {e:#}");
                    failed = true;
                }
            }
        }
        if failed && setup.network.is_none() {
            return;
        }
        let (start_ns, end_ns) = view.span_ns();
        for c in Channel::ALL {
            if let Some(h) = view.histogram(c) {
                frame.channels[c.index()] = summarize(c, h, setup.period_ns, start_ns, end_ns);
            }
        }
        let st = &setup.status;
        frame.seq += 1;
        frame.timestamp_ns = monotonic_ns();
        frame.phase = st.phase() as u32;
        frame.trip = st.trip().map_or(0, |t| t.code());
        frame.episode = st.episode.load(Ordering::Acquire);
        frame.ticks = st.ticks.load(Ordering::Acquire);
        frame.policy_beats = st.policy_beats.load(Ordering::Relaxed);
        frame.starved = starved;
        if let Some(c) = view.counters() {
            let (sv, h) = (&c.servo, &c.hal);
            frame.servo = ServoLive {
                commands_sent: sv.commands_sent,
                late_commands: sv.late_commands,
                resyncs: sv.resyncs,
                frameless_ticks: sv.frameless_ticks,
                actions_dropped: sv.actions_dropped,
                starved_ticks: sv.starved_ticks,
                limit_violations: sv.limit_violations,
            };
            frame.hal = HalLive {
                rejected: h.rejected,
                clamped: h.clamped,
                late: h.late,
                position_guard_hits: h.position_guard_hits,
                infeasible_steps: h.infeasible_steps,
                backend_errors: h.backend_errors,
            };
        }
        if let Some((_, writer)) = port.as_ref() {
            // Nobody watching is the normal case; a failed send only means this frame is not seen.
            let _ = writer.send(&frame);
        }
        if let Some(network) = setup.network.as_ref()
            && let Err(e) = network.put(&frame)
            && !network_failed
        {
            warn!("a live frame was not put on the network (said once): {e}");
            network_failed = true;
        }
    })
}

fn open(robot: &str) -> anyhow::Result<(iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>, LiveWriter)> {
    let ns = RobotNamespace::new(robot)?;
    let (node, _) = create_node(&format!("marsd-live-{robot}"))?;
    let writer = LiveWriter::new(&node, &ns)?;
    Ok((node, writer))
}

/// One channel's interval: percentiles, and the samples at or above the servo period (time channels).
pub fn summarize(c: Channel, h: &Histogram<u64>, period_ns: u64, start_ns: u64, end_ns: u64) -> LiveChannel {
    if h.is_empty() {
        return LiveChannel { start_ns, end_ns, ..Default::default() };
    }
    let over_period = if c.is_time() { h.count_between(period_ns, u64::MAX) } else { 0 };
    LiveChannel {
        count: h.len(),
        p50: h.value_at_quantile(0.5),
        p99: h.value_at_quantile(0.99),
        max: h.max(),
        over_period,
        start_ns,
        end_ns,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_channel_counts_the_samples_a_period_or_more_long() {
        let mut h = Channel::WakeJitter.new_histogram();
        for v in [10_000, 20_000, 999_000, 1_000_000, 3_000_000] {
            h.record(v).unwrap();
        }
        let live = summarize(Channel::WakeJitter, &h, 1_000_000, 5, 9);
        assert_eq!((live.count, live.over_period, live.start_ns, live.end_ns), (5, 2, 5, 9));
        assert!(live.max >= 3_000_000 && live.p50 >= 998_000 && live.p50 < 1_000_000, "{live:?}");
        let mut k = Channel::KUsed.new_histogram();
        k.record(8).unwrap();
        assert_eq!(summarize(Channel::KUsed, &k, 1_000_000, 0, 1).over_period, 0, "K is not a time");
        let empty = summarize(Channel::Inference, &Channel::Inference.new_histogram(), 1_000_000, 3, 4);
        assert_eq!((empty.count, empty.max, empty.start_ns), (0, 0, 3));
    }
}
