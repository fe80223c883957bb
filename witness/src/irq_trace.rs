//! The kernel's own record of the time each CPU spent in interrupts: hard IRQs, softirqs and the x86 system
//! vectors (timer, IPIs), from tracefs entry/exit events, timestamped on CLOCK_MONOTONIC.
//!
//! Why: a kernel without `CONFIG_IRQ_TIME_ACCOUNTING` (this VM's) charges an interrupt taken while a thread runs
//! to that thread's CPU clock. A loop whose tick "computed" past its period by its own clock may have spent that
//! time in a disk's completion interrupts instead (on this VM the block device's interrupt is pinned to core 1,
//! the servo core, and cannot be moved). Only the kernel can tell the two apart, and this is its account, not the
//! loop's.
//!
//! The witness records into a tracefs instance of its own (`instances/stall-witness-<pid>`), removed when the
//! process exits (and, for a process that was killed, by the next witness). A machine that booted without tracefs
//! mounted (a fresh CI VM: no systemd to mount it) gets it mounted at its usual place, as root may; where that
//! fails or tracefs is not writable (no root), the witness records nothing and excuses nothing.

use std::fs;
use std::path::{Path, PathBuf};

const TRACEFS: &str = "/sys/kernel/tracing";
const PREFIX: &str = "stall-witness-";
/// Ring buffer per CPU: at a few thousand events a second (a busy disk), a minute or more of history.
const BUFFER_KB_PER_CPU: u32 = 16 * 1024;
/// Entry/exit event pairs whose time between is interrupt time. The exits are enabled first: a handler that began
/// between enabling its entry and its exit would otherwise never end in the trace.
const EVENTS: [&str; 12] = [
    "irq/irq_handler_exit",
    "irq/softirq_exit",
    "irq_vectors/local_timer_exit",
    "irq_vectors/call_function_exit",
    "irq_vectors/call_function_single_exit",
    "irq_vectors/reschedule_exit",
    "irq/irq_handler_entry",
    "irq/softirq_entry",
    "irq_vectors/local_timer_entry",
    "irq_vectors/call_function_entry",
    "irq_vectors/call_function_single_entry",
    "irq_vectors/reschedule_entry",
];

/// Interrupt time on one CPU within a window.
#[derive(Debug, Clone, PartialEq)]
pub struct InterruptTime {
    pub cpu: usize,
    pub window: (u64, u64),
    pub ns: u64,
    /// Handler invocations (outermost) that overlapped the window.
    pub count: u64,
    /// The event (`irq_handler_entry: irq=36 name=virtio1-req.0`, `softirq_entry: vec=4 [action=BLOCK]`, …) whose
    /// handlers took most of that time.
    pub top: String,
}

impl std::fmt::Display for InterruptTime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "kernel interrupt trace, {}–{}: cpu {} spent {:.0} µs in {} interrupt handler(s), most in {}",
            crate::evidence::time_of_day(self.window.0),
            crate::evidence::time_of_day(self.window.1),
            self.cpu,
            self.ns as f64 * 1e-3,
            self.count,
            if self.top.is_empty() { "none" } else { &self.top }
        )
    }
}

pub struct IrqTrace {
    /// `None`: not recording (see [`Self::problem`]).
    dir: Option<PathBuf>,
    problem: Option<String>,
}

impl IrqTrace {
    /// Starts recording (best-effort: [`Self::problem`] says why not).
    pub fn start() -> Self {
        match start_instance() {
            Ok(dir) => Self { dir: Some(dir), problem: None },
            Err(why) => Self { dir: None, problem: Some(why) },
        }
    }

    /// Why this trace records nothing, if it does not.
    pub fn problem(&self) -> Option<&str> {
        self.problem.as_deref()
    }

    /// The time CPU `cpu` spent in interrupts within `[from, to]` (CLOCK_MONOTONIC ns); `None` when not recording
    /// or when the buffer no longer reaches back to `from`.
    pub fn time_in(&self, cpu: usize, from: u64, to: u64) -> Option<InterruptTime> {
        let dir = self.dir.as_ref()?;
        let text = fs::read_to_string(dir.join(format!("per_cpu/cpu{cpu}/trace"))).ok()?;
        let mut t = interrupt_time(&text, from, to)?;
        t.cpu = cpu;
        Some(t)
    }
}

fn write(path: &Path, value: &str) -> Result<(), String> {
    fs::write(path, value).map_err(|e| format!("cannot write {value:?} to {}: {e}", path.display()))
}

fn start_instance() -> Result<PathBuf, String> {
    let instances = Path::new(TRACEFS).join("instances");
    if !instances.exists() {
        mount_tracefs()?;
    }
    remove_stale(&instances);
    let pid = std::process::id();
    let dir = instances.join(format!("{PREFIX}{pid}"));
    if !dir.exists() {
        fs::create_dir(&dir).map_err(|e| format!("cannot create the tracefs instance {}: {e}", dir.display()))?;
    }
    // SAFETY: `remove_own_instance` is an `extern "C" fn()` that only calls rmdir on a path it builds.
    unsafe { libc::atexit(remove_own_instance) };
    write(&dir.join("trace_clock"), "mono")?;
    write(&dir.join("buffer_size_kb"), &BUFFER_KB_PER_CPU.to_string())?;
    for event in EVENTS {
        // An event this kernel lacks is left out (the x86 vectors elsewhere); the IRQ ones must be there.
        let enable = dir.join("events").join(event).join("enable");
        if let Err(e) = write(&enable, "1")
            && event.starts_with("irq/")
        {
            return Err(e);
        }
    }
    write(&dir.join("tracing_on"), "1")?;
    Ok(dir)
}

/// Mounts tracefs at [`TRACEFS`] (what systemd does at boot; a machine started without it lacks the mount).
fn mount_tracefs() -> Result<(), String> {
    let target = std::ffi::CString::new(TRACEFS).expect("a path without NUL");
    // SAFETY: three NUL-terminated strings and no data; mount(2) reads them and returns.
    let rc = unsafe { libc::mount(c"nodev".as_ptr(), target.as_ptr(), c"tracefs".as_ptr(), 0, std::ptr::null()) };
    if rc != 0 {
        let e = std::io::Error::last_os_error();
        return Err(format!("tracefs is not mounted at {TRACEFS} and mounting it failed: {e}"));
    }
    Ok(())
}

/// Instances of witnesses whose process is gone (killed before its exit handler ran).
fn remove_stale(instances: &Path) {
    let Ok(entries) = fs::read_dir(instances) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let pid = name.strip_prefix(PREFIX).and_then(|p| p.parse::<u32>().ok());
        if pid.is_some_and(|p| !Path::new(&format!("/proc/{p}")).exists()) {
            let _ = fs::remove_dir(e.path());
        }
    }
}

extern "C" fn remove_own_instance() {
    let dir = Path::new(TRACEFS).join("instances").join(format!("{PREFIX}{}", std::process::id()));
    let _ = fs::remove_dir(dir);
}

/// One trace line's time (ns), whether it enters or leaves a handler, and the event text after the time.
fn parse_line(line: &str) -> Option<(u64, bool, &str)> {
    // "<task>-<pid> [001] d.h1. 1234.567890: irq_handler_entry: irq=36 name=virtio1-req.0"
    let (head, event) = line.split_once(": ")?;
    let stamp = head.rsplit(' ').next()?;
    let (s, us) = stamp.split_once('.')?;
    let ns = s.parse::<u64>().ok()? * 1_000_000_000 + us.parse::<u64>().ok()? * 1000;
    let name = event.split(':').next()?;
    let entering = name.ends_with("_entry");
    (entering || name.ends_with("_exit")).then_some((ns, entering, event))
}

/// Interrupt time within `[from, to]` from one CPU's trace text (time-ordered): the union of handler intervals
/// (a hard IRQ nested in a softirq counts once). `None` when the trace starts after `from` (the ring buffer
/// overwrote the window's beginning) or says nothing.
pub fn interrupt_time(trace: &str, from: u64, to: u64) -> Option<InterruptTime> {
    let mut events = trace.lines().filter_map(parse_line).peekable();
    if events.peek()?.0 > from {
        return None;
    }
    // The handlers now running, outermost first: (kind, entry time, entry event).
    let mut running: Vec<(&str, u64, &str)> = Vec::new();
    let (mut ns, mut count) = (0u64, 0u64);
    let mut by_event: Vec<(String, u64)> = Vec::new();
    for (at, entering, event) in events {
        if at > to && running.is_empty() {
            break;
        }
        let kind = kind_of(event);
        // A CPU does not nest a handler kind in itself: a running one of this kind whose exit is missing (lost, or
        // its exit event not yet enabled when it began) has ended, and so have those that began inside it.
        let same = running.iter().position(|r| r.0 == kind);
        if entering {
            running.truncate(same.unwrap_or(running.len()));
            running.push((kind, at, event));
            continue;
        }
        let Some(i) = same else {
            continue; // its entry was before the buffer's start
        };
        running.truncate(i + 1);
        let (_, start, outer) = running.pop().expect("truncated to hold it");
        let overlap = at.min(to).saturating_sub(start.max(from));
        if !running.is_empty() || overlap == 0 {
            continue;
        }
        ns += overlap;
        count += 1;
        match by_event.iter_mut().find(|(e, _)| e == outer) {
            Some((_, t)) => *t += overlap,
            None => by_event.push((outer.to_string(), overlap)),
        }
    }
    let top = by_event.into_iter().max_by_key(|(_, t)| *t).map_or(String::new(), |(e, _)| e);
    Some(InterruptTime { cpu: 0, window: (from, to), ns, count, top })
}

/// An event's handler kind: its name less `_entry`/`_exit` (`softirq`, `local_timer`, …).
fn kind_of(event: &str) -> &str {
    let name = event.split(':').next().unwrap_or(event);
    name.strip_suffix("_entry").or_else(|| name.strip_suffix("_exit")).unwrap_or(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TRACE: &str = "\
# tracer: nop
          <idle>-0       [001] d.h1.   100.000100: irq_handler_entry: irq=36 name=virtio1-req.0
          <idle>-0       [001] d.h1.   100.000300: irq_handler_exit: irq=36 ret=handled
       mars-hal-77       [001] ..s1.   100.000400: softirq_entry: vec=4 [action=BLOCK]
       mars-hal-77       [001] d.h2.   100.000500: irq_handler_entry: irq=36 name=virtio1-req.0
       mars-hal-77       [001] d.h2.   100.000600: irq_handler_exit: irq=36 ret=handled
       mars-hal-77       [001] ..s1.   100.001400: softirq_exit: vec=4 [action=BLOCK]
       mars-hal-77       [001] d.h1.   100.002000: local_timer_entry: vector=236
       mars-hal-77       [001] d.h1.   100.002010: local_timer_exit: vector=236
";

    #[test]
    fn nested_handlers_count_once_and_the_window_clips() {
        let t = interrupt_time(TRACE, 100_000_100_000, 100_003_000_000).unwrap();
        assert_eq!(t.ns, 200_000 + 1_000_000 + 10_000);
        assert_eq!(t.count, 3);
        assert!(t.top.starts_with("softirq_entry: vec=4 [action=BLOCK]"), "{}", t.top);
        // Half the softirq inside the window.
        let t = interrupt_time(TRACE, 100_000_100_000, 100_000_900_000).unwrap();
        assert_eq!(t.ns, 200_000 + 500_000);
    }

    /// A softirq that began before its exit event was enabled never ends in the trace; the timer ticks after it
    /// still count once the next softirq shows it over (found: 0 handlers in 200 ms, 2 runs in 100).
    #[test]
    fn a_handler_whose_exit_is_missing_ends_at_the_next_of_its_kind() {
        const UNENDED: &str = "\
          <idle>-0       [001] ..s1.   100.000100: softirq_entry: vec=7 [action=SCHED]
       mars-hal-77       [001] d.h1.   100.001000: local_timer_entry: vector=236
       mars-hal-77       [001] d.h1.   100.001010: local_timer_exit: vector=236
       mars-hal-77       [001] ..s1.   100.002000: softirq_entry: vec=1 [action=TIMER]
       mars-hal-77       [001] ..s1.   100.002005: softirq_exit: vec=1 [action=TIMER]
       mars-hal-77       [001] d.h1.   100.003000: local_timer_entry: vector=236
       mars-hal-77       [001] d.h1.   100.003020: local_timer_exit: vector=236
       mars-hal-77       [001] d.h1.   100.004000: irq_handler_exit: irq=36 ret=handled
";
        let t = interrupt_time(UNENDED, 100_000_100_000, 100_005_000_000).unwrap();
        // The timer inside the unended softirq is lost with it; the softirq and the timer after it count.
        assert_eq!((t.count, t.ns), (2, 5_000 + 20_000));
    }

    #[test]
    fn a_window_older_than_the_buffer_says_nothing() {
        assert_eq!(interrupt_time(TRACE, 99_000_000_000, 100_003_000_000), None);
        assert_eq!(interrupt_time("# tracer: nop\n", 0, 1), None);
    }

    /// As root (CI, and the runtime's tests), a started trace records: a CPU busy for 200 ms takes timer
    /// interrupts, and the trace has them — on a machine that booted without tracefs mounted, too.
    #[test]
    fn a_started_trace_records_the_timer_interrupts_of_a_busy_cpu() {
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            eprintln!("not root: tracefs is root's, and the witness records nothing here (nothing to check)");
            return;
        }
        // SAFETY: sched_getcpu has no preconditions.
        let cpu = unsafe { libc::sched_getcpu() }.max(0) as usize;
        crate::core_watch::pin(cpu).unwrap();
        let spin = crate::hog::spin_for;
        let trace = IrqTrace::start();
        assert_eq!(trace.problem(), None);
        // A window is answered only once the CPU's buffer reaches back before it (its first event).
        spin(100);
        let from = crate::monotonic_ns();
        spin(200);
        let handlers = trace.time_in(cpu, from, crate::monotonic_ns()).map(|t| t.count);
        assert!(handlers > Some(0), "cpu {cpu} in 200 ms of spinning: {handlers:?} interrupt handlers traced");
    }
}
