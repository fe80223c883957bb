//! The peer's processes, held by pidfd: the kernel's own word, the moment it comes, that a peer has died.
//!
//! iceoryx2 tells a dead node from a live one by a file lock the kernel releases when the process's files are
//! closed. Finding that out means listing every node of the machine and reading each one's details (3–12 ms on
//! a busy VM), and cleaning up after it more (5–20 ms), both timed once with temporary timestamps in the watch: a
//! liveness watch that did this on every missed deadline learnt of a death up to 18 ms after the kernel had
//! finished the process (the HIL kill test's print before this file existed). A pidfd, opened while the peer was
//! alive, turns readable when the process is gone, so the watch's WaitSet wakes on it, and it cannot be fooled
//! by the pid's reuse. The watch resolves its peer's pids once per new set of heartbeat notifiers, off the
//! critical path, and falls back to iceoryx2's look-up where it cannot hold every peer process this way (the
//! peer in another pid namespace, a process it may not see).

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;

/// A pidfd: readable once its process has exited, so an iceoryx2 WaitSet can wait on a process's end.
#[derive(Debug)]
pub struct ProcessEnd(FileDescriptor);

impl FileDescriptorBased for ProcessEnd {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.0
    }
}

impl SynchronousMultiplexing for ProcessEnd {}

impl ProcessEnd {
    /// Whether the process has exited, without waiting.
    fn exited(&self) -> bool {
        // SAFETY: the descriptor is ours and open for as long as `self` lives.
        let mut p = libc::pollfd { fd: unsafe { self.0.native_handle() }, events: libc::POLLIN, revents: 0 };
        // SAFETY: one valid pollfd, zero timeout.
        unsafe { libc::poll(&mut p, 1, 0) > 0 }
    }
}

/// The processes owning the nodes of a service's notifiers, held by pidfd.
#[derive(Default)]
pub struct PeerProcesses {
    /// The notifier nodes these processes are for, in the order listed.
    nodes: Vec<UniqueNodeId>,
    /// One per distinct process still running when last asked; empty unless every node's process could be held.
    ends: Vec<ProcessEnd>,
}

impl PeerProcesses {
    /// The notifier nodes last followed.
    pub fn nodes(&self) -> &[UniqueNodeId] {
        &self.nodes
    }

    /// Re-resolves if the service's notifier nodes are not the ones followed (a listing of the machine's nodes).
    pub fn follow<S: iceoryx2::service::Service>(&mut self, notifier_nodes: &[UniqueNodeId], config: &Config) {
        if notifier_nodes == self.nodes.as_slice() {
            return;
        }
        self.nodes = notifier_nodes.to_vec();
        self.ends = resolve::<S>(notifier_nodes, config).unwrap_or_default();
    }

    /// The held processes' ends, to attach to a WaitSet.
    pub fn ends(&self) -> &[ProcessEnd] {
        &self.ends
    }

    /// Whether the peer's processes are held (without asking them anything).
    pub fn held(&self) -> bool {
        !self.ends.is_empty()
    }

    /// Whether every held process has exited; `None` if they are not held (use iceoryx2's look-up instead).
    pub fn all_gone(&self) -> Option<bool> {
        self.held().then(|| self.ends.iter().all(ProcessEnd::exited))
    }

    /// Lets go of the processes that have exited (a readable pidfd would wake a WaitSet again and again), keeping
    /// the nodes followed: the same notifiers are not resolved again.
    pub fn drop_exited(&mut self) {
        self.ends.retain(|e| !e.exited());
    }

    /// Lets go of every process, keeping the nodes followed: the watch falls back to iceoryx2's look-up.
    pub fn release(&mut self) {
        self.ends.clear();
    }
}

/// A pidfd for each distinct process owning one of the nodes, or `None` if one cannot be held (not listed, no
/// details, no pidfd, or the pid names another program here: the peer runs in another pid namespace).
fn resolve<S: iceoryx2::service::Service>(nodes: &[UniqueNodeId], config: &Config) -> Option<Vec<ProcessEnd>> {
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
    let mut owners = owners.into_iter().collect::<Option<Vec<_>>>()?;
    // One process often owns several of the nodes; one pidfd each is enough.
    owners.sort();
    owners.dedup_by_key(|(pid, _)| *pid);
    owners.into_iter().map(|(pid, exe)| open_checked(pid, &exe)).collect()
}

/// A pidfd for `pid` if that process runs the executable `exe` (the node's own record of its program).
fn open_checked(pid: i32, exe: &str) -> Option<ProcessEnd> {
    // SAFETY: pidfd_open(2) takes a pid and flags and returns a new descriptor or -1.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid, 0) };
    if fd < 0 {
        return None;
    }
    // Owned: closed when dropped. A descriptor fcntl does not know is refused.
    let fd = ProcessEnd(FileDescriptor::new(fd as i32)?);
    // Checked after opening: the pidfd pins this very process, so the name read now is its own.
    let running = std::fs::read_link(format!("/proc/{pid}/exe")).ok()?;
    (running.file_name()?.to_string_lossy() == exe).then_some(fd)
}
