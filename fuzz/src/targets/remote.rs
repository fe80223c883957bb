//! The inference host's wire (crate mars-remote): a request as `marsd serve` takes it (decoded, then run through
//! the robot's engine with the budget it names), a reply as marsd's policy loop takes it (decoded, its chunk
//! judged against the robot's shape). Seeds: a Pick Cup request and its reply, as the two sides write them. And a
//! daemon's live frame as `marsd top --connect` takes it off the network: decoded, then shown in the fleet's table.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mars_engine::{Engine, EngineConfig};
use mars_ipc::{LiveChannel, LiveStats};
use mars_remote::live;
use mars_remote::wire::{Reply, Request};
use mars_runtime::tools::top_network::{Fleet, FleetView};

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

/// A live frame (`mars_remote::live`) decoded and drawn in `marsd top --connect`'s table, whatever its numbers say.
/// Seed: a running robot's frame as marsd puts it.
pub fn live_frames() -> Arc<dyn Target> {
    let mut frame = LiveStats { seq: 9, period_ns: 1_000_000, inference_budget_ns: 68_000_000, ..Default::default() };
    (frame.phase, frame.episode, frame.ticks) = (4, 2, 4_000);
    frame.channels[0] =
        LiveChannel { count: 250, p50: 30_000, p99: 60_000, max: 90_000, start_ns: 1, end_ns: 2, ..Default::default() };
    frame.set_camera_name("top");
    Bundles::of_files("remote-live", vec![live::encode(&frame)], false, |_, bytes| {
        let frame = live::decode(bytes);
        let accepted = frame.is_ok();
        let mut fleet = Fleet::default();
        fleet.receive("arm".into(), frame, Instant::now());
        let table = FleetView { prefix: "mars", fleet: &fleet, now: Instant::now() }.to_string();
        accepted && table.contains("| arm |")
    })
}
