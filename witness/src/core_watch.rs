//! One core watched: a thread pinned to it at SCHED_FIFO [`crate::PRIORITY`] that wakes every [`PERIOD_NS`] on an
//! absolute deadline and records every wake-up at least [`FINE_LATE_NS`] late — a stretch in which its core ran
//! nothing below it. A stall is one of at least [`LATE_NS`]; the shorter ones count only inside a loop's tick.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use crate::monotonic_ns;

/// How often the witness wakes: a quarter of the HAL's period on an FR3. A stall between two wake-ups shows only if
/// one of its deadlines falls at least the threshold ([`LATE_NS`], or [`FINE_LATE_NS`] inside a tick) before the
/// stall's end, so one of [`LATE_NS`] + `PERIOD_NS` (750 µs) is seen wherever it falls, and inside a tick one of
/// 400 µs. This VM's absences often begin right after a wake-up of the witness (`absence_probe 30 1 --witness`,
/// 2026-11-29: charged stretches starting at the witness's own phase), where only the next deadline can see them:
/// at a 1 ms period a 1 ms absence went unseen on CI (a HAL tick of 1 024 µs of "CPU"), at 500 µs one of 1.6 ms
/// in ~500 µs pieces (`hil/tests/franka_sim.rs`, the stalled HAL, 1 run in 12). The price, what the witness costs
/// the core it watches (`absence_probe 10 1` with and without `--witness`, time taken from a spinner at SCHED_FIFO
/// 80, charged and not): 3.6 % at 1 ms, 7.7 % at 500 µs, 15 % at 250 µs. Whether it also draws more of the
/// hypervisor's absences is not settled: `examples/witness_cost.rs 8 30` (2026-11-30, idle VM, windows with and
/// without a witness in swapped pairs) gave steal +31 (−3–65) ms/s and a 1 kHz loop's late time +3 (−9–15) ms/s
/// with it, both intervals across 0, the host's own drift (5–133 ms/s of steal) larger than either.
pub const PERIOD_NS: u64 = 250_000;
/// A wake-up at least this late is recorded (the witness's own wake-up lateness on an idle VM is tens of µs). Not
/// lower: on a kernel that does not preempt itself (`preempt=none`) a thread of the rig in a system call on this
/// core delays the witness too — a neighbour mapping and unmapping 1 GB made a waker at [`crate::PRIORITY`] ≥ 100
/// µs late several times as often (`examples/absence_probe.rs --churn`) — and that is no stall of the machine.
pub const LATE_NS: u64 = 500_000;
/// A wake-up at least this late is recorded too, but counts only where the core ran one known thread all along: a
/// loop tick whose own CPU clock charged the time to itself ([`CoreWatch::stretches_in`], what
/// `Witness::machine_time_in_ticks` takes off such a tick). The hypervisor's absences come in pieces shorter than
/// [`LATE_NS`] too, back to back: `absence_probe 30 1 --witness` (2026-11-29, spinner at SCHED_FIFO 80) found
/// charged stretches of 765–850 µs with no wake-up [`LATE_NS`] late in them. Inside a tick the only other way to
/// delay the witness is the loop's own system call, which a few µs of UDP or clock reads do not make 150 µs.
pub const FINE_LATE_NS: u64 = 150_000;
/// Late wake-ups kept per core (the oldest go first): an hour of a noisy machine.
const CAPACITY: usize = 1 << 18;
/// Late wake-ups held in the thread while a reader holds the record: the witness never waits for a reader.
const PENDING: usize = 256;

/// A wake-up of the witness later than its deadline: its core ran nothing of the rig from `due_ns` to `woke_ns`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Late {
    pub due_ns: u64,
    pub woke_ns: u64,
}

impl Late {
    /// The part of this stretch inside `(from, to)`, in ns.
    fn overlap_ns(&self, (from, to): (u64, u64)) -> u64 {
        self.woke_ns.min(to).saturating_sub(self.due_ns.max(from))
    }
}

/// What one core's witness saw in a window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatenessSeen {
    pub core: usize,
    /// Its late stretches inside the window, summed (ms).
    pub ms: f64,
    pub longest_ms: f64,
    pub count: usize,
}

struct Shared {
    setup: OnceLock<Result<(), String>>,
    /// When the watch began (0 until then), and its latest wake-up whose lateness, if any, is in `late` already
    /// (a reader that saw only the wake-up could miss the late stretch it ended).
    started_ns: AtomicU64,
    recorded_ns: AtomicU64,
    late: Mutex<VecDeque<Late>>,
}

/// The witness thread of one core and what it recorded.
pub struct CoreWatch {
    core: usize,
    shared: Arc<Shared>,
}

impl CoreWatch {
    /// Starts the thread for `core`; returns once it has tried to pin itself and take SCHED_FIFO.
    pub fn start(core: usize) -> Self {
        let shared = Arc::new(Shared {
            setup: OnceLock::new(),
            started_ns: AtomicU64::new(0),
            recorded_ns: AtomicU64::new(0),
            late: Mutex::new(VecDeque::with_capacity(CAPACITY)),
        });
        let s = shared.clone();
        let spawned = std::thread::Builder::new().name(format!("witness-{core}")).spawn(move || watch(core, &s));
        if let Err(e) = spawned {
            let _ = shared.setup.set(Err(format!("core {core}: cannot start its thread: {e}")));
        }
        while shared.setup.get().is_none() {
            std::thread::sleep(Duration::from_millis(1));
        }
        Self { core, shared }
    }

    pub fn core(&self) -> usize {
        self.core
    }

    /// Why this core's witness cannot give evidence, if it cannot.
    pub fn setup_problem(&self) -> Option<String> {
        self.shared.setup.get().and_then(|r| r.clone().err())
    }

    /// Its late stretches (at least [`LATE_NS`]) inside `window`; `None` if it did not watch the window from its
    /// start.
    pub fn lateness_in(&self, window: (u64, u64)) -> Option<LatenessSeen> {
        let late = self.late_in(window, LATE_NS)?;
        let overlaps = late.iter().map(|l| l.overlap_ns(window) as f64 * 1e-6);
        let (ms, longest_ms) = overlaps.fold((0.0, 0.0), |(sum, max): (f64, f64), o| (sum + o, max.max(o)));
        Some(LatenessSeen { core: self.core, ms, longest_ms, count: late.len() })
    }

    /// Its late stretches of at least [`FINE_LATE_NS`] clipped to `window` (CLOCK_MONOTONIC ns from, to): for a
    /// window in which one loop thread ran by its own clock; `None` if it did not watch the window from its start.
    pub fn stretches_in(&self, window: (u64, u64)) -> Option<Vec<(u64, u64)>> {
        let late = self.late_in(window, FINE_LATE_NS)?;
        Some(late.iter().map(|l| (l.due_ns.max(window.0), l.woke_ns.min(window.1))).filter(|(a, b)| b > a).collect())
    }

    /// Periods of `period_ns` its late stretches inside `window` could have cost a loop on this core: each
    /// stretch rounded up to whole periods.
    pub fn lost_periods(&self, window: (u64, u64), period_ns: u64) -> u64 {
        let late = self.late_in(window, LATE_NS).unwrap_or_default();
        late.iter().map(|l| l.overlap_ns(window).div_ceil(period_ns.max(1))).sum()
    }

    /// The late stretches of at least `late_ns` overlapping `window`, the one still going on at `window`'s end
    /// included (so a stall the witness is still in counts); `None` if the watch began after the window did.
    fn late_in(&self, (from, to): (u64, u64), late_ns: u64) -> Option<Vec<Late>> {
        let started = self.shared.started_ns.load(Ordering::Acquire);
        if started == 0 || started > from {
            return None;
        }
        // Give the witness the time to wake once past the window (it may be in a stall right now).
        let patience = monotonic_ns() + 4_000_000;
        while self.shared.recorded_ns.load(Ordering::Acquire) < to && monotonic_ns() < patience {
            std::thread::sleep(Duration::from_micros(200));
        }
        let mut late: Vec<Late> = {
            let g = self.shared.late.lock().unwrap_or_else(|e| e.into_inner());
            let late_enough = |l: &&Late| l.woke_ns - l.due_ns >= late_ns;
            g.iter().filter(|l| l.overlap_ns((from, to)) > 0).filter(late_enough).copied().collect()
        };
        let last = self.shared.recorded_ns.load(Ordering::Acquire);
        if last < to && last + PERIOD_NS + late_ns <= to {
            late.push(Late { due_ns: last + PERIOD_NS, woke_ns: to });
        }
        Some(late)
    }
}

/// The witness thread: pin, SCHED_FIFO, then wake every period for ever, recording late wake-ups.
fn watch(core: usize, shared: &Shared) {
    let fifo = || {
        sched_fifo(crate::PRIORITY)
            .map_err(|e| format!("{e}: without it the witness would see the loops' own work as stalls"))
    };
    let setup = pin(core).and_then(|()| fifo()).map_err(|e| format!("core {core}: {e}"));
    let ok = setup.is_ok();
    let _ = shared.setup.set(setup);
    if !ok {
        return;
    }
    let mut pending: Vec<Late> = Vec::with_capacity(PENDING);
    let mut due = monotonic_ns() + PERIOD_NS;
    shared.started_ns.store(due, Ordering::Release);
    loop {
        sleep_until(due);
        let woke = monotonic_ns();
        if woke.saturating_sub(due) >= FINE_LATE_NS && pending.len() < PENDING {
            pending.push(Late { due_ns: due, woke_ns: woke });
        }
        if !pending.is_empty()
            && let Ok(mut record) = shared.late.try_lock()
        {
            for l in pending.drain(..) {
                if record.len() == CAPACITY {
                    record.pop_front();
                }
                record.push_back(l);
            }
        }
        // Published only once this wake-up's lateness is in the record (or it had none): a reader waits for it.
        if pending.is_empty() {
            shared.recorded_ns.store(woke, Ordering::Release);
        }
        // The next deadline after this wake-up: periods missed in a stall are not made up in a burst.
        due += PERIOD_NS;
        if due <= woke {
            due = woke + PERIOD_NS - (woke - due) % PERIOD_NS;
        }
    }
}

/// Sleeps until `ns` on CLOCK_MONOTONIC (absolute).
pub fn sleep_until(ns: u64) {
    let ts = libc::timespec { tv_sec: (ns / 1_000_000_000) as libc::time_t, tv_nsec: (ns % 1_000_000_000) as _ };
    // SAFETY: an absolute sleep on CLOCK_MONOTONIC with a valid timespec; EINTR just ends the sleep early.
    unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
}

/// Pins the calling thread to `core`.
pub fn pin(core: usize) -> Result<(), String> {
    // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET and sched_setaffinity take it by reference.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    unsafe { libc::CPU_SET(core, &mut set) };
    match unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) } {
        0 => Ok(()),
        _ => Err(format!("cannot pin to it: {}", std::io::Error::last_os_error())),
    }
}

/// Raises the calling thread to SCHED_FIFO `priority`.
pub fn sched_fifo(priority: i32) -> Result<(), String> {
    let param = libc::sched_param { sched_priority: priority };
    // SAFETY: the calling thread's own scheduling; the error comes back as the return value.
    match unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) } {
        0 => Ok(()),
        e => Err(format!("SCHED_FIFO {priority} refused ({})", std::io::Error::from_raw_os_error(e))),
    }
}
