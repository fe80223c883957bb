//! The inference host's wire (crate mars-remote): a request as `marsd serve` takes it (decoded, then run through
//! the robot's engine with the budget it names), a reply as marsd's policy loop takes it (decoded, its chunk
//! judged against the robot's shape). Seeds: a Pick Cup request and its reply, as the two sides write them.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use mars_engine::{Engine, EngineConfig};
use mars_remote::wire::{Reply, Request};

use super::{Bundles, repo};
use crate::runner::Target;

pub fn messages() -> Arc<dyn Target> {
    let dir = repo("assets/checkpoints/fr3_pick_cup/mars");
    let mut engine = Engine::load(&dir, EngineConfig::default()).expect("the committed FR3 checkpoint");
    let m = engine.meta();
    let request = Request {
        seq: 3,
        episode: 1,
        period: 16,
        budget_ns: 70_000_000,
        seed: 5,
        observation: m.normalizer.obs.mean.clone(),
        history: m.normalizer.action.mean.repeat(engine.chunk_len()),
        // One row the robot will have executed when the chunk arrives.
        committed: m.normalizer.action.mean.clone(),
        ..Default::default()
    };
    let out = engine
        .infer_after(&request.observation, &request.history, &request.committed, Duration::from_millis(70))
        .expect("a call");
    let reply = Reply {
        seq: 3,
        k_requested: out.k_requested as u32,
        k_used: out.k_used as u32,
        chunk: out.chunk.to_vec(),
        ..Default::default()
    };
    let (mut q, mut p) = (Vec::new(), Vec::new());
    request.encode_into(&mut q);
    reply.encode_into(&mut p);
    let chunk_values = request.history.len();
    let engine = Mutex::new(engine);
    Bundles::of_files("remote-wire", vec![q, p], false, move |b, bytes| {
        if b == 1 {
            return Reply::decode(bytes).is_ok_and(|r| r.chunk.len() == chunk_values);
        }
        let Ok(r) = Request::decode(bytes) else { return false };
        let mut e = engine.lock().unwrap_or_else(|p| p.into_inner());
        e.reseed(r.seed);
        // The host's budget is its receive time plus the request's: any u64 is a Duration.
        e.infer_after(&r.observation, &r.history, &r.committed, Duration::from_nanos(r.budget_ns)).is_ok()
    })
}
