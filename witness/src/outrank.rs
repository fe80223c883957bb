//! Threads above the witness. The core watchers' lateness is the machine's only if nothing of the rig outranks
//! them: a user-space thread under SCHED_FIFO or SCHED_RR above [`crate::PRIORITY`] (an encoder library's threads
//! at 99, say) delays them as the machine would, and it may be the code under test. Every thread on the machine is
//! looked at every [`SCAN_MS`] (from /proc, under the normal scheduler); once one is seen above the witness, the
//! witness's lateness excuses nothing more in this process (see [`crate::Evidence::stalled_ms`]).
//!
//! Not counted: kernel threads (the kernel's own, at 99, are the machine), and [`crate::hog`]'s stall made on
//! purpose in this very process (a test's stand-in for the machine, named [`HOG_NAME`]).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::monotonic_ns;

pub const SCAN_MS: u64 = 100;
/// The name of [`crate::hog`]'s thread.
pub const HOG_NAME: &str = "witness-hog";
/// `PF_KTHREAD` in /proc's `flags` field.
const KERNEL_THREAD: u64 = 0x0020_0000;

/// A thread seen above the witness: the first one seen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outranker {
    pub pid: i32,
    pub tid: i32,
    pub comm: [u8; 16],
    /// 1: SCHED_FIFO, 2: SCHED_RR.
    pub policy: u32,
    pub priority: u32,
    /// When it was first seen (CLOCK_MONOTONIC ns).
    pub at_ns: u64,
}

impl Outranker {
    pub fn name(&self) -> String {
        let end = self.comm.iter().position(|&b| b == 0).unwrap_or(self.comm.len());
        String::from_utf8_lossy(&self.comm[..end]).into_owned()
    }
}

pub struct OutrankWatch {
    first: Arc<Mutex<Option<Outranker>>>,
}

impl OutrankWatch {
    pub fn start(above: u32) -> Self {
        let first = Arc::new(Mutex::new(None));
        let found = first.clone();
        let own = std::process::id() as i32;
        let _ = std::thread::Builder::new().name("witness-outrank".into()).spawn(move || {
            loop {
                if let Some(o) = scan(above, own) {
                    found.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(o);
                    return;
                }
                std::thread::sleep(Duration::from_millis(SCAN_MS));
            }
        });
        Self { first }
    }

    /// The first thread seen above the witness, if one was.
    pub fn seen(&self) -> Option<Outranker> {
        *self.first.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// One look at every thread on the machine.
fn scan(above: u32, own_pid: i32) -> Option<Outranker> {
    for proc_entry in std::fs::read_dir("/proc").ok()?.flatten() {
        let Some(pid) = proc_entry.file_name().to_str().and_then(|s| s.parse::<i32>().ok()) else { continue };
        let Ok(tasks) = std::fs::read_dir(proc_entry.path().join("task")) else { continue };
        for task in tasks.flatten() {
            let Ok(stat) = std::fs::read_to_string(task.path().join("stat")) else { continue };
            let Some(o) = outranker(&stat, pid, above) else { continue };
            if !(pid == own_pid && o.name() == HOG_NAME) {
                return Some(o);
            }
        }
    }
    None
}

/// The thread of a /proc `stat` line, if it is a user-space thread under SCHED_FIFO or SCHED_RR above `above`.
pub fn outranker(stat: &str, pid: i32, above: u32) -> Option<Outranker> {
    let (head, tail) = stat.rsplit_once(") ")?;
    let (tid, name) = head.split_once(" (")?;
    let fields: Vec<&str> = tail.split_whitespace().collect();
    // Field numbers as proc(5) gives them; `tail` starts at field 3.
    let field = |n: usize| fields.get(n - 3)?.parse::<u64>().ok();
    let (flags, priority, policy) = (field(9)?, field(40)?, field(41)?);
    if flags & KERNEL_THREAD != 0 || !(policy == 1 || policy == 2) || priority <= u64::from(above) {
        return None;
    }
    let mut comm = [0u8; 16];
    let n = name.len().min(16);
    comm[..n].copy_from_slice(&name.as_bytes()[..n]);
    let tid = tid.parse().ok()?;
    Some(Outranker { pid, tid, comm, policy: policy as u32, priority: priority as u32, at_ns: monotonic_ns() })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stat line with `flags`, `priority` and `policy` where proc(5) puts them.
    fn stat(name: &str, flags: u64, priority: u64, policy: u64) -> String {
        let mut fields = vec!["0".to_string(); 50];
        fields[0] = "S".into();
        fields[9 - 3] = flags.to_string();
        fields[40 - 3] = priority.to_string();
        fields[41 - 3] = policy.to_string();
        format!("4242 ({name}) {}", fields.join(" "))
    }

    #[test]
    fn only_user_threads_above_the_witness_outrank_it() {
        let o = outranker(&stat("marsd-record", 0x40, 99, 1), 7, 95).unwrap();
        assert_eq!((o.pid, o.tid, o.name().as_str(), o.priority), (7, 4242, "marsd-record", 99));
        assert!(outranker(&stat("a (b) c", 0, 96, 2), 7, 95).is_some(), "a name with parentheses");
        assert!(outranker(&stat("migration/0", KERNEL_THREAD, 99, 1), 7, 95).is_none(), "a kernel thread");
        assert!(outranker(&stat("marsd-servo", 0, 80, 1), 7, 95).is_none(), "below the witness");
        assert!(outranker(&stat("witness-1", 0, 95, 1), 7, 95).is_none(), "the witness's own priority");
        assert!(outranker(&stat("batch", 0, 99, 3), 7, 95).is_none(), "not a real-time policy");
    }
}
