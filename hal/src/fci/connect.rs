//! Connecting to an FCI robot in bounded time, without letting franka-rs change our own threads' scheduling.
//!
//! Two behaviours of franka-rs 0.4 shape this file:
//! - `Robot::new` puts the *calling* thread on SCHED_FIFO at the highest priority (99) whenever the process may
//!   (it may as root), even with `RealtimeConfig::Ignore`, which only ignores a failure to do so. Our main thread
//!   or a test thread left at FIFO 99 would starve everything else on a 2-core machine the moment it spun. So
//!   `Robot::new` runs on a thread of its own, which goes back to SCHED_OTHER as soon as `Robot::new` returns.
//! - Its TCP replies have no deadline (`blocking_receive_response` polls until the socket errors or closes), and
//!   the connect handshake waits for one: a peer that accepts the connection and never answers would hang the
//!   caller for good. So the caller waits on a channel with a timeout. A worker still stuck then is left behind:
//!   it holds nothing of ours and ends when the peer closes (or with the process). `read_once` gets the same
//!   treatment: its loop waits for a state newer than the last one it saw, and only each wait has a 1 s timeout.
//!
//! A panic inside franka-rs stays on the worker thread and comes back as an error, so neither case can panic or
//! hang the caller.

use std::sync::Arc;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::Duration;

use franka::{FciVersion, RealtimeConfig, Robot, RobotState};

use super::error::FciError;

/// A connected robot and the address it was reached at (for error messages).
pub struct Fci {
    /// Shared with a `read_once` worker that may outlive a timed-out call.
    robot: Arc<Robot>,
    addr: String,
}

impl std::fmt::Debug for Fci {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fci").field("addr", &self.addr).finish_non_exhaustive()
    }
}

impl Fci {
    pub fn addr(&self) -> &str {
        &self.addr
    }

    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// The FCI protocol version this connection negotiated (v10 for an FR3).
    pub fn fci_version(&self) -> FciVersion {
        self.robot.fci_version()
    }

    /// The version the robot announced.
    pub fn server_version(&self) -> u16 {
        self.robot.server_version()
    }

    /// The newest robot state, waited for at most `timeout`. Commands nothing; only for an idle robot (franka-rs's
    /// `read_once` competes for the state datagrams with a running control loop).
    pub fn read_once(&self, timeout: Duration) -> Result<RobotState, FciError> {
        let robot = Arc::clone(&self.robot);
        match run_bounded("fci-read", timeout, move || robot.read_once()) {
            Ok(Ok(state)) => Ok(state),
            Ok(Err(e)) => Err(FciError::from_franka(&self.addr, e)),
            Err(e) => Err(e.into_error(&self.addr, "waiting for a robot state", timeout)),
        }
    }
}

impl Fci {
    /// Clears a reflex (libfranka's `automaticErrorRecovery`), waited for at most `timeout`. Only while no
    /// control loop runs.
    pub fn recover(&self, timeout: Duration) -> Result<(), FciError> {
        let robot = Arc::clone(&self.robot);
        match run_bounded("fci-recover", timeout, move || robot.automatic_error_recovery()) {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(FciError::from_franka(&self.addr, e)),
            Err(e) => Err(e.into_error(&self.addr, "recovering from an error", timeout)),
        }
    }
}

/// Connects to the FCI robot at `addr` (`"172.16.0.2"`, or `"host:port"`; port 1337 by default), giving up after
/// `timeout`. Never needs a real-time kernel (`RealtimeConfig::Ignore`): reading a state does not, and the loop
/// that will need one makes its own real-time setup.
pub fn connect(addr: &str, timeout: Duration) -> Result<Fci, FciError> {
    if addr.is_empty() || addr.chars().any(char::is_whitespace) {
        return Err(FciError::BadAddress { addr: addr.to_string() });
    }
    let owned = addr.to_string();
    let outcome = run_bounded("fci-connect", timeout, move || {
        // Without CAP_SYS_NICE, Robot::new's raise fails (below RLIMIT_RTPRIO) and is ignored: the handshake, and
        // a worker stuck in it for good, never run above the loops (or above the tests' stall witness, which
        // then saw this thread at SCHED_FIFO 99 and could no longer tell the machine's stalls from ours).
        drop_sys_nice();
        let robot = Robot::new(&owned, RealtimeConfig::Ignore);
        // Whether or not it connected, Robot::new raised this thread first; undo it before anything else runs here.
        back_to_sched_other();
        robot
    });
    match outcome {
        Ok(Ok(robot)) => Ok(Fci { robot: Arc::new(robot), addr: addr.to_string() }),
        Ok(Err(e)) => Err(FciError::from_franka(addr, e)),
        Err(e) => Err(e.into_error(addr, "connecting", timeout)),
    }
}

/// Why a bounded call returned no result.
#[derive(Debug)]
pub(crate) enum Unfinished {
    TimedOut,
    /// The worker ended without a result: franka-rs panicked.
    Panicked,
    Spawn(std::io::Error),
}

impl Unfinished {
    pub(crate) fn into_error(self, addr: &str, during: &'static str, timeout: Duration) -> FciError {
        match self {
            Unfinished::TimedOut => FciError::timeout(addr, during, timeout),
            Unfinished::Panicked => FciError::Panicked { addr: addr.to_string(), during },
            Unfinished::Spawn(source) => FciError::Thread { addr: addr.to_string(), source },
        }
    }
}

/// Runs `f` on a new thread named `name` and waits at most `timeout` for its result. A worker that takes longer
/// is left to finish on its own; what it returns then is dropped there (a late `Robot` disconnects).
pub(crate) fn run_bounded<T: Send + 'static>(
    name: &str,
    timeout: Duration,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, Unfinished> {
    // Capacity 1: the worker's send never blocks, even when nobody waits any more.
    let (tx, rx) = mpsc::sync_channel(1);
    std::thread::Builder::new()
        .name(name.to_string())
        .spawn(move || {
            let _ = tx.send(f());
        })
        .map_err(Unfinished::Spawn)?;
    rx.recv_timeout(timeout).map_err(|e| match e {
        RecvTimeoutError::Timeout => Unfinished::TimedOut,
        RecvTimeoutError::Disconnected => Unfinished::Panicked,
    })
}

/// Takes `CAP_SYS_NICE` out of the calling thread's capabilities for good (capabilities are per thread): it can
/// then raise itself no higher than `RLIMIT_RTPRIO` allows. For a worker thread that must never run real-time.
fn drop_sys_nice() {
    const CAP_SYS_NICE: u32 = 23;
    // capget(2)/capset(2) on this thread (pid 0), version 3: a header and two data structs of three u32 masks.
    let mut header = [0x2008_0522u32, 0];
    let mut data = [[0u32; 3]; 2];
    // SAFETY: the kernel reads the header and writes the two data structs it is given.
    if unsafe { libc::syscall(libc::SYS_capget, header.as_mut_ptr(), data.as_mut_ptr()) } != 0 {
        return;
    }
    data[0][0] &= !(1 << CAP_SYS_NICE);
    data[0][1] &= !(1 << CAP_SYS_NICE);
    // SAFETY: as above; the kernel reads both.
    if unsafe { libc::syscall(libc::SYS_capset, header.as_mut_ptr(), data.as_ptr()) } != 0 {
        tracing::warn!("could not drop CAP_SYS_NICE on the FCI connect thread");
    }
}

/// Puts the calling thread back on the default time-sharing policy (what franka-rs's raise replaced).
fn back_to_sched_other() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pthread_self() is the calling thread, and `param` is a valid sched_param for SCHED_OTHER.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param) };
    if rc != 0 {
        tracing::warn!(errno = rc, "could not put the FCI connect thread back on SCHED_OTHER");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::TcpListener;
    use std::time::Instant;

    /// The calling thread's scheduling policy.
    fn policy() -> i32 {
        // SAFETY: 0 names the calling thread; no memory is passed.
        unsafe { libc::sched_getscheduler(0) }
    }

    /// A port on 127.0.0.1 with nothing listening (bound, then closed).
    fn closed_port() -> u16 {
        TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
    }

    #[test]
    fn a_refused_connection_is_a_clear_error_naming_the_address() {
        let addr = format!("127.0.0.1:{}", closed_port());
        let e = connect(&addr, Duration::from_secs(5)).unwrap_err();
        assert!(matches!(e, FciError::Network { .. }), "{e:?}");
        let text = e.to_string();
        assert!(
            text.contains(&addr) && text.contains("FCI is activated in Desk") && text.contains("refused"),
            "{text}"
        );
    }

    #[test]
    fn a_peer_that_accepts_and_never_answers_times_out_instead_of_hanging() {
        // The kernel completes the TCP handshake into the backlog; nobody ever reads or answers the Connect request.
        let silent = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = silent.local_addr().unwrap().to_string();
        let start = Instant::now();
        let e = connect(&addr, Duration::from_millis(500)).unwrap_err();
        let took = start.elapsed();
        assert!(matches!(e, FciError::Timeout { .. }), "{e:?}");
        assert!(took < Duration::from_secs(2), "took {took:?}");
        assert!(e.to_string().contains(&addr), "{e}");
        // The caller's thread was never touched.
        assert_eq!(policy(), libc::SCHED_OTHER);
        // Nor raised is the worker left waiting inside Robot::new's handshake (SCHED_FIFO 99 as root before).
        let worker = stuck_connect_worker_policy().expect("the worker still waits for the silent peer");
        assert_eq!(worker, "0", "the stuck fci-connect thread's policy (/proc stat field 41)");
    }

    /// The scheduling policy (/proc stat's field 41) of this process's thread named `fci-connect`, if one lives.
    fn stuck_connect_worker_policy() -> Option<String> {
        for task in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
            let stat = std::fs::read_to_string(task.path().join("stat")).unwrap_or_default();
            if let Some((head, tail)) = stat.rsplit_once(") ")
                && head.ends_with("(fci-connect")
            {
                return tail.split_whitespace().nth(41 - 3).map(str::to_owned);
            }
        }
        None
    }

    #[test]
    fn the_connect_thread_is_back_on_sched_other_after_robot_new() {
        // Robot::new raises its thread before it connects (to SCHED_FIFO 99 when the process may, e.g. as root),
        // so a refused connection shows it as well as a good one.
        let addr = format!("127.0.0.1:{}", closed_port());
        let worker = std::thread::spawn(move || {
            let raised = Robot::new(&addr, RealtimeConfig::Ignore).is_err() && policy() == libc::SCHED_FIFO;
            back_to_sched_other();
            (raised, policy())
        });
        let (raised, after) = worker.join().unwrap();
        eprintln!("Robot::new raised its thread to SCHED_FIFO: {raised}");
        assert_eq!(after, libc::SCHED_OTHER);
    }

    #[test]
    fn a_malformed_address_is_refused_before_anything_is_sent() {
        for addr in ["", "172.16.0.2 ", "a b"] {
            assert!(matches!(connect(addr, Duration::from_secs(1)), Err(FciError::BadAddress { .. })), "{addr:?}");
        }
    }

    #[test]
    fn a_panicking_worker_is_an_error_not_a_panic() {
        let r = run_bounded("t", Duration::from_secs(5), || -> u32 { panic!("inside franka-rs") });
        assert!(matches!(r, Err(Unfinished::Panicked)));
    }
}
