//! When the kernel finished a process's exit: the moment a test may start holding a peer responsible for
//! noticing that the process is gone.
//!
//! A SIGKILLed process is not gone at the kill. The kernel first stops each of its threads, frees its memory
//! (slow for locked memory) and closes its files — which releases the file locks by which iceoryx2 tells a live
//! node from a dead one — and only then is the process a zombie. That work runs at the dying threads' own
//! priorities, a busy machine delays it, and no code of the process or of its peer takes part in it. A
//! [`ExitWatch`] records the kernel's own signal that it is over: its pidfd (Linux ≥ 5.3) turns readable once
//! the whole thread group has exited. A thread at SCHED_FIFO [`crate::PRIORITY`] waits on it, so its wake-up
//! comes well within a millisecond of that moment (unless the machine stalls, which the stall witness sees).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::JoinHandle;

use crate::core_watch::sched_fifo;
use crate::monotonic_ns;

/// Watches one process (a child or any other) for the end of its exit.
pub struct ExitWatch {
    gone_ns: Arc<AtomicU64>,
    thread: Option<JoinHandle<Result<(), String>>>,
}

impl ExitWatch {
    /// Starts watching `pid`. Fails if the kernel has no pidfd for it (no such process, a kernel before 5.3).
    /// Without SCHED_FIFO the watch still runs, its wake-up then as late as the normal scheduler makes it, which
    /// only ever makes the exit look later.
    pub fn start(pid: libc::pid_t) -> Result<Self, String> {
        // SAFETY: pidfd_open(2) takes a pid and flags, and returns a new descriptor or -1.
        let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid, 0) };
        if fd < 0 {
            return Err(format!("pidfd_open({pid}): {}", std::io::Error::last_os_error()));
        }
        let fd = fd as libc::c_int;
        let gone_ns = Arc::new(AtomicU64::new(0));
        let seen = gone_ns.clone();
        let thread = std::thread::Builder::new()
            .name(format!("exit-watch-{pid}"))
            .spawn(move || {
                let _ = sched_fifo(crate::PRIORITY);
                let waited = wait_readable(fd);
                seen.store(monotonic_ns(), Ordering::Release);
                // SAFETY: the descriptor is ours, opened above and closed once.
                unsafe { libc::close(fd) };
                waited
            })
            .map_err(|e| format!("spawning the exit watch: {e}"))?;
        Ok(Self { gone_ns, thread: Some(thread) })
    }

    /// CLOCK_MONOTONIC ns at which the kernel reported the process gone, once it did.
    pub fn gone_ns(&self) -> Option<u64> {
        let ns = self.gone_ns.load(Ordering::Acquire);
        (ns != 0).then_some(ns)
    }

    /// Waits for the verdict; `Err` if the watch could not wait on the pidfd (its time is then meaningless).
    pub fn join(mut self) -> Result<u64, String> {
        let waited = self.thread.take().map_or(Ok(()), |t| t.join().unwrap_or_else(|_| Err("panicked".into())));
        waited.map(|()| self.gone_ns.load(Ordering::Acquire))
    }
}

/// Blocks until `fd` (a pidfd) is readable: its process has exited.
fn wait_readable(fd: libc::c_int) -> Result<(), String> {
    let mut p = libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
    loop {
        // SAFETY: one valid pollfd, no timeout.
        let rc = unsafe { libc::poll(&mut p, 1, -1) };
        if rc > 0 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        if rc < 0 && e.kind() != std::io::ErrorKind::Interrupted {
            return Err(format!("poll on the pidfd: {e}"));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::Command;

    #[test]
    fn a_killed_child_is_reported_gone_after_the_kill_and_before_it_is_reaped() {
        let mut child = Command::new("sleep").arg("30").spawn().unwrap();
        let watch = ExitWatch::start(child.id() as libc::pid_t).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(50));
        assert_eq!(watch.gone_ns(), None, "sleep 30 is still running");
        let killed = monotonic_ns();
        child.kill().unwrap();
        let gone = watch.join().unwrap();
        let reaped = monotonic_ns();
        child.wait().unwrap();
        assert!(killed < gone && gone <= reaped, "killed {killed}, gone {gone}, reaped {reaped}");
    }

    #[test]
    fn no_such_process_is_an_error() {
        // The highest pid Linux can hand out is 2^22; beyond it nothing runs.
        assert!(ExitWatch::start(1 << 23).is_err());
    }
}
