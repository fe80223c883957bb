//! A host and a robot on two Zenoh sessions joined over TCP on localhost: the host's chunk is the local engine's,
//! bit for bit (same checkpoint, same seed); every way a query can fail comes back as an error, within its wait.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mars_engine::{Engine, EngineConfig};
use mars_remote::client::{RemoteError, RemotePolicy};
use mars_remote::link::LinkConfig;
use mars_remote::server::{ServeReport, ServedRobot, serve};
use mars_remote::wire::{Request, Status};

fn checkpoint() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/checkpoints/fr3_pick_cup/mars")
}

fn engine() -> Engine {
    Engine::load(&checkpoint(), EngineConfig::default()).expect("the committed FR3 checkpoint loads")
}

/// A TCP port nothing listens on now (the kernel's choice), so parallel tests and other runs do not meet.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

struct Host {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<ServeReport>>,
    locator: String,
}

impl Host {
    fn start(prefix: &str, robots: &[&str]) -> Self {
        let locator = format!("tcp/127.0.0.1:{}", free_port());
        let session = LinkConfig::listening(&locator).open().expect("the host's session opens");
        let served = robots.iter().map(|r| ServedRobot { robot: (*r).to_owned(), engine: engine() }).collect();
        let stop = Arc::new(AtomicBool::new(false));
        let (s, prefix) = (stop.clone(), prefix.to_owned());
        let thread = std::thread::spawn(move || serve(&session, &prefix, served, &s).expect("serving"));
        Self { stop, thread: Some(thread), locator }
    }

    fn stop(mut self) -> ServeReport {
        self.stop.store(true, Ordering::Release);
        self.thread.take().unwrap().join().unwrap()
    }
}

/// The robot's client, once the host answers its clock (declarations take a moment to reach a new peer).
fn robot(host: &Host, prefix: &str, name: &str) -> RemotePolicy {
    let mut r = RemotePolicy::connect(&LinkConfig::connecting(&host.locator), prefix, name).unwrap();
    let t0 = Instant::now();
    while r.probe_clock(1, Duration::from_millis(200)).is_err() {
        assert!(t0.elapsed() < Duration::from_secs(10), "the host never answered its clock");
    }
    r
}

fn request(e: &Engine, seq: u64) -> Request {
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

#[test]
fn the_hosts_chunk_is_the_local_engines_bit_for_bit() {
    let prefix = format!("mars-test/{}/same", std::process::id());
    let host = Host::start(&prefix, &["fr3"]);
    let mut remote = robot(&host, &prefix, "fr3");
    let clock = remote.probe_clock(20, Duration::from_secs(1)).unwrap();
    // One machine: the two clocks are one, so the offset is within the round trip.
    assert!(clock.offset_ns.unsigned_abs() <= clock.rtt_min_ns, "{clock:?}");
    let mut local = engine();
    for seq in 1..=5 {
        let req = request(&local, seq);
        let reply = remote.infer(&req, Duration::from_secs(2)).unwrap();
        local.reseed(req.seed);
        let out = local.infer(&req.observation, &req.history, Duration::from_secs(2)).unwrap();
        assert_eq!(reply.chunk, out.chunk, "seq {seq}");
        assert_eq!((reply.seq, reply.k_used as usize), (seq, out.k_used));
        assert!(reply.received_ns <= reply.sent_ns);
    }
    let report = host.stop();
    assert_eq!(report.robots["fr3"].chunks, 5);
}

#[test]
fn an_unknown_robot_an_expired_query_and_a_vanished_host_are_errors_in_time() {
    let prefix = format!("mars-test/{}/errors", std::process::id());
    let host = Host::start(&prefix, &["fr3"]);
    let e = engine();
    let mut stranger = robot(&host, &prefix, "r1-lite");
    match stranger.infer(&request(&e, 1), Duration::from_secs(2)) {
        Err(RemoteError::Status(Status::UnknownRobot, 1)) => {}
        other => panic!("a robot the host does not serve: {other:?}"),
    }
    let mut remote = robot(&host, &prefix, "fr3");
    let mut late = request(&e, 2);
    late.budget_ns = 0;
    match remote.infer(&late, Duration::from_secs(2)) {
        Err(RemoteError::Status(Status::Expired, 2)) => {}
        other => panic!("a query with no time left: {other:?}"),
    }
    let report = host.stop();
    assert_eq!((report.robots["fr3"].expired, report.unknown_robot), (1, 1));
    let t0 = Instant::now();
    let wait = Duration::from_millis(300);
    let gone = remote.infer(&request(&e, 3), wait);
    assert!(matches!(gone, Err(RemoteError::NoHost(_) | RemoteError::Timeout(_))), "{gone:?}");
    assert!(t0.elapsed() < wait + Duration::from_millis(200), "took {:?}", t0.elapsed());
}
