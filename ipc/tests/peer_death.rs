//! A peer's death as the liveness watch sees it, timed from the kernel's own word that the peer's process is gone
//! (its pidfd, watched by the stall witness's [`ExitWatch`], which shares no code with this crate).
//!
//! The test runs itself a second time as the peer: a process that beats the HAL side's heartbeat until it is
//! SIGKILLed. Half the rounds it dies while beating, before its heartbeat deadline; half it is first stopped
//! (SIGSTOP) until the watch finds it late, as a HAL whose exit the kernel takes tens of ms to finish is late
//! when it ends. Either way the verdict must follow the process's end, not the next deadline.

use std::process::{Child, Command};
use std::time::{Duration, Instant};

use mars_ipc::liveness::HEARTBEAT_DEADLINE;
use mars_ipc::node::create_node;
use mars_ipc::{Heartbeat, Peer, PeerWatch, RobotNamespace, Route, Side};
use stall_witness::process_exit::ExitWatch;
use stall_witness::{Attempt, at_most_one_rerun, monotonic_ns, witness};

const PEER_ENV: &str = "MARS_PEER_DEATH_CHILD";
/// The watch's SCHED_FIFO priority, marsd's `watchdog.priority`.
const WATCH_PRIORITY: i32 = 60;
/// The test's own thread, which polls the verdict: below the watch, above what is not real-time.
const POLL_PRIORITY: i32 = 50;
/// How late the verdict may come after the process's end, as the median of the rounds: the watch thread's
/// wake-up from its WaitSet and this test's 0.1 ms poll of the verdict.
const MEDIAN_VERDICT_AFTER_MS: f64 = 1.0;
/// How late any one verdict may come: half the heartbeat deadline, so a verdict that waited for the deadline's
/// route (or the registry's) fails, while a VM's 1–2 ms wake-up stall in one round does not decide the test.
const EVERY_VERDICT_AFTER_MS: f64 = 5.0;
const ROUNDS: usize = 8;

/// The peer: beats the HAL side's heartbeat of the namespace in `PEER_ENV` until killed.
#[test]
fn peer_process() {
    let Ok(robot) = std::env::var(PEER_ENV) else { return };
    let ns = RobotNamespace::new(&robot).unwrap();
    let (node, _) = create_node(&format!("peer-death-{robot}")).unwrap();
    let mut hb = Heartbeat::new(&node, &ns, Side::Hal).unwrap();
    loop {
        hb.beat().unwrap();
        std::thread::sleep(Duration::from_micros(500));
    }
}

fn spawn_peer(robot: &str) -> Child {
    Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "peer_process", "--nocapture", "--test-threads", "1"])
        .env(PEER_ENV, robot)
        .spawn()
        .unwrap()
}

fn wait_for(watch: &PeerWatch, want: Peer, timeout: Duration) -> u64 {
    let start = Instant::now();
    while watch.peer() != want {
        assert!(start.elapsed() < timeout, "still {:?} after {timeout:?}, wanted {want:?}", watch.peer());
        std::thread::sleep(Duration::from_micros(100));
    }
    monotonic_ns()
}

#[test]
fn a_killed_peer_is_declared_dead_within_a_ms_of_its_end_alive_or_late_by_the_median() {
    if std::env::var(PEER_ENV).is_ok() {
        return;
    }
    witness();
    at_most_one_rerun("a killed peer declared dead", rounds);
}

fn rounds(attempt: u32) -> Attempt {
    // This thread reads the verdict: above ordinary threads (the dying peer, the build), below the watch.
    let _ = stall_witness::core_watch::sched_fifo(POLL_PRIORITY);
    let mut after_end = Vec::with_capacity(ROUNDS);
    let mut window = (u64::MAX, 0);
    for round in 0..ROUNDS {
        let robot = format!("death{}-{attempt}-{round}", std::process::id());
        let ns = RobotNamespace::new(&robot).unwrap();
        let watch = PeerWatch::spawn_then(&ns, Side::Hal, || {
            let _ = stall_witness::core_watch::sched_fifo(WATCH_PRIORITY);
        })
        .unwrap();
        let mut child = spawn_peer(&robot);
        wait_for(&watch, Peer::Alive, Duration::from_secs(10));
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(watch.route(), Route::Pidfd, "a peer on this machine is held by pidfd");
        let late = round % 2 == 1;
        if late {
            signal(&child, libc::SIGSTOP);
            wait_for(&watch, Peer::Late, Duration::from_secs(2));
            std::thread::sleep(HEARTBEAT_DEADLINE);
        }
        let exit = ExitWatch::start(child.id() as libc::pid_t).unwrap();
        let killed = monotonic_ns();
        child.kill().unwrap();
        let dead = wait_for(&watch, Peer::Dead, Duration::from_secs(2));
        let gone = exit.join().unwrap();
        child.wait().unwrap();
        assert_eq!(watch.deaths(), 1, "one death, counted once");
        let ms = |a: u64, b: u64| (b as f64 - a as f64) * 1e-6;
        let how = if late { "stopped, late," } else { "beating" };
        eprintln!(
            "round {round} ({how}): the process gone {:.2} ms after the kill; declared dead {:.2} ms after that",
            ms(killed, gone),
            ms(gone, dead)
        );
        witness().within_or_excused(
            "a verdict after the process's end",
            ms(gone, dead),
            EVERY_VERDICT_AFTER_MS,
            gone,
            dead,
        )?;
        after_end.push(ms(gone, dead));
        window = (window.0.min(gone), window.1.max(dead));
    }
    let median = median(&mut after_end);
    eprintln!("median verdict {median:.2} ms after the process's end over {ROUNDS} rounds");
    witness().within_or_excused(
        "the median verdict after the process's end",
        median,
        MEDIAN_VERDICT_AFTER_MS,
        window.0,
        window.1,
    )
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    (values[(n - 1) / 2] + values[n / 2]) / 2.0
}

fn signal(child: &Child, sig: libc::c_int) {
    // SAFETY: kill(2) on our own child, which has not been reaped.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, sig) }, 0);
}

/// A peer the watch cannot hold by pidfd (it runs in another pid namespace, so the pid its node records names
/// another process here) is still found dead, through iceoryx2's node registry at a missed deadline.
#[test]
fn a_peer_in_another_pid_namespace_is_found_dead_through_the_registry() {
    if std::env::var(PEER_ENV).is_ok() {
        return;
    }
    let robot = format!("death-ns{}", std::process::id());
    let ns = RobotNamespace::new(&robot).unwrap();
    let watch = PeerWatch::spawn(&ns, Side::Hal).unwrap();
    // `unshare` (util-linux) runs the peer as pid 1 of a new pid namespace and SIGKILLs it when itself dies.
    let mut unshare = Command::new("unshare")
        .args(["--pid", "--kill-child"])
        .arg(std::env::current_exe().unwrap())
        .args(["--exact", "peer_process", "--nocapture", "--test-threads", "1"])
        .env(PEER_ENV, &robot)
        .spawn()
        .expect("util-linux's unshare");
    wait_for(&watch, Peer::Alive, Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(watch.route(), Route::Registry, "a peer in another pid namespace cannot be held by pidfd");
    unshare.kill().unwrap();
    unshare.wait().unwrap();
    let killed = Instant::now();
    wait_for(&watch, Peer::Dead, Duration::from_secs(2));
    eprintln!(
        "a peer in another pid namespace found dead {:.1} ms after its parent was reaped",
        killed.elapsed().as_secs_f64() * 1e3
    );
    assert_eq!(watch.deaths(), 1, "one death, counted once");
}
