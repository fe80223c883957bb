//! The inference host's loop (`marsd serve`): every robot's queries, earliest deadline first, each through that
//! robot's own engine; a query whose deadline passed before its turn is answered `Expired`, unrun (the robot has
//! already replaced it), so one late robot does not make the others late.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use mars_engine::Engine;
use serde::Serialize;
use zenoh::Wait;
use zenoh::query::Query;

use crate::link::{self, LinkError};
use crate::monotonic_ns;
use crate::wire::{Reply, Request, Status};

/// A robot this host serves, with the engine that runs its policy.
pub struct ServedRobot {
    pub robot: String,
    pub engine: Engine,
}

/// Per robot, what the host did with its queries.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RobotCounts {
    /// Chunks sent.
    pub chunks: u64,
    /// Queries whose deadline had passed at their turn (dropped unrun).
    pub expired: u64,
    /// Chunks sent after their deadline (the engine's call ran past it).
    pub late_replies: u64,
    /// Queries the engine refused (wrong lengths, non-finite values).
    pub refused: u64,
    /// Sum of the steps run (mean K = k_sum / chunks).
    pub k_sum: u64,
    /// Longest wait of a query before its turn (ns): what the other robots cost it.
    pub max_queue_ns: u64,
}

/// What `serve` did, when it stops.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ServeReport {
    pub robots: BTreeMap<String, RobotCounts>,
    /// Queries for a robot this host does not serve.
    pub unknown_robot: u64,
    /// Queries whose payload was not a request (answered with an error naming why).
    pub undecodable: u64,
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("declaring `{key}`: {error}")]
    Declare { key: String, error: String },
    #[error("robot `{0}` is served twice")]
    Duplicate(String),
}

/// A decoded query waiting for its turn.
struct Pending {
    query: Query,
    robot: usize,
    request: Request,
    received_ns: u64,
    deadline_ns: u64,
}

/// Answers the queries of `robots` under `prefix` until `stop` is set (checked at least every 50 ms).
pub fn serve(
    session: &zenoh::Session,
    prefix: &str,
    mut robots: Vec<ServedRobot>,
    stop: &AtomicBool,
) -> Result<ServeReport, ServeError> {
    let mut report = ServeReport::default();
    for r in &robots {
        link::infer_key(prefix, &r.robot)?;
        if report.robots.insert(r.robot.clone(), RobotCounts::default()).is_some() {
            return Err(ServeError::Duplicate(r.robot.clone()));
        }
    }
    let declare_error = |key: &str, e: zenoh::Error| ServeError::Declare { key: key.to_owned(), error: e.to_string() };
    // The clock answers at once, from zenoh's own thread: a ping must not wait behind an inference.
    let clock_key = link::clock_key(prefix)?;
    let _clock = session
        .declare_queryable(&clock_key)
        .callback(|q| {
            let _ = q.reply(q.key_expr().clone(), monotonic_ns().to_le_bytes().to_vec()).wait();
        })
        .wait()
        .map_err(|e| declare_error(&clock_key, e))?;
    let infer_key = link::all_infer_keys(prefix)?;
    let queries = session.declare_queryable(&infer_key).wait().map_err(|e| declare_error(&infer_key, e))?;
    tracing::info!(prefix, robots = robots.len(), "serving");
    let mut pending: Vec<Pending> = Vec::new();
    while !stop.load(Ordering::Acquire) {
        if pending.is_empty() {
            match queries.recv_timeout(Duration::from_millis(50)) {
                Ok(Some(q)) => admit(q, prefix, &robots, &mut pending, &mut report),
                Ok(None) => continue,
                Err(_) => break,
            }
        }
        while let Ok(Some(q)) = queries.try_recv() {
            admit(q, prefix, &robots, &mut pending, &mut report);
        }
        let Some(next) = (0..pending.len()).min_by_key(|&i| pending[i].deadline_ns) else { continue };
        let p = pending.swap_remove(next);
        let robot = &mut robots[p.robot];
        let counts = report.robots.get_mut(&robot.robot).expect("every served robot has counts");
        let mut bytes = Vec::new();
        answer(&mut robot.engine, &p, counts).encode_into(&mut bytes);
        let _ = p.query.reply(p.query.key_expr().clone(), bytes).wait();
    }
    Ok(report)
}

/// Decodes a query and queues it, or answers it at once when it cannot be run.
fn admit(query: Query, prefix: &str, robots: &[ServedRobot], pending: &mut Vec<Pending>, report: &mut ServeReport) {
    let received_ns = monotonic_ns();
    let payload = query.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
    let request = match Request::decode(&payload) {
        Ok(r) => r,
        Err(e) => {
            report.undecodable += 1;
            let _ = query.reply_err(e.to_string()).wait();
            return;
        }
    };
    let robot =
        link::robot_of(prefix, query.key_expr().as_str()).and_then(|r| robots.iter().position(|s| s.robot == r));
    let Some(robot) = robot else {
        report.unknown_robot += 1;
        let mut bytes = Vec::new();
        Reply::without_chunk(Status::UnknownRobot, request.seq, received_ns).encode_into(&mut bytes);
        let _ = query.reply(query.key_expr().clone(), bytes).wait();
        return;
    };
    let deadline_ns = received_ns.saturating_add(request.budget_ns);
    pending.push(Pending { query, robot, request, received_ns, deadline_ns });
}

/// Runs one queued request through its robot's engine within what is left of its deadline.
fn answer(engine: &mut Engine, p: &Pending, counts: &mut RobotCounts) -> Reply {
    let now = monotonic_ns();
    counts.max_queue_ns = counts.max_queue_ns.max(now - p.received_ns);
    let req = &p.request;
    if now >= p.deadline_ns {
        counts.expired += 1;
        return Reply::without_chunk(Status::Expired, req.seq, p.received_ns);
    }
    engine.reseed(req.seed);
    let budget = Duration::from_nanos(p.deadline_ns - now);
    let out = match engine.infer_after(&req.observation, &req.history, &req.committed, budget) {
        Ok(out) => out,
        Err(e) => {
            counts.refused += 1;
            tracing::warn!(seq = req.seq, "request refused by the engine: {e}");
            return Reply::without_chunk(Status::Refused, req.seq, p.received_ns);
        }
    };
    let sent_ns = monotonic_ns();
    counts.chunks += 1;
    counts.k_sum += out.k_used as u64;
    counts.late_replies += u64::from(sent_ns > p.deadline_ns);
    Reply {
        status: Status::Chunk,
        seq: req.seq,
        received_ns: p.received_ns,
        sent_ns,
        k_requested: out.k_requested as u32,
        k_used: out.k_used as u32,
        capped: out.capped,
        over_budget: out.over_budget,
        encode_ns: out.encode.as_nanos() as u64,
        w_inf: out.w.iter().fold(0.0f32, |m, w| m.max(w.abs())),
        chunk: out.chunk.to_vec(),
    }
}
