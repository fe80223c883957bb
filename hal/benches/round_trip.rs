//! One state→command round trip through iceoryx2 between two processes, next to iceoryx2's own bare
//! publish/subscribe round trip (a `u64` ping-pong, the pattern of iceoryx2's `benchmarks/publish-subscribe`),
//! both measured in this run on this machine.
//!
//! `cargo bench -p mars-hal` (the bench re-executes itself as the second process). Both sides busy-poll, as a
//! 1 kHz controller on its own core would; on a machine with fewer than two idle cores the tails show the
//! scheduler, not iceoryx2.
//!
//! - **bare**: parent publishes a `u64` on `ping`, the child publishes it back on `pong`.
//! - **state→command**: parent (in the HAL's place) publishes a [`RobotState`] through `StateWriter`; the child
//!   (a controller) reads it through `StateReader` (schema check included) and answers with a
//!   [`JointCommand`] through `CommandWriter`; the parent's `CommandReader` receives the command that answers
//!   that state `seq`.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use iceoryx2::prelude::*;
use mars_ipc::node::create_node;
use mars_ipc::*;

const WARMUP: u64 = 5_000;
const SAMPLES: u64 = 100_000;
const BLOCK: u64 = 1_000;
const CHILD_ENV: &str = "MARS_RT_BENCH_CHILD";

struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn bare_service(
    node: &Node<ipc::Service>,
    name: &str,
) -> iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, u64, ()> {
    node.service_builder(&ServiceName::new(name).unwrap())
        .publish_subscribe::<u64>()
        .history_size(0)
        .subscriber_max_buffer_size(1)
        .max_publishers(1)
        .max_subscribers(1)
        .open_or_create()
        .unwrap()
}

/// While its case is being timed, an echo side busy-polls; when idle for a millisecond (the other case's
/// block), it yields so it does not steal the core from the case being timed.
fn idle(last: Instant) {
    if last.elapsed() < Duration::from_millis(1) { std::hint::spin_loop() } else { std::thread::yield_now() }
}

fn child(kind: &str, id: &str) {
    let (node, _) = create_node(&format!("rt-bench-child-{id}")).unwrap();
    let mut last = Instant::now();
    match kind {
        "bare" => {
            let ping = bare_service(&node, &format!("rt-bench/{id}/ping")).subscriber_builder().create().unwrap();
            let pong = bare_service(&node, &format!("rt-bench/{id}/pong")).publisher_builder().create().unwrap();
            loop {
                if let Some(s) = ping.receive().unwrap() {
                    pong.send_copy(*s.payload()).unwrap();
                    last = Instant::now();
                } else {
                    idle(last);
                }
            }
        }
        _ => {
            let ns = RobotNamespace::new(id).unwrap();
            let states = StateReader::new(&node, &ns).unwrap();
            let commands = CommandWriter::new(&node, &ns).unwrap();
            let mut seq = 0;
            loop {
                if let Some(s) = states.receive().unwrap() {
                    seq += 1;
                    let n = s.num_joints as usize;
                    commands.send(&JointCommand::position(1, seq, s.seq, &s.applied_position[..n])).unwrap();
                    last = Instant::now();
                } else {
                    idle(last);
                }
            }
        }
    }
}

fn spawn_child(kind: &str, id: &str) -> Proc {
    let exe = std::env::current_exe().unwrap();
    Proc(
        Command::new(exe)
            .env(CHILD_ENV, format!("{kind}:{id}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

/// One round trip: send number `i`, return true once its answer arrived, false after `patience`.
type RoundTrip<'a> = Box<dyn FnMut(u64, Duration) -> bool + 'a>;

/// Warm both cases up (the first exchanges also wait for the children to connect), then time them in
/// alternating blocks of `BLOCK`, so both see the same machine load.
fn measure(cases: &mut [RoundTrip<'_>]) -> Vec<Histogram<u64>> {
    let mut i = 1;
    for once in cases.iter_mut() {
        let mut answered = 0;
        let end = Instant::now() + Duration::from_secs(30);
        while answered < WARMUP {
            assert!(Instant::now() < end, "a child process never answered");
            if once(i, Duration::from_millis(5)) {
                answered += 1;
            }
            i += 1;
        }
    }
    let mut hs: Vec<_> =
        cases.iter().map(|_| Histogram::<u64>::new_with_bounds(1, 1_000_000_000, 3).unwrap()).collect();
    for _ in 0..SAMPLES / BLOCK {
        for (once, h) in cases.iter_mut().zip(&mut hs) {
            for _ in 0..BLOCK {
                let t = Instant::now();
                assert!(once(i, Duration::from_secs(1)), "no answer within 1 s");
                h.saturating_record(t.elapsed().as_nanos() as u64);
                i += 1;
            }
        }
    }
    hs
}

fn main() {
    if let Ok(spec) = std::env::var(CHILD_ENV) {
        let (kind, id) = spec.split_once(':').unwrap();
        child(kind, id);
        return;
    }
    let id = format!("rtbench{}", std::process::id());
    println!(
        "iceoryx2 round trip between two processes: {SAMPLES} samples per case after {WARMUP} warm-up, \
         cases alternating in blocks of {BLOCK}, busy-polling (an echo side yields while the other case is timed)"
    );
    // The tails depend on what else runs: say so next to the numbers.
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!("machine: {cpus} CPUs, load average {}", load.split_whitespace().take(3).collect::<Vec<_>>().join(" "));
    let (node, _) = create_node(&format!("rt-bench-parent-{id}")).unwrap();

    // bare: u64 ping → pong.
    let bare_id = format!("{id}-bare");
    let ping = bare_service(&node, &format!("rt-bench/{bare_id}/ping")).publisher_builder().create().unwrap();
    let pong = bare_service(&node, &format!("rt-bench/{bare_id}/pong")).subscriber_builder().create().unwrap();
    let _bare_child = spawn_child("bare", &bare_id);
    let bare_rt: RoundTrip<'_> = Box::new(|i, patience| {
        ping.send_copy(i).unwrap();
        let t = Instant::now();
        loop {
            match pong.receive().unwrap() {
                Some(s) if *s.payload() == i => return true,
                Some(_) => {}
                None if t.elapsed() > patience => return false,
                None => std::hint::spin_loop(),
            }
        }
    });

    // state→command through mars-ipc's typed ports (schema check on both sides).
    let ns = RobotNamespace::new(&format!("{id}-state")).unwrap();
    let states = StateWriter::new(&node, &ns).unwrap();
    let commands = CommandReader::new(&node, &ns).unwrap();
    let _state_child = spawn_child("state", ns.robot());
    let mut st = RobotState { num_joints: 7, status: status::ACTIVE, ..Default::default() };
    st.applied_position[..7].copy_from_slice(&[0.1, -0.7, 0.1, -2.3, 0.1, 1.5, 0.7]);
    let start = Instant::now();
    let state_rt: RoundTrip<'_> = Box::new(|i, patience| {
        st.seq = i;
        st.timestamp_ns = start.elapsed().as_nanos() as u64;
        states.send(&st).unwrap();
        let t = Instant::now();
        loop {
            match commands.receive().unwrap() {
                Some(c) if c.state_seq == i => return true,
                Some(_) => {}
                None if t.elapsed() > patience => return false,
                None => std::hint::spin_loop(),
            }
        }
    });
    let mut hs = measure(&mut [bare_rt, state_rt]);
    let ours = hs.pop().unwrap();
    let bare_h = hs.pop().unwrap();
    let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p) as f64 / 1e3;
    println!();
    println!("| round trip | payload bytes (out / back) | p50 µs | p99 µs | p99.9 µs | max µs |");
    println!("|---|---|---:|---:|---:|---:|");
    for (name, sizes, h) in [
        ("bare iceoryx2 pub/sub (u64 ping-pong)", "8 / 8".to_string(), &bare_h),
        (
            "state→command (RobotState → JointCommand, mars-ipc)",
            format!("{} / {}", std::mem::size_of::<RobotState>(), std::mem::size_of::<JointCommand>()),
            &ours,
        ),
    ] {
        println!(
            "| {name} | {sizes} | {:.2} | {:.2} | {:.2} | {:.2} |",
            q(h, 0.5),
            q(h, 0.99),
            q(h, 0.999),
            h.max() as f64 / 1e3
        );
    }
    println!(
        "| ratio state→command / bare | | {:.2}× | {:.2}× | {:.2}× | |",
        q(&ours, 0.5) / q(&bare_h, 0.5),
        q(&ours, 0.99) / q(&bare_h, 0.99),
        q(&ours, 0.999) / q(&bare_h, 0.999)
    );
    println!();
    println!(
        "(at 1 kHz the period is 1000 µs: the p99.9 state→command round trip is {:.1} % of it)",
        q(&ours, 0.999) / 10.0
    );
}
