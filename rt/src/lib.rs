//! The real-time discipline both loops keep, the HAL's and marsd's servo: setup of a loop thread (core pinning,
//! SCHED_FIFO, locked memory), the absolute-deadline [`Ticker`] it runs on, per-thread allocation counting
//! ([`alloc_count`]), the machine-wide lock that keeps two real-time rigs apart ([`rig_lock`]), and how both
//! daemons log ([`logging`]).
//!
//! Setup is best-effort by design: a container or an unprivileged user is refused SCHED_FIFO and mlockall,
//! and a loop must still run there (tests, CI, a laptop). But a refusal is never silent: it is logged once,
//! at setup, from the thread concerned, saying what was refused, why, and which setting allows it.

pub mod alloc_count;
pub mod logging;
pub mod overlong;
pub mod rig_lock;

use std::time::Duration;

use anyhow::{bail, ensure};
use serde::Serialize;
use tracing::{info, warn};

/// Nanoseconds on CLOCK_MONOTONIC: the clock the HAL stamps its state frames with, so ages are differences.
pub use mars_ipc::clock::monotonic_ns;

/// What became of one real-time request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Outcome {
    NotRequested,
    Applied,
    /// The kernel said no for lack of privilege (a limit or a capability): fixable by configuration.
    Denied {
        errno: i32,
    },
    /// Any other error (an invalid priority, ...): a bug or a bad configuration value.
    Failed {
        errno: i32,
    },
}

/// Pins the calling thread to `core`; `None` leaves it where it is. Returns the core pinned to.
pub fn pin(core: Option<usize>) -> anyhow::Result<Option<usize>> {
    let Some(core) = core else { return Ok(None) };
    // Existence is checked against the machine, not against this thread's current mask: a thread spawned by an
    // already pinned thread inherits its one-core mask but may still move to any core of the cpuset.
    let configured = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_CONF) };
    ensure!(core < configured.max(1) as usize, "cannot pin to core {core}: this machine has {configured} cores");
    if !core_affinity::set_for_current(core_affinity::CoreId { id: core }) {
        bail!("cannot pin to core {core}: it is outside this process's cpuset (see `taskset -p`, the cgroup's cpus)");
    }
    Ok(Some(core))
}

/// Switches the calling thread (only it) to SCHED_FIFO at `priority` (1..=99).
pub fn try_sched_fifo(priority: i32) -> Outcome {
    let (lo, hi) =
        unsafe { (libc::sched_get_priority_min(libc::SCHED_FIFO), libc::sched_get_priority_max(libc::SCHED_FIFO)) };
    if !(lo..=hi).contains(&priority) {
        return Outcome::Failed { errno: libc::EINVAL };
    }
    let param = libc::sched_param { sched_priority: priority };
    // pthread_setschedparam returns the error number instead of setting errno.
    match unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) } {
        0 => Outcome::Applied,
        e @ (libc::EPERM | libc::EACCES) => Outcome::Denied { errno: e },
        e => Outcome::Failed { errno: e },
    }
}

/// Returns the calling thread to the normal scheduler (SCHED_OTHER), e.g. once its real-time part is done.
pub fn back_to_sched_other() {
    let param = libc::sched_param { sched_priority: 0 };
    // Cannot fail for SCHED_OTHER at priority 0 on this thread; nothing to report if it did.
    let _ = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param) };
}

/// Locks the process's current and future pages in RAM so a page fault never stalls a loop.
///
/// With a finite RLIMIT_MEMLOCK, MCL_FUTURE also makes later allocations fail once the limit is reached, so
/// the unit should say `LimitMEMLOCK=infinity`, not a number.
pub fn try_mlockall() -> Outcome {
    if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } == 0 {
        return Outcome::Applied;
    }
    match std::io::Error::last_os_error().raw_os_error().unwrap_or(0) {
        // ENOMEM: more is mapped than RLIMIT_MEMLOCK allows an unprivileged process.
        e @ (libc::EPERM | libc::ENOMEM) => Outcome::Denied { errno: e },
        e => Outcome::Failed { errno: e },
    }
}

/// What [`setup_realtime`] achieved for one thread (also worth a line in a run summary).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RtStatus {
    pub thread: String,
    /// The core the thread is pinned to.
    pub core: Option<usize>,
    pub pin_error: Option<String>,
    pub sched_fifo: Outcome,
    pub memory_locked: Outcome,
}

impl RtStatus {
    /// Everything requested was applied.
    pub fn ok(&self) -> bool {
        self.pin_error.is_none()
            && !matches!(self.sched_fifo, Outcome::Denied { .. } | Outcome::Failed { .. })
            && !matches!(self.memory_locked, Outcome::Denied { .. } | Outcome::Failed { .. })
    }
}

/// Pins the calling thread, makes it SCHED_FIFO at `priority` and (if `lock_memory`) locks the process's
/// memory, logging every refusal with its remedy. Call it from the loop thread before the loop starts.
pub fn setup_realtime(name: &str, core: Option<usize>, priority: Option<i32>, lock_memory: bool) -> RtStatus {
    let (core, pin_error) = match pin(core) {
        Ok(c) => (c, None),
        Err(e) => {
            warn!(thread = name, "{e:#}; the thread runs unpinned and may migrate between cores");
            (None, Some(format!("{e:#}")))
        }
    };
    let sched_fifo = priority.map_or(Outcome::NotRequested, try_sched_fifo);
    match (sched_fifo, priority) {
        (Outcome::Denied { errno }, Some(p)) => warn!(
            thread = name,
            "SCHED_FIFO priority {p} refused ({}): RLIMIT_RTPRIO is {} and the process lacks CAP_SYS_NICE, so the \
             loop runs under the normal scheduler and any busy process can delay it. Allow it with \
             `LimitRTPRIO={p}` in the systemd unit, `setcap cap_sys_nice+ep` on the binary, or `--cap-add \
             SYS_NICE --ulimit rtprio={p}` for a container",
            errno_name(errno),
            rlimit_text(libc::RLIMIT_RTPRIO)
        ),
        (Outcome::Failed { errno }, Some(p)) => warn!(
            thread = name,
            "SCHED_FIFO priority {p} failed ({}): priorities run 1..=99; the loop runs under the normal scheduler",
            errno_name(errno)
        ),
        _ => {}
    }
    let memory_locked = if lock_memory { try_mlockall() } else { Outcome::NotRequested };
    match memory_locked {
        Outcome::Denied { errno } => warn!(
            thread = name,
            "locking memory (mlockall) refused ({}): RLIMIT_MEMLOCK is {} and the process lacks CAP_IPC_LOCK, so \
             a page fault can stall the loop. Allow it with `LimitMEMLOCK=infinity` in the systemd unit, `setcap \
             cap_ipc_lock+ep` on the binary, or `--ulimit memlock=-1` for a container",
            errno_name(errno),
            rlimit_text(libc::RLIMIT_MEMLOCK)
        ),
        Outcome::Failed { errno } => warn!(thread = name, "locking memory (mlockall) failed ({})", errno_name(errno)),
        _ => {}
    }
    let status = RtStatus { thread: name.to_string(), core, pin_error, sched_fifo, memory_locked };
    info!(thread = name, core = ?status.core, sched_fifo = ?status.sched_fifo, memory_locked = ?status.memory_locked, "real-time setup");
    status
}

fn errno_name(errno: i32) -> String {
    let name = match errno {
        libc::EPERM => "EPERM",
        libc::EACCES => "EACCES",
        libc::ENOMEM => "ENOMEM",
        libc::EINVAL => "EINVAL",
        _ => return std::io::Error::from_raw_os_error(errno).to_string(),
    };
    name.to_string()
}

/// A soft resource limit as text ("0", "65536", "unlimited").
fn rlimit_text(resource: libc::__rlimit_resource_t) -> String {
    let mut lim = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    if unsafe { libc::getrlimit(resource, &mut lim) } != 0 {
        return "unknown".into();
    }
    if lim.rlim_cur == libc::RLIM_INFINITY { "unlimited".into() } else { lim.rlim_cur.to_string() }
}

/// One wake-up of a [`Ticker`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wake {
    /// The deadline this tick is for.
    pub deadline_ns: u64,
    /// How far past `deadline_ns` the thread woke.
    pub late_ns: u64,
    /// Whole periods skipped because the loop fell behind by more than one (0 normally).
    pub missed: u64,
}

impl Wake {
    /// When the thread woke, on [`monotonic_ns`].
    pub fn now_ns(&self) -> u64 {
        self.deadline_ns + self.late_ns
    }
}

/// A periodic loop clock on absolute CLOCK_MONOTONIC deadlines.
///
/// Absolute deadlines (`TIMER_ABSTIME`) do not drift: the time spent working in a tick, or a late wake-up,
/// does not push later ticks back. If the loop falls more than a period behind (a stall), the missed ticks
/// are skipped and counted rather than run back to back: a burst of catch-up ticks would send commands
/// faster than the robot's rate. Allocation-free and lock-free.
#[derive(Debug, Clone)]
pub struct Ticker {
    period_ns: u64,
    next_ns: u64,
    missed_total: u64,
}

impl Ticker {
    /// First deadline one period from now.
    pub fn new(period: Duration) -> Self {
        Self::starting_at(monotonic_ns() + period.as_nanos() as u64, period)
    }

    /// First deadline at `first_deadline_ns` on [`monotonic_ns`].
    pub fn starting_at(first_deadline_ns: u64, period: Duration) -> Self {
        let period_ns = period.as_nanos() as u64;
        assert!(period_ns > 0, "a Ticker needs a positive period");
        Self { period_ns, next_ns: first_deadline_ns, missed_total: 0 }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Periods skipped so far.
    pub fn missed_total(&self) -> u64 {
        self.missed_total
    }

    /// Moves the next deadline (and so the loop's phase) by `delta_ns`: a phase-locked loop nudges its ticks
    /// toward another clock's grid this way without changing the period.
    pub fn shift(&mut self, delta_ns: i64) {
        self.next_ns = self.next_ns.saturating_add_signed(delta_ns);
    }

    /// Sleeps until the next deadline (returns at once if it has passed).
    pub fn wait(&mut self) -> Wake {
        let ts = libc::timespec {
            tv_sec: (self.next_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (self.next_ns % 1_000_000_000) as libc::c_long,
        };
        // Returns the error number; EINTR (a signal) just means sleep again until the same absolute deadline.
        while unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) }
            == libc::EINTR
        {}
        let now = monotonic_ns();
        let behind = now.saturating_sub(self.next_ns);
        // Adopt the latest deadline that has passed: lateness is then the wake-up's own (< one period), and the
        // stall shows up as missed periods instead.
        let missed = behind / self.period_ns;
        let deadline_ns = self.next_ns + missed * self.period_ns;
        self.missed_total += missed;
        self.next_ns = deadline_ns + self.period_ns;
        Wake { deadline_ns, late_ns: now.saturating_sub(deadline_ns), missed }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticker_keeps_the_period_on_average() {
        let period = Duration::from_millis(1);
        let mut t = Ticker::new(period);
        let start = monotonic_ns();
        let (mut ticks, mut missed, mut max_late) = (0u64, 0u64, 0u64);
        while ticks + missed < 200 {
            let w = t.wait();
            ticks += 1;
            missed += w.missed;
            max_late = max_late.max(w.late_ns);
            assert!(w.late_ns < t.period_ns(), "lateness {} ns past a skip", w.late_ns);
        }
        let elapsed = monotonic_ns() - start;
        // Absolute deadlines: 200 periods take 200 ms plus the last wake-up's lateness, never less. The upper
        // bound is generous for a loaded machine (no SCHED_FIFO here).
        assert!(elapsed >= 199_000_000, "{elapsed} ns for 200 periods");
        assert!(elapsed < 300_000_000, "{elapsed} ns for 200 periods (missed {missed}, max late {max_late} ns)");
        assert_eq!(t.missed_total(), missed);
    }

    #[test]
    fn a_stalled_caller_skips_ahead_and_counts_missed_periods() {
        let mut t = Ticker::new(Duration::from_millis(2));
        let first = t.wait();
        std::thread::sleep(Duration::from_millis(11)); // 5.5 periods of "work"
        let w = t.wait();
        assert!((4..=8).contains(&w.missed), "missed {}", w.missed);
        assert!(w.late_ns < 2_000_000, "late {} ns", w.late_ns);
        assert_eq!(w.deadline_ns, first.deadline_ns + (1 + w.missed) * 2_000_000);
        // Back on schedule: the next wake-up is one period later, not a burst.
        let n = t.wait();
        assert_eq!(n.deadline_ns, w.deadline_ns + 2_000_000 * (1 + n.missed));
        assert!(n.now_ns() >= n.deadline_ns);
    }

    #[test]
    fn pinning_to_a_nonexistent_core_errors() {
        let err = pin(Some(1 << 20)).unwrap_err().to_string();
        assert!(err.contains("cannot pin to core"), "{err}");
        assert_eq!(pin(None).unwrap(), None);
    }

    #[test]
    fn pinning_to_an_allowed_core_works() {
        let core = core_affinity::get_core_ids().expect("core ids")[0].id;
        // In a throwaway thread, so the test harness's threads keep their affinity.
        let got = std::thread::spawn(move || pin(Some(core)).unwrap()).join().unwrap();
        assert_eq!(got, Some(core));
    }

    #[test]
    fn setup_reports_every_request_without_failing() {
        let s = std::thread::spawn(|| setup_realtime("test", None, Some(10), false)).join().unwrap();
        // Applied as root with CAP_SYS_NICE, denied elsewhere; either way reported, never an error.
        assert!(matches!(s.sched_fifo, Outcome::Applied | Outcome::Denied { .. }), "{s:?}");
        assert_eq!(s.memory_locked, Outcome::NotRequested);
        assert_eq!(try_sched_fifo(0), Outcome::Failed { errno: libc::EINVAL });
    }
}
