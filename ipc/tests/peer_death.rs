//! A peer's death as the liveness watch sees it, timed from the kernel's own word that the peer's process is gone
//! (its pidfd, watched by the stall witness's [`ExitWatch`], which shares no code with this crate).
//!
//! The test runs itself a second time as the peer: a process that beats the HAL side's heartbeat until it is
//! SIGKILLed. Half the rounds the peer first locks 256 MiB, as a real-time HAL locks its memory, so that the kernel
//! takes longer than the heartbeat deadline to finish it (the watch is then late and must ask again).

use std::process::{Child, Command};
use std::time::{Duration, Instant};

use mars_ipc::liveness::HEARTBEAT_DEADLINE;
use mars_ipc::node::create_node;
use mars_ipc::{Heartbeat, Peer, PeerWatch, RobotNamespace, Side};
use stall_witness::process_exit::ExitWatch;
use stall_witness::{Attempt, at_most_one_rerun, monotonic_ns, witness};

const PEER_ENV: &str = "MARS_PEER_DEATH_CHILD";
const LOCK_ENV: &str = "MARS_PEER_DEATH_LOCK_MIB";
/// The watch's SCHED_FIFO priority, marsd's `watchdog.priority`.
const WATCH_PRIORITY: i32 = 60;
/// How late the verdict may come after the later of the process's end and the heartbeat deadline after the
/// kill: the watch's 1 ms poll of a late peer, its wake-up and this test's 0.1 ms poll of the verdict.
const VERDICT_AFTER_MS: f64 = 2.0;

/// The peer: beats the HAL side's heartbeat of the namespace in `PEER_ENV` until killed.
#[test]
fn peer_process() {
    let Ok(robot) = std::env::var(PEER_ENV) else { return };
    let locked = lock_memory(std::env::var(LOCK_ENV).map_or(0, |v| v.parse().unwrap()));
    let ns = RobotNamespace::new(&robot).unwrap();
    let (node, _) = create_node(&format!("peer-death-{robot}")).unwrap();
    let mut hb = Heartbeat::new(&node, &ns, Side::Hal).unwrap();
    loop {
        hb.beat().unwrap();
        std::hint::black_box(&locked);
        std::thread::sleep(Duration::from_micros(500));
    }
}

/// `mib` MiB, touched and locked in memory (none if the process may not lock memory).
fn lock_memory(mib: usize) -> Vec<u8> {
    // SAFETY: mlockall(2) takes flags only.
    if mib == 0 || unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
        return Vec::new();
    }
    vec![1u8; mib << 20]
}

fn spawn_peer(robot: &str, lock_mib: usize) -> Child {
    Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "peer_process", "--nocapture", "--test-threads", "1"])
        .env(PEER_ENV, robot)
        .env(LOCK_ENV, lock_mib.to_string())
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
fn a_killed_peer_is_declared_dead_within_two_ms_of_its_end_or_its_deadline() {
    if std::env::var(PEER_ENV).is_ok() {
        return;
    }
    witness();
    at_most_one_rerun("a killed peer declared dead", rounds);
}

fn rounds(attempt: u32) -> Attempt {
    for round in 0..8 {
        let robot = format!("death{}-{attempt}-{round}", std::process::id());
        let ns = RobotNamespace::new(&robot).unwrap();
        let watch = PeerWatch::spawn_then(&ns, Side::Hal, || {
            let _ = stall_witness::core_watch::sched_fifo(WATCH_PRIORITY);
        })
        .unwrap();
        let mut child = spawn_peer(&robot, if round % 2 == 1 { 256 } else { 0 });
        wait_for(&watch, Peer::Alive, Duration::from_secs(10));
        std::thread::sleep(Duration::from_millis(50));
        let exit = ExitWatch::start(child.id() as libc::pid_t).unwrap();
        let killed = monotonic_ns();
        child.kill().unwrap();
        let dead = wait_for(&watch, Peer::Dead, Duration::from_secs(2));
        let gone = exit.join().unwrap();
        child.wait().unwrap();
        assert_eq!(watch.deaths(), 1, "one death, counted once");
        let due = gone.max(killed + HEARTBEAT_DEADLINE.as_nanos() as u64);
        let ms = |a: u64, b: u64| (b as f64 - a as f64) * 1e-6;
        eprintln!(
            "round {round}: the process gone {:.1} ms after the kill; declared dead {:.1} ms after that, {:.1} ms \
             after the later of it and the deadline",
            ms(killed, gone),
            ms(gone, dead),
            ms(due, dead)
        );
        witness().within_or_excused("the verdict after its due time", ms(due, dead), VERDICT_AFTER_MS, due, dead)?;
    }
    Ok(())
}
