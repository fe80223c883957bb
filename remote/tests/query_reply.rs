//! A host and a robot on two Zenoh sessions joined over TCP on localhost: the host's chunk is the local engine's,
//! bit for bit (same checkpoint, same seed); every way a query can fail comes back as an error, within its wait.

mod support;

use std::time::{Duration, Instant};

use mars_remote::client::{RemoteError, RemotePolicy};
use mars_remote::link::{self, LinkConfig};
use mars_remote::wire::Status;
use support::*;

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

/// Zenoh ends a query whose timeout passed unanswered with an error reply of its own ("Timeout"). Read after that
/// (a robot whose loop woke late), it is a timeout, as it would have been read in time — not the host's error.
#[test]
fn a_reply_read_after_the_querys_timeout_is_a_timeout_not_a_host_error() {
    use zenoh::Wait;
    let prefix = format!("mars-test/{}/silent", std::process::id());
    let locator = format!("tcp/127.0.0.1:{}", free_port());
    let host = LinkConfig::listening(&locator).open().unwrap();
    // A host that never answers (stalled, or its link cut): its queryable keeps every query unread.
    let queries = host.declare_queryable(link::infer_key(&prefix, "fr3").unwrap()).wait().unwrap();
    let mut robot = RemotePolicy::connect(&LinkConfig::connecting(&locator), &prefix, "fr3").unwrap();
    let (e, wait, t0) = (engine(), Duration::from_millis(100), Instant::now());
    let read_late = loop {
        let pending = robot.send(&request(&e, 1), wait).unwrap();
        std::thread::sleep(3 * wait);
        match pending.wait_for(Duration::ZERO) {
            // The queryable's declaration had not reached the robot's session yet.
            Err(RemoteError::NoHost(_)) if t0.elapsed() < Duration::from_secs(10) => continue,
            other => break other,
        }
    };
    assert!(matches!(read_late, Err(RemoteError::Timeout(w)) if w == wait), "{read_late:?}");
    assert!(queries.try_recv().unwrap().is_some(), "the query never reached the host");
}
