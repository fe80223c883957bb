//! The policy loop's inference host (`[remote]`): each chunk is asked of the host first, within the time left less
//! the local engine's reserve; a chunk not back by then is the local engine's (or, with `on_miss = "rest"`, none:
//! the arm comes to rest), and the report says when each side took over and why. The host is asked again at every
//! chunk, so it resumes as soon as it answers.
//!
//! A request is sent ([`Remote::send`]) and its reply collected later ([`Remote::settle`]), so that a chunk asked
//! periods ahead (`[policy] ask_ahead_periods`) does not hold the policy loop up for longer than one period.

use std::time::Duration;

use hdrhistogram::Histogram;
use mars_remote::client::{PendingReply, RemoteError, RemotePolicy};
use mars_remote::clock::ClockEstimate;
use mars_remote::live::LivePublisher;
use mars_remote::wire::{Reply, Request, Status};
use serde::Serialize;

use crate::config::{DaemonConfig, OnMiss, PolicyLoopConfig, RemoteConfig};

/// Switches between host and local engine kept for the report.
pub const SWITCHES_KEPT: usize = 32;

/// The inference host as the policy loop uses it.
pub struct Remote {
    policy: RemotePolicy,
    reserve_ns: u64,
    /// Reused for every request (its vectors keep their capacity).
    request: Request,
    on_miss: OnMiss,
    /// Who gave the last chunk (None before the first).
    last: Option<Side>,
    in_flight: Option<InFlight>,
    round_trip_us: Histogram<u64>,
    pub report: RemoteReport,
}

/// Why a chunk was not the host's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Miss {
    /// No reply within the host's share of the time.
    Timeout,
    /// No host answers the key (none declared, or it left).
    NoHost,
    /// The host had it queued past its deadline.
    Expired,
    /// Anything else: an error reply, a malformed one, the engine's refusal.
    Error,
    /// No time was left for the host at all (the call started too late).
    NoTime,
}

/// Who gives the servo a chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Side {
    /// The inference host.
    Host,
    /// The robot's own engine (`[remote] on_miss = "local"`).
    Local,
    /// Nobody: the servo finishes its chunk and holds the last action (`on_miss = "rest"`).
    Rest,
}

/// One change of who computes the chunks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Switch {
    pub episode: u64,
    /// The policy period of the first chunk asked of the new side.
    pub period: u64,
    /// Robot clock (ns).
    pub at_ns: u64,
    pub to: Side,
    /// Why the host's chunk was missing (None when switching back to the host).
    pub miss: Option<Miss>,
}

/// What `[remote]` did in a run (in `summary.json` and marsd's report).
#[derive(Debug, Clone, Default, Serialize)]
pub struct RemoteReport {
    pub key: String,
    /// The host's clock against ours at start (None: no host answered then).
    pub clock: Option<ClockEstimate>,
    pub requests: u64,
    /// Chunks the host computed, those the local engine computed instead, and those nobody did (the arm rested);
    /// the misses by reason.
    pub host_chunks: u64,
    pub local_chunks: u64,
    pub rested: u64,
    pub timeouts: u64,
    pub no_host: u64,
    pub expired: u64,
    pub errors: u64,
    pub no_time: u64,
    /// Request sent → reply received, over the host's chunks (ms).
    pub round_trip_ms_p50: f64,
    pub round_trip_ms_p99: f64,
    pub round_trip_ms_max: f64,
    /// Requests still on their way when their episode ended (neither side's chunk).
    pub abandoned: u64,
    /// The first [`SWITCHES_KEPT`] changes between host and local engine.
    pub switches: Vec<Switch>,
    /// The first error's words.
    pub first_error: Option<String>,
    /// `[remote] auto_ask_ahead`: what was chosen, and from what.
    pub auto_ask_ahead: Option<AutoAskAhead>,
}

/// The periods ahead `[remote] auto_ask_ahead` chose at start.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AutoAskAhead {
    /// `[policy] ask_ahead_periods` for this run.
    pub periods: usize,
    /// The round trip it was chosen for (the median ping at start; None: no host answered then).
    pub round_trip_ms: Option<f64>,
    /// The periods that round trip needs (more than `periods` when the chunk allows fewer: then 0 is used).
    pub needed: Option<usize>,
}

/// What the host needs beyond the round trip to answer (a state policy's call is ~1 ms on a 2-core VM), with room.
pub const HOST_ANSWER_MS: f64 = 5.0;

/// The fewest periods ahead that leave the host `round_trip_ms` and its answer before the local engine's reserve.
pub fn periods_ahead(policy: &PolicyLoopConfig, round_trip_ms: f64, reserve_ms: f64) -> usize {
    let period_ms = 1e3 / policy.rate_hz;
    let available = policy.lead_ms - policy.handoff_margin_ms - reserve_ms;
    let short = round_trip_ms + HOST_ANSWER_MS - available;
    if short <= 0.0 { 0 } else { (short / period_ms).ceil() as usize }
}

/// One chunk's request, as the policy loop knows it.
pub struct Ask<'a> {
    pub episode: u64,
    pub period: u64,
    pub seed: u64,
    pub capture_ns: u64,
    /// When the chunk must be handed to the servo (its need less the handoff margin), robot clock.
    pub handoff_ns: u64,
    pub observation: &'a [f32],
    pub history: &'a [f32],
    /// The chunk's first rows as the previous chunk will have executed them (`[policy] ask_ahead_periods` rows).
    pub committed: &'a [f32],
}

/// A request on its way to the host.
struct InFlight {
    pending: PendingReply,
    sent_ns: u64,
    /// When the local engine must take over if no reply has come.
    decide_ns: u64,
    episode: u64,
    period: u64,
    /// The chunk's values (C·D): a reply of another shape is refused.
    values: usize,
}

/// Where the chunk of the request in flight comes from, as far as is known now.
pub enum Settled {
    /// No reply yet, and still time for one.
    Waiting,
    Host(Reply),
    /// No chunk from the host (counted, with the reason): the local engine's to compute now, or none
    /// ([`Remote::rests_on_miss`]).
    Missed,
}

impl Remote {
    /// Joins the Zenoh network and measures the host's clock (a host not up yet is not an error: the local engine
    /// runs until it answers). From the main thread, before the loops start: zenoh's own threads inherit the
    /// creator's scheduling, and must not inherit a loop's SCHED_FIFO and core.
    pub fn connect(cfg: &DaemonConfig, remote: &RemoteConfig) -> anyhow::Result<Self> {
        let mut policy = RemotePolicy::connect(&remote.link(), &remote.prefix, remote.name(&cfg.robot))?;
        // A ping may take a slow link's whole round trip: up to 1 s each (a host that is not up answers none at once).
        let clock = policy.probe_clock(10, Duration::from_secs(1));
        match &clock {
            Ok(c) => tracing::info!(
                key = policy.key(),
                offset_ms = c.offset_ns as f64 * 1e-6,
                rtt_min_ms = c.rtt_min_ns as f64 * 1e-6,
                "inference host found"
            ),
            Err(e) => tracing::warn!("no inference host yet ({e}); the local engine runs until one answers"),
        }
        let report = RemoteReport { key: policy.key().to_owned(), clock: clock.ok(), ..Default::default() };
        Ok(Self {
            policy,
            reserve_ns: (remote.local_reserve_ms * 1e6) as u64,
            request: Request::default(),
            on_miss: remote.on_miss,
            last: None,
            in_flight: None,
            round_trip_us: Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid histogram bounds"),
            report,
        })
    }

    /// This robot's live frames on the session it joined (`<prefix>/<name>/live`), for a `marsd top --connect` on
    /// any machine. Declared from the main thread, as the session was.
    pub fn live_publisher(&self, remote: &RemoteConfig, robot: &str) -> anyhow::Result<LivePublisher> {
        Ok(LivePublisher::declare(self.policy.session(), &remote.prefix, remote.name(robot))?)
    }

    /// `[remote] auto_ask_ahead`: the periods ahead the round trip measured at start needs (the median ping), at
    /// most `max`; 0 (asked at the lead, the local engine computing what the host cannot) when no host answered
    /// then or when more than `max` are needed. Said in the log and the report.
    pub fn choose_ask_ahead(&mut self, policy: &PolicyLoopConfig, max: usize) -> usize {
        let round_trip_ms = self.report.clock.as_ref().map(|c| c.rtt_median_ns as f64 * 1e-6);
        let needed = round_trip_ms.map(|rtt| periods_ahead(policy, rtt, self.reserve_ns as f64 * 1e-6));
        let periods = needed.filter(|n| *n <= max).unwrap_or(0);
        match (round_trip_ms, needed) {
            (Some(rtt), Some(n)) if n > max => tracing::warn!(
                "auto_ask_ahead: a round trip of {rtt:.1} ms needs {n} periods ahead, more than the chunk allows \
                 ({max}): chunks asked at the lead"
            ),
            (Some(rtt), _) => tracing::info!(periods, round_trip_ms = rtt, "auto_ask_ahead"),
            (None, _) => tracing::warn!("auto_ask_ahead: no host answered at start; chunks asked at the lead"),
        }
        self.report.auto_ask_ahead = Some(AutoAskAhead { periods, round_trip_ms, needed });
        periods
    }

    /// Whether a missing chunk is left missing (the arm rests) rather than the local engine's.
    pub fn rests_on_miss(&self) -> bool {
        self.on_miss == OnMiss::Rest
    }

    /// Sends `a` to the host; false (counted, with the reason) when its chunk is missed already.
    pub fn send(&mut self, a: &Ask<'_>) -> bool {
        debug_assert!(self.in_flight.is_none(), "one request in flight at a time");
        let now = mars_ipc::clock::monotonic_ns();
        let decide_ns = a.handoff_ns.saturating_sub(self.reserve_ns);
        let Some(wait_ns) = decide_ns.checked_sub(now).filter(|&w| w > 0) else {
            self.resolve(a.episode, a.period, Err(Miss::NoTime));
            return false;
        };
        let r = &mut self.request;
        r.seq += 1;
        (r.episode, r.period, r.seed, r.capture_ns, r.sent_ns) = (a.episode, a.period, a.seed, a.capture_ns, now);
        // The host must send its reply one round trip before our wait ends.
        let rtt = self.report.clock.map_or(0, |c| c.rtt_min_ns);
        r.budget_ns = wait_ns.saturating_sub(rtt);
        for (to, from) in
            [(&mut r.observation, a.observation), (&mut r.history, a.history), (&mut r.committed, a.committed)]
        {
            to.clear();
            to.extend_from_slice(from);
        }
        self.report.requests += 1;
        match self.policy.send(r, Duration::from_nanos(wait_ns)) {
            Ok(pending) => {
                let (episode, period, values) = (a.episode, a.period, a.history.len());
                self.in_flight = Some(InFlight { pending, sent_ns: now, decide_ns, episode, period, values });
                true
            }
            Err(e) => {
                let miss = self.miss(e);
                self.resolve(a.episode, a.period, Err(miss));
                false
            }
        }
    }

    /// The request in flight's outcome, waiting for its reply until `until_ns` at most and never past the moment
    /// the local engine must take over. `Missed` when nothing is in flight.
    pub fn settle(&mut self, until_ns: u64) -> Settled {
        let Some(f) = &self.in_flight else { return Settled::Missed };
        let now = mars_ipc::clock::monotonic_ns();
        let wait = Duration::from_nanos(until_ns.min(f.decide_ns).saturating_sub(now));
        let result = match f.pending.wait_for(wait) {
            Ok(None) if mars_ipc::clock::monotonic_ns() < f.decide_ns => return Settled::Waiting,
            Ok(None) => Err(Miss::Timeout),
            // A chunk of another shape than ours (another checkpoint on the host) is never executed.
            Ok(Some(reply)) if reply.chunk.len() != f.values => {
                let e = format!("a chunk of {} values, this robot's have {}", reply.chunk.len(), f.values);
                Err(self.miss(RemoteError::Host(e)))
            }
            Ok(Some(reply)) => Ok(reply),
            Err(e) => Err(self.miss(e)),
        };
        let f = self.in_flight.take().expect("checked above");
        if result.is_ok() {
            let back = mars_ipc::clock::monotonic_ns();
            let _ = self.round_trip_us.record(((back - f.sent_ns) / 1000).max(1));
        }
        match self.resolve(f.episode, f.period, result) {
            Some(reply) => Settled::Host(reply),
            None => Settled::Missed,
        }
    }

    /// Drops the request in flight (its episode ended).
    pub fn abandon(&mut self) {
        if self.in_flight.take().is_some() {
            self.report.abandoned += 1;
        }
    }

    /// Counts the outcome and any change of side; the host's reply if it is one.
    fn resolve(&mut self, episode: u64, period: u64, result: Result<Reply, Miss>) -> Option<Reply> {
        let to = match (&result, self.on_miss) {
            (Ok(_), _) => Side::Host,
            (Err(_), OnMiss::Local) => Side::Local,
            (Err(_), OnMiss::Rest) => Side::Rest,
        };
        if self.last != Some(to) && self.report.switches.len() < SWITCHES_KEPT {
            let miss = result.as_ref().err().copied();
            let at_ns = mars_ipc::clock::monotonic_ns();
            self.report.switches.push(Switch { episode, period, at_ns, to, miss });
        }
        self.last = Some(to);
        let r = &mut self.report;
        *match to {
            Side::Host => &mut r.host_chunks,
            Side::Local => &mut r.local_chunks,
            Side::Rest => &mut r.rested,
        } += 1;
        match result {
            Ok(reply) => Some(reply),
            Err(miss) => {
                *self.count(miss) += 1;
                None
            }
        }
    }

    fn miss(&mut self, e: RemoteError) -> Miss {
        let miss = match &e {
            RemoteError::Timeout(_) => Miss::Timeout,
            RemoteError::NoHost(_) => Miss::NoHost,
            RemoteError::Status(Status::Expired, _) => Miss::Expired,
            _ => Miss::Error,
        };
        if miss == Miss::Error && self.report.first_error.is_none() {
            tracing::warn!("the inference host's chunk: {e}");
            self.report.first_error = Some(e.to_string());
        }
        miss
    }

    fn count(&mut self, miss: Miss) -> &mut u64 {
        let r = &mut self.report;
        match miss {
            Miss::Timeout => &mut r.timeouts,
            Miss::NoHost => &mut r.no_host,
            Miss::Expired => &mut r.expired,
            Miss::Error => &mut r.errors,
            Miss::NoTime => &mut r.no_time,
        }
    }

    /// The report, with the round-trip percentiles filled in.
    pub fn finish(mut self) -> RemoteReport {
        let h = &self.round_trip_us;
        if !h.is_empty() {
            let ms = |us: u64| us as f64 * 1e-3;
            self.report.round_trip_ms_p50 = ms(h.value_at_quantile(0.5));
            self.report.round_trip_ms_p99 = ms(h.value_at_quantile(0.99));
            self.report.round_trip_ms_max = ms(h.max());
        }
        self.report
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped config (10 Hz, lead 80 ms, margin 2 ms) with a 10 ms local reserve leaves the host 68 ms at the
    /// lead (less 5 ms for its answer): a 100 ms round trip needs one period more, 200 ms two, 400 ms four.
    #[test]
    fn the_periods_ahead_cover_the_round_trip() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
        let rtts = [0.0, 60.0, 63.0, 63.1, 100.0, 200.0, 400.0];
        let ahead: Vec<usize> = rtts.iter().map(|&rtt| periods_ahead(&cfg.policy, rtt, 10.0)).collect();
        assert_eq!(ahead, [0, 0, 0, 1, 1, 2, 4]);
    }
}
