//! What the tests of this crate share: the committed FR3 checkpoint's engine, a host serving in a thread of the test
//! process, and a request of the checkpoint's shape.
#![allow(dead_code)] // each test binary uses a part

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mars_engine::{Engine, EngineConfig};
use mars_remote::client::RemotePolicy;
use mars_remote::link::LinkConfig;
use mars_remote::server::{ServeReport, ServedRobot, serve};
use mars_remote::wire::Request;

pub fn checkpoint() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/checkpoints/fr3_pick_cup/mars")
}

pub fn engine() -> Engine {
    Engine::load(&checkpoint(), EngineConfig::default()).expect("the committed FR3 checkpoint loads")
}

/// A TCP port nothing listens on now (the kernel's choice), so parallel tests and other runs do not meet.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

pub struct Host {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<ServeReport>>,
    pub locator: String,
}

impl Host {
    pub fn start(prefix: &str, robots: &[&str]) -> Self {
        let locator = format!("tcp/127.0.0.1:{}", free_port());
        let session = LinkConfig::listening(&locator).open().expect("the host's session opens");
        let served = robots.iter().map(|r| ServedRobot { robot: (*r).to_owned(), engine: engine() }).collect();
        let stop = Arc::new(AtomicBool::new(false));
        let (s, prefix) = (stop.clone(), prefix.to_owned());
        let thread = std::thread::spawn(move || serve(&session, &prefix, served, &s).expect("serving"));
        Self { stop, thread: Some(thread), locator }
    }

    pub fn stop(mut self) -> ServeReport {
        self.stop.store(true, Ordering::Release);
        self.thread.take().unwrap().join().unwrap()
    }
}

/// The robot's client, once the host answers its clock (declarations take a moment to reach a new peer).
pub fn robot(host: &Host, prefix: &str, name: &str) -> RemotePolicy {
    let mut r = RemotePolicy::connect(&LinkConfig::connecting(&host.locator), prefix, name).unwrap();
    let t0 = Instant::now();
    while r.probe_clock(1, Duration::from_millis(200)).is_err() {
        assert!(t0.elapsed() < Duration::from_secs(10), "the host never answered its clock");
    }
    r
}

pub fn request(e: &Engine, seq: u64) -> Request {
    let m = e.meta();
    Request {
        seq,
        episode: 1,
        period: 8 * seq,
        budget_ns: 2_000_000_000,
        seed: 40 + seq,
        observation: m.normalizer.obs.mean.clone(),
        history: m.normalizer.action.mean.repeat(e.chunk_len()),
        ..Default::default()
    }
}

/// The repository's root.
pub fn repo() -> &'static std::path::Path {
    std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// `.ci/zenoh-venv`'s Python (installed first if missing; idempotent, and one install at a time machine-wide).
pub fn python() -> PathBuf {
    let status =
        std::process::Command::new(repo().join(".ci/zenoh-venv")).current_dir(repo()).status().expect(".ci/zenoh-venv");
    assert!(status.success(), ".ci/zenoh-venv failed ({status}): the Python peer is not installed");
    repo().join(".venv-zenoh/bin/python")
}
