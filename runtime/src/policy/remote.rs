//! The policy loop's inference host (`[remote]`): each chunk is asked of the host first, within the time left less
//! the local engine's reserve; a chunk not back by then is the local engine's, and the report says when each side
//! took over and why. The host is asked again at every chunk, so it resumes as soon as it answers.

use std::time::Duration;

use hdrhistogram::Histogram;
use mars_remote::client::{RemoteError, RemotePolicy};
use mars_remote::clock::ClockEstimate;
use mars_remote::wire::{Reply, Request, Status};
use serde::Serialize;

use crate::config::{DaemonConfig, RemoteConfig};

/// Switches between host and local engine kept for the report.
pub const SWITCHES_KEPT: usize = 32;

/// The inference host as the policy loop uses it.
pub struct Remote {
    policy: RemotePolicy,
    reserve_ns: u64,
    /// Reused for every request (its vectors keep their capacity).
    request: Request,
    /// Whether the last chunk came from the host (None before the first).
    on_host: Option<bool>,
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

/// One change of who computes the chunks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Switch {
    pub episode: u64,
    /// The policy period of the first chunk computed by the new side.
    pub period: u64,
    /// Robot clock (ns).
    pub at_ns: u64,
    pub to_host: bool,
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
    /// Chunks the host computed, and those the local engine computed instead, by reason.
    pub host_chunks: u64,
    pub local_chunks: u64,
    pub timeouts: u64,
    pub no_host: u64,
    pub expired: u64,
    pub errors: u64,
    pub no_time: u64,
    /// Request sent → reply received, over the host's chunks (ms).
    pub round_trip_ms_p50: f64,
    pub round_trip_ms_p99: f64,
    pub round_trip_ms_max: f64,
    /// The first [`SWITCHES_KEPT`] changes between host and local engine.
    pub switches: Vec<Switch>,
    /// The first error's words.
    pub first_error: Option<String>,
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

impl Remote {
    /// Joins the Zenoh network and measures the host's clock (a host not up yet is not an error: the local engine
    /// runs until it answers). From the main thread, before the loops start: zenoh's own threads inherit the
    /// creator's scheduling, and must not inherit a loop's SCHED_FIFO and core.
    pub fn connect(cfg: &DaemonConfig, remote: &RemoteConfig) -> anyhow::Result<Self> {
        let mut policy = RemotePolicy::connect(&remote.link(), &remote.prefix, remote.name(&cfg.robot))?;
        let clock = policy.probe_clock(20, Duration::from_millis(200));
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
            on_host: None,
            round_trip_us: Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid histogram bounds"),
            report,
        })
    }

    /// The host's chunk for `a`, or None (counted, with the reason) when the local engine must compute it.
    pub fn ask(&mut self, a: &Ask<'_>) -> Option<Reply> {
        let now = mars_ipc::clock::monotonic_ns();
        let until = a.handoff_ns.saturating_sub(self.reserve_ns);
        let result = match until.checked_sub(now).filter(|&w| w > 0) {
            None => Err(Miss::NoTime),
            Some(wait_ns) => self.request(a, now, wait_ns),
        };
        let host = result.is_ok();
        if self.on_host != Some(host) && self.report.switches.len() < SWITCHES_KEPT {
            let miss = result.as_ref().err().copied();
            let at_ns = mars_ipc::clock::monotonic_ns();
            self.report.switches.push(Switch { episode: a.episode, period: a.period, at_ns, to_host: host, miss });
        }
        self.on_host = Some(host);
        match result {
            Ok(reply) => {
                self.report.host_chunks += 1;
                Some(reply)
            }
            Err(miss) => {
                self.report.local_chunks += 1;
                *self.count(miss) += 1;
                None
            }
        }
    }

    fn request(&mut self, a: &Ask<'_>, now: u64, wait_ns: u64) -> Result<Reply, Miss> {
        let r = &mut self.request;
        r.seq += 1;
        (r.episode, r.period, r.seed, r.capture_ns, r.sent_ns) = (a.episode, a.period, a.seed, a.capture_ns, now);
        // The host must send its reply one round trip before our wait ends.
        let rtt = self.report.clock.map_or(0, |c| c.rtt_min_ns);
        r.budget_ns = wait_ns.saturating_sub(rtt);
        r.observation.clear();
        r.observation.extend_from_slice(a.observation);
        r.history.clear();
        r.history.extend_from_slice(a.history);
        r.committed.clear();
        r.committed.extend_from_slice(a.committed);
        self.report.requests += 1;
        let reply = self.policy.infer(r, Duration::from_nanos(wait_ns));
        let back = mars_ipc::clock::monotonic_ns();
        match reply {
            // A chunk of another shape than ours (another checkpoint on the host) is never executed.
            Ok(reply) if reply.chunk.len() != a.history.len() => {
                let e = format!("a chunk of {} values, this robot's have {}", reply.chunk.len(), a.history.len());
                Err(self.miss(RemoteError::Host(e)))
            }
            Ok(reply) => {
                let _ = self.round_trip_us.record(((back - now) / 1000).max(1));
                Ok(reply)
            }
            Err(e) => Err(self.miss(e)),
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
