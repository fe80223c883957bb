//! Live frames read by a program in another language: tests/peers/live_peer.py (Zenoh's Python binding, the frame
//! encoded and decoded from README's description) reads the frames a robot of ours puts, and we read its. Both go
//! through a router, as on a fleet: the robot is a peer connected to it, the watchers are its clients.

mod support;

use std::io::Write;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use mars_ipc::{HalLive, LiveChannel, LiveStats, ServoLive};
use mars_remote::link::{LinkConfig, Role};
use mars_remote::live::{LivePublisher, LiveWatch};
use serde_json::{Value, json};
use support::{free_port, python, repo};

/// A frame whose every field differs from the others, from `base`.
fn numbered(base: u64, camera: &str) -> LiveStats {
    let mut f = LiveStats { seq: base, timestamp_ns: base + 1, period_ns: base + 2, ..Default::default() };
    f.inference_budget_ns = base + 3;
    for (i, c) in f.channels.iter_mut().enumerate() {
        let b = base + 100 + 10 * i as u64;
        *c = LiveChannel {
            count: b,
            p50: b + 1,
            p99: b + 2,
            max: b + 3,
            over_period: b + 4,
            start_ns: b + 5,
            end_ns: b + 6,
        };
    }
    (f.phase, f.trip) = (4, 7);
    (f.episode, f.ticks, f.policy_beats, f.starved) = (base + 5, base + 6, base + 7, base + 8);
    let s = base + 300;
    f.servo = ServoLive {
        commands_sent: s,
        late_commands: s + 1,
        resyncs: s + 2,
        frameless_ticks: s + 3,
        actions_dropped: s + 4,
        starved_ticks: s + 5,
        limit_violations: s + 6,
    };
    let h = base + 400;
    f.hal = HalLive {
        rejected: h,
        clamped: h + 1,
        late: h + 2,
        position_guard_hits: h + 3,
        infeasible_steps: h + 4,
        backend_errors: u64::MAX - base,
    };
    f.set_camera_name(camera);
    f
}

/// A frame as the Python peer's JSON gives it.
fn as_json(f: &LiveStats) -> Value {
    let ch: Vec<_> =
        f.channels.iter().map(|c| json!([c.count, c.p50, c.p99, c.max, c.over_period, c.start_ns, c.end_ns])).collect();
    let (s, h) = (&f.servo, &f.hal);
    json!({
        "seq": f.seq, "timestamp_ns": f.timestamp_ns, "period_ns": f.period_ns,
        "inference_budget_ns": f.inference_budget_ns, "channels": ch, "phase": f.phase, "trip": f.trip,
        "episode": f.episode, "ticks": f.ticks, "policy_beats": f.policy_beats, "starved": f.starved,
        "servo": [s.commands_sent, s.late_commands, s.resyncs, s.frameless_ticks, s.actions_dropped, s.starved_ticks,
                  s.limit_violations],
        "hal": [h.rejected, h.clamped, h.late, h.position_guard_hits, h.infeasible_steps, h.backend_errors],
        "camera": f.camera_name(),
    })
}

#[test]
fn a_python_watcher_reads_our_frames_and_we_read_its_through_a_router() {
    let python = python();
    let prefix = format!("mars-test/{}/live", std::process::id());
    let locator = format!("tcp/127.0.0.1:{}", free_port());
    let _router = LinkConfig::listening(&locator).open_as(Role::Router).expect("the router opens");
    // Our robot: a peer connected to the router, putting a frame every 20 ms until the test ends.
    let ours = numbered(1_000, "wrist");
    let robot = LinkConfig::connecting(&locator).open().unwrap();
    let publisher = LivePublisher::declare(&robot, &prefix, "rs-arm").unwrap();
    let done = Arc::new(AtomicBool::new(false));
    let d = done.clone();
    let putting = std::thread::spawn(move || {
        while !d.load(Ordering::Acquire) {
            publisher.put(&ours).unwrap();
            std::thread::sleep(Duration::from_millis(20));
        }
    });
    // Our watcher: a client of the router, as `marsd top --connect` is.
    let watcher = LinkConfig::connecting(&locator).open_as(Role::Client).unwrap();
    let watch = LiveWatch::subscribe(&watcher, &prefix, None).unwrap();
    let theirs = numbered(7_000, "täg");
    let job = json!({"connect": locator, "prefix": prefix, "watch": "rs-arm", "robot": "py-arm",
                     "frame": as_json(&theirs), "seconds": 3.0});
    let mut child = Command::new(&python)
        .arg(repo().join("tests/peers/live_peer.py"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("starting the Python peer");
    child.stdin.take().unwrap().write_all(job.to_string().as_bytes()).unwrap();
    let t0 = Instant::now();
    let got = loop {
        assert!(t0.elapsed() < Duration::from_secs(20), "no frame of the Python peer's reached our watcher");
        match watch.next(Duration::from_millis(100)) {
            Some((robot, frame)) if robot == "py-arm" => break frame.expect("its frame decodes"),
            _ => continue,
        }
    };
    assert_eq!(got, theirs, "the Python peer's frame as we read it");
    let out = child.wait_with_output().unwrap();
    done.store(true, Ordering::Release);
    putting.join().unwrap();
    assert!(out.status.success(), "the Python peer failed ({})", out.status);
    let line = String::from_utf8(out.stdout).unwrap();
    let read: Value = serde_json::from_str(line.trim()).unwrap_or_else(|e| panic!("{e}: {line}"));
    assert_eq!(read, as_json(&ours), "our frame as the Python peer read it");
}
