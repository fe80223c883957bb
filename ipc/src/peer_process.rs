//! The peer's processes, held by pidfd: the kernel's word, in microseconds, that a peer has died.
//!
//! iceoryx2 tells a dead node from a live one by a file lock the kernel releases when the process's files are
//! closed. Finding that out means listing every node of the machine and reading each one's details (3–12 ms on
//! a busy VM), and cleaning up after it more (5–20 ms), both timed once with temporary timestamps in the watch: a
//! liveness watch that did this on every missed deadline learnt of a death up to 18 ms after the kernel had
//! finished the process (the HIL kill test's print before this file existed). A pidfd, opened while the peer was
//! alive, answers in one `poll` and cannot be fooled by the pid's reuse. The watch resolves its peer's pids
//! once per new set of heartbeat notifiers, off the critical path, and falls back to iceoryx2's look-up where it
//! cannot hold every peer process this way (the peer in another pid namespace, a process it may not see).

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;

/// Pidfds for the processes owning the nodes of a service's notifiers.
#[derive(Default)]
pub struct PeerProcesses {
    /// The notifier nodes these pidfds are for, in the order listed.
    nodes: Vec<UniqueNodeId>,
    /// One per node; empty unless every node's process could be held.
    fds: Vec<OwnedFd>,
}

impl PeerProcesses {
    /// Re-resolves if the service's notifier nodes are not the ones held (one read of shared memory when they
    /// are; a listing of the machine's nodes when they changed).
    pub fn follow<S: iceoryx2::service::Service>(&mut self, notifier_nodes: &[UniqueNodeId], config: &Config) {
        if notifier_nodes == self.nodes.as_slice() {
            return;
        }
        self.nodes = notifier_nodes.to_vec();
        self.fds = resolve::<S>(notifier_nodes, config).unwrap_or_default();
    }

    /// Whether the peer's processes are held (without asking them anything).
    pub fn held(&self) -> bool {
        !self.fds.is_empty()
    }

    /// Whether every held process has exited; `None` if they are not held (use iceoryx2's look-up instead).
    pub fn all_gone(&self) -> Option<bool> {
        if self.fds.is_empty() {
            return None;
        }
        Some(self.fds.iter().all(exited))
    }
}

/// A pidfd for each node's process, or `None` if one cannot be held (not listed, no details, no pidfd, or the
/// pid names another program here: the peer runs in another pid namespace).
fn resolve<S: iceoryx2::service::Service>(nodes: &[UniqueNodeId], config: &Config) -> Option<Vec<OwnedFd>> {
    let mut owners: Vec<Option<(i32, String)>> = vec![None; nodes.len()];
    Node::<S>::list(config, |state| {
        if let NodeState::Alive(view) = &state
            && let Some(i) = nodes.iter().position(|n| n == view.id())
            && let Some(d) = view.details()
        {
            let exe = String::from_utf8_lossy(d.executable().as_bytes()).into_owned();
            owners[i] = Some((d.process_id().value(), exe));
        }
        CallbackProgression::Continue
    })
    .ok()?;
    owners.into_iter().map(|o| o.and_then(|(pid, exe)| open_checked(pid, &exe))).collect()
}

/// A pidfd for `pid` if that process runs the executable `exe` (the node's own record of its program).
fn open_checked(pid: i32, exe: &str) -> Option<OwnedFd> {
    // SAFETY: pidfd_open(2) takes a pid and flags and returns a new descriptor or -1.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid, 0) };
    if fd < 0 {
        return None;
    }
    // SAFETY: a fresh descriptor that nothing else owns.
    let fd = unsafe { OwnedFd::from_raw_fd(fd as i32) };
    // Checked after opening: the pidfd pins this very process, so the name read now is its own.
    let running = std::fs::read_link(format!("/proc/{pid}/exe")).ok()?;
    (running.file_name()?.to_string_lossy() == exe).then_some(fd)
}

/// Whether the pidfd's process has exited (readable), without waiting.
fn exited(fd: &OwnedFd) -> bool {
    let mut p = libc::pollfd { fd: fd.as_raw_fd(), events: libc::POLLIN, revents: 0 };
    // SAFETY: one valid pollfd, zero timeout.
    unsafe { libc::poll(&mut p, 1, 0) > 0 }
}
