//! An encoder's threads never run real-time.
//!
//! SVT-AV1 (LeRobot's encoder), run as root, makes every thread it starts SCHED_FIFO 99: seen in marsd's recording
//! (ftrace: `marsd-record` threads at kernel priority 0 for 52 ms while the encoder opened, above the servo loop at
//! 80, the HAL at 85 and every other real-time thread on that core). A video file must never outrank the arm's
//! loops, so an encoder is opened through [`open_without_realtime`]:
//!
//! 1. while it opens, the opening thread is not root and lacks `CAP_SYS_NICE` (credentials are per thread, and a
//!    thread it starts inherits them): SVT-AV1 asks `geteuid()` whether to raise its threads, and a thread without
//!    `CAP_SYS_NICE` could not be raised above `RLIMIT_RTPRIO` anyway. Its other capabilities stay in effect
//!    (`CAP_IPC_LOCK` above all: marsd's `mlockall` locks what the encoder's threads map). Its threads keep that
//!    identity, and they only compute: the files are written by the caller.
//! 2. afterwards, should anything still have been raised (another encoder, an `RLIMIT_RTPRIO` of 99), the opening
//!    thread's policy is put back and every thread started during the opening is set to SCHED_OTHER.
//!
//! [`realtime_threads_demoted`] counts what step 2 had to undo.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU64, Ordering};

const CAP_SYS_NICE: u32 = 23;
/// Who the opening thread is while it opens, when it is root: `nobody`.
const NOT_ROOT: libc::uid_t = 65534;
const CAPABILITY_VERSION_3: u32 = 0x2008_0522;

static DEMOTED: AtomicU64 = AtomicU64::new(0);

/// Threads (the opener included) found real-time after an encoder opened and set back, in this process so far.
pub fn realtime_threads_demoted() -> u64 {
    DEMOTED.load(Ordering::Relaxed)
}

/// Runs `open` (an encoder's opening) so that neither this thread nor any thread it starts leaves it real-time.
pub(crate) fn open_without_realtime<T>(open: impl FnOnce() -> T) -> T {
    let caller = Policy::of(0);
    let before = thread_ids();
    let identity = Unprivileged::for_this_thread();
    let opened = open();
    drop(identity);
    let mut demoted = 0;
    if let Some(caller) = caller
        && Policy::of(0) != Some(caller)
    {
        caller.apply(0);
        demoted += 1;
    }
    for tid in thread_ids().difference(&before) {
        if Policy::of(*tid).is_some_and(|p| p.is_realtime()) {
            Policy::NORMAL.apply(*tid);
            demoted += 1;
        }
    }
    DEMOTED.fetch_add(demoted, Ordering::Relaxed);
    opened
}

/// A thread's scheduling policy and priority.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub(crate) struct Policy {
    pub policy: i32,
    pub priority: i32,
}

impl Policy {
    const NORMAL: Policy = Policy { policy: libc::SCHED_OTHER, priority: 0 };

    /// Thread `tid`'s (0: this thread's); `None` once it has ended.
    pub fn of(tid: libc::pid_t) -> Option<Policy> {
        let mut param = libc::sched_param { sched_priority: 0 };
        // SAFETY: plain syscalls on a thread id, writing only into `param`.
        let policy = unsafe { libc::sched_getscheduler(tid) };
        if policy < 0 || unsafe { libc::sched_getparam(tid, &mut param) } != 0 {
            return None;
        }
        // SCHED_RESET_ON_FORK is a flag, not a policy.
        Some(Policy { policy: policy & !libc::SCHED_RESET_ON_FORK, priority: param.sched_priority })
    }

    pub fn is_realtime(self) -> bool {
        self.policy == libc::SCHED_FIFO || self.policy == libc::SCHED_RR
    }

    /// Best effort: lowering a thread's policy needs no privilege; a thread that ended meanwhile is gone anyway.
    fn apply(self, tid: libc::pid_t) {
        let param = libc::sched_param { sched_priority: self.priority };
        // SAFETY: a plain syscall reading `param`.
        unsafe { libc::sched_setscheduler(tid, self.policy, &param) };
    }
}

/// This process's thread ids.
pub(crate) fn thread_ids() -> BTreeSet<libc::pid_t> {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else { return BTreeSet::new() };
    dir.filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok()).collect()
}

#[repr(C)]
struct CapHeader {
    version: u32,
    pid: libc::c_int,
}

#[repr(C)]
#[derive(Clone, Copy, Default)]
struct CapData {
    effective: u32,
    permitted: u32,
    inheritable: u32,
}

/// This thread as [`NOT_ROOT`] (when it was root) and without `CAP_SYS_NICE`, until dropped.
struct Unprivileged {
    was_root: bool,
    restore: Option<[CapData; 2]>,
}

impl Unprivileged {
    fn for_this_thread() -> Self {
        let caps = capabilities();
        // SAFETY: geteuid(2); setresuid(2) as a raw syscall changes this thread's effective uid alone (glibc's
        // wrapper would change every thread's). Leaving uid 0 empties the effective capability set; the permitted
        // set stays (the real and saved uids are still 0), so the wanted ones are raised back from it below.
        let was_root = unsafe { libc::geteuid() } == 0
            && unsafe { libc::syscall(libc::SYS_setresuid, -1i64, NOT_ROOT as i64, -1i64) } == 0;
        let Some(caps) = caps else { return Self { was_root, restore: None } };
        let mut without = caps;
        without[0].effective &= !(1 << CAP_SYS_NICE);
        set_capabilities(&without);
        Self { was_root, restore: Some(caps) }
    }
}

impl Drop for Unprivileged {
    fn drop(&mut self) {
        if self.was_root {
            // SAFETY: as above; back to uid 0, which copies the permitted set into the effective one.
            unsafe { libc::syscall(libc::SYS_setresuid, -1i64, 0i64, -1i64) };
        }
        if let Some(caps) = self.restore {
            // Raising effective capabilities back from the permitted set never fails.
            set_capabilities(&caps);
        }
    }
}

fn capabilities() -> Option<[CapData; 2]> {
    let mut header = CapHeader { version: CAPABILITY_VERSION_3, pid: 0 };
    let mut data = [CapData::default(); 2];
    // SAFETY: capget(2) with a version-3 header and room for its two data structs.
    let rc = unsafe { libc::syscall(libc::SYS_capget, &mut header, data.as_mut_ptr()) };
    (rc == 0).then_some(data)
}

fn set_capabilities(data: &[CapData; 2]) -> bool {
    let mut header = CapHeader { version: CAPABILITY_VERSION_3, pid: 0 };
    // SAFETY: capset(2) on this thread (pid 0) with a version-3 header and its two data structs.
    unsafe { libc::syscall(libc::SYS_capset, &mut header, data.as_ptr()) == 0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_opening_thread_keeps_its_policy_and_capabilities() {
        let caps = capabilities().expect("capget");
        let policy = Policy::of(0).unwrap();
        // SAFETY: geteuid(2).
        let euid = || unsafe { libc::geteuid() };
        let root = euid() == 0;
        let (during, euid_during) = open_without_realtime(|| (capabilities().unwrap()[0].effective, euid()));
        assert_eq!(during & (1 << CAP_SYS_NICE), 0, "CAP_SYS_NICE was in effect while opening");
        assert_eq!(during, caps[0].effective & !(1 << CAP_SYS_NICE), "other capabilities were lost while opening");
        assert!(!root || euid_during == NOT_ROOT, "root while opening");
        assert_eq!(root, euid() == 0, "the opener's uid not given back");
        assert_eq!(capabilities().unwrap()[0].effective, caps[0].effective, "capabilities not given back");
        assert_eq!(Policy::of(0), Some(policy));
    }

    /// What SVT-AV1 does as root, done by hand: the opener and a thread it starts each ask for SCHED_FIFO 99.
    /// Checked where that could succeed at all (root, or CAP_SYS_NICE); elsewhere it says so and checks the rest.
    #[test]
    fn threads_raised_while_opening_run_normal_afterwards() {
        let fifo99 = || {
            let param = libc::sched_param { sched_priority: 99 };
            // SAFETY: a plain syscall on this thread reading `param`.
            unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0 }
        };
        let could = std::thread::spawn(fifo99).join().unwrap();
        eprintln!("SCHED_FIFO 99 possible for this process: {could}");
        let (park_tx, park_rx) = std::sync::mpsc::channel::<()>();
        let (tid_tx, tid_rx) = std::sync::mpsc::channel();
        let (raised, started, (tid, started_raised)) = open_without_realtime(|| {
            let started = std::thread::spawn(move || {
                // SAFETY: gettid(2).
                let _ = tid_tx.send((unsafe { libc::gettid() }, fifo99()));
                let _ = park_rx.recv();
            });
            // As SVT-AV1's threads are, raised before the opening returns.
            (fifo99(), started, tid_rx.recv().unwrap())
        });
        assert!(!Policy::of(0).unwrap().is_realtime(), "the opener stayed real-time ({raised})");
        assert!(!Policy::of(tid).unwrap().is_realtime(), "a thread started while opening stayed real-time");
        eprintln!("raised while opening: opener {raised}, started thread {started_raised}");
        drop(park_tx);
        started.join().unwrap();
    }
}
