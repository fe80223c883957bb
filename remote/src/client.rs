//! The robot's side: one query per chunk to the host that serves this robot, bounded by the time the robot can
//! wait; whatever does not come back in time is an error the caller replaces (marsd runs its local engine).

use std::time::Duration;

use zenoh::Wait;
use zenoh::query::ConsolidationMode;

use crate::clock::{ClockEstimate, Ping};
use crate::link::{self, LinkConfig, LinkError};
use crate::monotonic_ns;
use crate::wire::{Reply, Request, Status, WireError};

#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("no reply from the inference host within {0:?}")]
    Timeout(Duration),
    #[error("no inference host answers `{0}`")]
    NoHost(String),
    #[error("the inference host answered with an error: {0}")]
    Host(String),
    #[error("the inference host's reply: {0}")]
    Wire(#[from] WireError),
    #[error("the inference host answered {0:?} for seq {1}")]
    Status(Status, u64),
    #[error("the reply answers seq {got}, the request was seq {want}")]
    Seq { got: u64, want: u64 },
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// The policy of one robot, served by a host on the Zenoh network.
pub struct RemotePolicy {
    session: zenoh::Session,
    key: String,
    clock_key: String,
}

impl RemotePolicy {
    /// Joins the network and names the robot's key; reaches no host yet (see [`RemotePolicy::probe_clock`]).
    pub fn connect(link: &LinkConfig, prefix: &str, robot: &str) -> Result<Self, RemoteError> {
        let key = link::infer_key(prefix, robot)?;
        let clock_key = link::clock_key(prefix)?;
        Ok(Self { session: link.open()?, key, clock_key })
    }

    /// The Zenoh session this robot joined (its live frames go out on it too, `crate::live::LivePublisher`).
    pub fn session(&self) -> &zenoh::Session {
        &self.session
    }

    /// The key this robot's queries go to.
    pub fn key(&self) -> &str {
        &self.key
    }

    /// Asks the host's clock `n` times (each bounded by `timeout`): the offset and round trips, or `NoHost`
    /// when no ping came back.
    pub fn probe_clock(&mut self, n: usize, timeout: Duration) -> Result<ClockEstimate, RemoteError> {
        let mut pings = Vec::with_capacity(n);
        for _ in 0..n {
            let asked_ns = monotonic_ns();
            let Ok(reply) = self.ask(&self.clock_key, Vec::new(), timeout) else { continue };
            let answered_ns = monotonic_ns();
            let Ok(host) = <[u8; 8]>::try_from(&reply[..]) else {
                return Err(RemoteError::Host(format!("a clock reply of {} bytes, not 8", reply.len())));
            };
            pings.push(Ping { asked_ns, host_ns: u64::from_le_bytes(host), answered_ns });
        }
        ClockEstimate::from_pings(&pings).ok_or_else(|| RemoteError::NoHost(self.clock_key.clone()))
    }

    /// The host's chunk for `request`, or an error once `wait` has passed (or sooner, when no host answers).
    pub fn infer(&mut self, request: &Request, wait: Duration) -> Result<Reply, RemoteError> {
        let pending = self.send(request, wait)?;
        pending.wait_for(wait)?.ok_or(RemoteError::Timeout(wait))
    }

    /// Sends `request` and returns at once: the reply is collected with [`PendingReply::wait_for`], so the caller
    /// keeps its own rhythm meanwhile. Zenoh drops the query after `wait`.
    pub fn send(&mut self, request: &Request, wait: Duration) -> Result<PendingReply, RemoteError> {
        let mut payload = Vec::new();
        request.encode_into(&mut payload);
        let replies = self.query(&self.key, payload, wait)?;
        Ok(PendingReply { replies, seq: request.seq, key: self.key.clone(), wait })
    }

    /// One query and its first reply's bytes, within `wait`.
    fn ask(&self, key: &str, payload: Vec<u8>, wait: Duration) -> Result<Vec<u8>, RemoteError> {
        let replies = self.query(key, payload, wait)?;
        first_reply(&replies, key, wait, wait)?.ok_or(RemoteError::Timeout(wait))
    }

    fn query(&self, key: &str, payload: Vec<u8>, wait: Duration) -> Result<Replies, RemoteError> {
        self.session
            .get(key)
            .payload(payload)
            .consolidation(ConsolidationMode::None)
            .express(true)
            .timeout(wait)
            .wait()
            .map_err(|e| RemoteError::Zenoh(e.to_string()))
    }
}

type Replies = zenoh::handlers::FifoChannelHandler<zenoh::query::Reply>;

/// The error reply Zenoh itself gives a query whose timeout passed unanswered (the querier's own session, or a
/// router on the way): the query timed out, no host said anything. (Our host answers in its payload's `Status`,
/// never with a Zenoh error.)
const ZENOH_TIMEOUT: &str = "Timeout";

/// A request on its way: its reply, when it comes.
pub struct PendingReply {
    replies: Replies,
    seq: u64,
    key: String,
    /// The query's own timeout, after which Zenoh ends it.
    wait: Duration,
}

impl PendingReply {
    /// The host's chunk if it comes within `wait` (`Duration::ZERO`: whether it is here now); `Ok(None)` while
    /// it has not come; an error for a reply that is not a chunk for this request, or when the query ended
    /// with none (no host, or the host vanished).
    pub fn wait_for(&self, wait: Duration) -> Result<Option<Reply>, RemoteError> {
        let Some(bytes) = first_reply(&self.replies, &self.key, wait, self.wait)? else { return Ok(None) };
        let reply = Reply::decode(&bytes)?;
        if reply.seq != self.seq {
            return Err(RemoteError::Seq { got: reply.seq, want: self.seq });
        }
        match reply.status {
            Status::Chunk => Ok(Some(reply)),
            other => Err(RemoteError::Status(other, reply.seq)),
        }
    }
}

/// The first reply's bytes within `wait`, `None` if none came by then; a timeout once the query's own timeout
/// (`query_wait`) has ended it, even when the caller reads that only later (it woke late).
fn first_reply(
    replies: &Replies,
    key: &str,
    wait: Duration,
    query_wait: Duration,
) -> Result<Option<Vec<u8>>, RemoteError> {
    let got = if wait.is_zero() { replies.try_recv() } else { replies.recv_timeout(wait) };
    match got {
        Ok(Some(reply)) => match reply.into_result() {
            Ok(sample) => Ok(Some(sample.payload().to_bytes().into_owned())),
            Err(e) => match e.payload().try_to_string() {
                Ok(text) if text == ZENOH_TIMEOUT => Err(RemoteError::Timeout(query_wait)),
                Ok(text) => Err(RemoteError::Host(text.into_owned())),
                Err(_) => Err(RemoteError::Host("?".into())),
            },
        },
        Ok(None) => Ok(None),
        // The query ended with no reply: nothing matched the key, or the host vanished.
        Err(_) => Err(RemoteError::NoHost(key.to_owned())),
    }
}
