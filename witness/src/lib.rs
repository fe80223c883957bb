//! A witness of machine stalls that is not the code under test.
//!
//! A timing test (the HIL rigs, the franka-sim tests) may blame the machine for a failure, and run once more, only
//! when this witness saw the machine stall at the failure's time. Its evidence is its own:
//!
//! - [`core_watch`]: one thread per core, pinned to it, SCHED_FIFO [`PRIORITY`] — above every loop of a rig (the
//!   HAL at 85, marsd's servo at 80) — waking every 250 µs on an absolute deadline and recording each wake-up
//!   later than [`core_watch::LATE_NS`]. Nothing of a rig's user-space code can delay it: only the kernel,
//!   interrupts, a higher-priority thread of another program, or the hypervisor (whose absences this VM charges to
//!   the running thread's CPU clock: `examples/absence_probe.rs`). The kernel's work for a rig's system call can
//!   delay it too, on a kernel that does not preempt itself: beside a neighbour's mmap churn (`absence_probe
//!   --churn`) wake-ups ≥ 100 µs late came several times as often, those ≥ [`core_watch::LATE_NS`] not measurably
//!   so; shorter lateness is therefore not recorded. A late wake-up is a stretch in which its core ran nothing of
//!   the rig's own code either.
//! - [`steal`]: the kernel's per-CPU `steal` counter (/proc/stat), sampled every 10 ms: CPU time the hypervisor
//!   took.
//! - [`irq_trace`]: the kernel's trace of interrupt handlers per CPU (tracefs, CLOCK_MONOTONIC): what a loop's
//!   own CPU clock cannot tell apart from its work on a kernel without IRQ time accounting.
//! - [`outrank`]: whether any user-space thread on the machine ran above the witness. Once one did (it may be the
//!   code under test: SVT-AV1's encoder threads at SCHED_FIFO 99 were), the witness excuses nothing more.
//!
//! It shares no code with the HAL or marsd (its one dependency is libc), so a bug there cannot make it excuse
//! itself. Where it cannot run above the loops (no SCHED_FIFO: an unprivileged user) it gives no evidence at all:
//! a witness under the normal scheduler would see the loops' own work as stalls.
//!
//! [`peer`]: for a failure only a peer simulator's pace can cause (franka-sim's control success rate), that peer's
//! own log of falling behind real time — an account neither of the code under test nor of this witness, and the
//! only other evidence a rerun may rest on.
//!
//! [`process_exit`]: when the kernel finished a killed process's exit (its pidfd), the moment from which a peer
//! can be held responsible for noticing it is gone.
//!
//! [`rerun`] is the rule the tests follow: at most one rerun per test, only with such evidence for that very
//! failure's time, printed to the test's stderr (past libtest's capture) and appended to `$MARS_RERUN_LOG`,
//! which `.ci/run` sums up in its last line.
//!
//! ```no_run
//! let w = stall_witness::witness(); // started once per process, at the start of each timing test
//! let (from, to) = (stall_witness::monotonic_ns() - 100_000_000, stall_witness::monotonic_ns());
//! if let Some(e) = w.stall_in(from, to, 15.0) {
//!     println!("the machine stalled: {e}");
//! }
//! ```

pub mod core_watch;
pub mod evidence;
pub mod hog;
pub mod irq_trace;
pub mod log_time;
pub mod outrank;
pub mod peer;
pub mod process_exit;
pub mod rerun;
pub mod steal;

use std::sync::OnceLock;

pub use evidence::Evidence;
pub use rerun::{Attempt, Excuse, at_most_one_rerun, report_machine_time};

use core_watch::CoreWatch;
use irq_trace::{InterruptTime, IrqTrace};
use outrank::OutrankWatch;
use steal::StealWatch;

/// The witness threads' SCHED_FIFO priority: above the HAL (85) and marsd's loops (80, 70), below the kernel's
/// own threads at 99.
pub const PRIORITY: i32 = 95;

/// A window [`Witness::wait_for_calm`] watches (2 s) is calm with late wake-ups, or steal, under this much (ms) in
/// it on every core, none of them this long (ms). This VM's host takes 1–4 % of an idle 2 s in stretches up to
/// ~15 ms (`cargo run --release -p stall-witness --example calm_probe`); the failures reruns were excused for
/// lost 8–47 % of their windows. A calm window is the host's ordinary noise, not none.
pub const CALM_MS: f64 = 50.0;
pub const CALM_LONGEST_MS: f64 = 5.0;

/// The stall witness of this process: a [`CoreWatch`] per core and a [`StealWatch`].
pub struct Witness {
    cores: Vec<CoreWatch>,
    steal: StealWatch,
    outrank: OutrankWatch,
    irq: IrqTrace,
}

/// The process's witness, started on the first call. Call it when a timing test starts: it sees only what happens
/// after.
pub fn witness() -> &'static Witness {
    static WITNESS: OnceLock<Witness> = OnceLock::new();
    WITNESS.get_or_init(Witness::start)
}

impl Witness {
    fn start() -> Self {
        let cores = online_cores().into_iter().map(CoreWatch::start).collect();
        Self {
            cores,
            steal: StealWatch::start(),
            outrank: OutrankWatch::start(PRIORITY as u32),
            irq: IrqTrace::start(),
        }
    }

    /// Why this witness can give no evidence, if it cannot: some core's thread could not be pinned or made
    /// SCHED_FIFO at [`PRIORITY`].
    pub fn unable(&self) -> Option<String> {
        let problems: Vec<String> = self.cores.iter().filter_map(CoreWatch::setup_problem).collect();
        if self.cores.is_empty() {
            return Some("no core to watch".into());
        }
        (!problems.is_empty()).then(|| problems.join("; "))
    }

    /// The witness's evidence that the machine stalled for at least `min_ms` within `[from_ns, to_ns]`
    /// (CLOCK_MONOTONIC): on one core, its late wake-ups inside the window adding up to `min_ms`; or the steal the
    /// hypervisor took over the window at least `min_ms` on one CPU. `None` when it saw less, did not watch the
    /// whole window, or cannot witness at all ([`Self::unable`]).
    pub fn stall_in(&self, from_ns: u64, to_ns: u64, min_ms: f64) -> Option<Evidence> {
        self.stall_on(None, from_ns, to_ns, min_ms)
    }

    /// [`Self::stall_in`] on one core (`Some`): the core a loop that failed runs on, for the lateness and the steal.
    pub fn stall_on(&self, core: Option<usize>, from_ns: u64, to_ns: u64, min_ms: f64) -> Option<Evidence> {
        let e = self.seen_on(core, from_ns, to_ns)?;
        (e.stalled_ms() >= min_ms).then_some(e)
    }

    /// An [`Excuse`] for `failure`, if the witness saw the machine stall for at least `min_ms` within `[from_ns,
    /// to_ns]` ([`Self::stall_in`]) (the one other way: a peer's own account, [`peer`]).
    pub fn excuse(&self, failure: impl Into<String>, from_ns: u64, to_ns: u64, min_ms: f64) -> Option<Excuse> {
        self.stall_in(from_ns, to_ns, min_ms).map(|e| Excuse::new(failure.into(), e))
    }

    /// [`Self::excuse`] with the stall on `core`, the one the loop that failed runs on.
    pub fn excuse_on(
        &self,
        core: usize,
        failure: impl Into<String>,
        from: u64,
        to: u64,
        min_ms: f64,
    ) -> Option<Excuse> {
        self.stall_on(Some(core), from, to, min_ms).map(|e| Excuse::new(failure.into(), e))
    }

    /// A measured time of `what` (ms) against its bound: `Ok` within it; beyond it, the excuse if the witness saw
    /// the machine stall at least the excess within `[from_ns, to_ns]`; otherwise a failure (it panics, saying what
    /// the witness saw).
    pub fn within_or_excused(&self, what: &str, measured_ms: f64, bound_ms: f64, from_ns: u64, to_ns: u64) -> Attempt {
        if measured_ms <= bound_ms {
            return Ok(());
        }
        let failure = format!("{what}: {measured_ms:.1} ms, over its bound of {bound_ms:.1} ms");
        match self.excuse(failure.clone(), from_ns, to_ns, measured_ms - bound_ms) {
            Some(e) => Err(e),
            None => match self.seen_in(from_ns, to_ns) {
                Some(seen) => panic!("{failure}; {seen}"),
                None => panic!("{failure}; the stall witness did not watch it"),
            },
        }
    }

    /// An [`Excuse`] for failures a log gives one line each (`lines`, each starting with its UTC timestamp, as
    /// tracing writes them): every one needs the witness's stall of at least `min_ms` from `before_ns` before its
    /// time to `after_ns` after it. `None` if there is no such line, a line has no time, or one was not excused.
    pub fn excuse_logged<'a>(
        &self,
        lines: impl IntoIterator<Item = &'a str>,
        before_ns: u64,
        after_ns: u64,
        min_ms: f64,
    ) -> Option<Excuse> {
        let mut excuses = Vec::new();
        for line in lines {
            let t = log_time::monotonic_of_line(line)?;
            excuses.push(self.excuse(line.trim(), t.saturating_sub(before_ns), t + after_ns, min_ms)?);
        }
        excuses.into_iter().max_by(|a, b| a.stalled_ms().total_cmp(&b.stalled_ms()))
    }

    /// What the machine took from each tick of a loop on `core` whose own CPU clock put it at `period_ns` or more
    /// (`ticks`: CLOCK_MONOTONIC start ns, wall ns, CPU ns by the thread's clock): the kernel's trace of interrupt
    /// handlers on the core (a kernel without IRQ time accounting charges them to the thread's clock) and the
    /// witness's late wake-ups on it (the hypervisor's absences, which this VM's clock charges to the thread that
    /// was running), each moment counted once ([`TickTaken::ns`]). `Ok` when every tick's clock time less that stays
    /// under the period — the loop's own work fitted, the clock was wrong; otherwise `Err` with the first tick that
    /// did not (its index and what was taken from it). This measures, it does not rerun: a tick no evidence
    /// explains is the loop's, however often the machine was seen elsewhere.
    pub fn machine_time_in_ticks(
        &self,
        core: usize,
        ticks: &[(u64, u64, u64)],
        period_ns: u64,
    ) -> Result<Vec<TickTaken>, Box<(usize, TickTaken)>> {
        let mut taken = Vec::with_capacity(ticks.len());
        for (i, &(start, wall, cpu)) in ticks.iter().enumerate() {
            let t = self.taken_from_tick(core, start, start + wall);
            if cpu.saturating_sub(t.ns()) >= period_ns {
                return Err(Box::new((i, t)));
            }
            taken.push(t);
        }
        Ok(taken)
    }

    /// What the machine took from `core` within `[from_ns, to_ns]`: interrupts by the kernel's trace, and the
    /// witness's stall (for a test's log, and [`Self::machine_time_in_ticks`]).
    pub fn taken_from_tick(&self, core: usize, from_ns: u64, to_ns: u64) -> TickTaken {
        let stall = self.seen_on(Some(core), from_ns, to_ns);
        let late = self.cores.iter().find(|c| c.core() == core).and_then(|c| c.stretches_in((from_ns, to_ns)));
        let late = late.unwrap_or_default();
        let in_late = late.iter().filter_map(|&(from, to)| self.irq.time_in(core, from, to));
        TickTaken {
            interrupts: self.irq.time_in(core, from_ns, to_ns),
            stall,
            late: late.len(),
            late_ns: late.iter().map(|(from, to)| to - from).sum(),
            interrupts_while_late_ns: in_late.map(|t| t.ns).sum(),
        }
    }

    /// What the machine took from a span of work that crossed processes and cores (a camera frame's way to a
    /// command), in ms: the late stretches inside `[from_ns, to_ns]` of the watched core that lost most (each at
    /// least [`core_watch::LATE_NS`]), not the steal (/proc/stat places it only to 10 ms). 0 when something
    /// outranked the witness; `None` when it cannot witness or did not watch the whole span.
    pub fn stalled_in_span(&self, from_ns: u64, to_ns: u64) -> Option<f64> {
        let e = self.seen_in(from_ns, to_ns)?;
        Some(if e.outranked.is_some() { 0.0 } else { e.lateness.map_or(0.0, |l| l.ms) })
    }

    /// Why the kernel's interrupt trace records nothing here (no tracefs, not root), if it does not.
    pub fn interrupt_trace_problem(&self) -> Option<&str> {
        self.irq.problem()
    }

    /// What the witness saw within `[from_ns, to_ns]`, stalled or not (for a test's log); `None` when it cannot
    /// witness or did not watch the whole window.
    pub fn seen_in(&self, from_ns: u64, to_ns: u64) -> Option<Evidence> {
        self.seen_on(None, from_ns, to_ns)
    }

    /// [`Self::seen_in`] on one core (`Some`) or the one that lost most (`None`).
    pub fn seen_on(&self, core: Option<usize>, from_ns: u64, to_ns: u64) -> Option<Evidence> {
        self.unable().is_none().then_some(())?;
        let window = (from_ns, to_ns.max(from_ns));
        let watched = self.cores.iter().filter(|c| core.is_none_or(|k| c.core() == k));
        let lateness: Vec<_> = watched.map(|c| c.lateness_in(window)).collect::<Option<_>>()?;
        let lateness = lateness.into_iter().max_by(|a, b| a.ms.total_cmp(&b.ms));
        let steal = self.steal.largest_in(window, core);
        Some(Evidence { window, lateness, steal, outranked: self.outrank.seen() })
    }

    /// Waits until the witness has watched a calm `window_ns` ([`CALM_MS`], [`CALM_LONGEST_MS`]) or `max_ns`
    /// passed; how long it waited (ns) and whether it saw calm. A stall seldom comes alone
    /// on a busy host (the excused attempt's minute is often busy throughout), and a rerun is one try: it is made
    /// on a machine the witness saw calm, where one can be had. It returns at once where the witness cannot
    /// witness.
    pub fn wait_for_calm(&self, window_ns: u64, max_ns: u64) -> (u64, bool) {
        let start = monotonic_ns();
        loop {
            let now = monotonic_ns();
            let calm = match self.seen_in(now.saturating_sub(window_ns).max(start), now) {
                Some(e) => now - start >= window_ns && e.is_calm(),
                None => return (now - start, false),
            };
            if calm || now - start >= max_ns {
                return (now - start, calm);
            }
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
    }

    /// Whole periods of `period_ns` lost on `core` within `[from_ns, to_ns]`: its witness's late wake-ups, each
    /// rounded down to whole periods (0 when the core is not watched, the witness cannot witness, or something
    /// outranked it).
    pub fn lost_periods(&self, core: usize, from_ns: u64, to_ns: u64, period_ns: u64) -> u64 {
        if self.unable().is_some() || self.outrank.seen().is_some() {
            return 0;
        }
        let Some(c) = self.cores.iter().find(|c| c.core() == core) else { return 0 };
        c.lost_periods((from_ns, to_ns.max(from_ns)), period_ns)
    }
}

/// What the machine took from a loop's core during one of its ticks (see [`Witness::taken_from_tick`]).
#[derive(Debug, Clone, PartialEq)]
pub struct TickTaken {
    pub interrupts: Option<InterruptTime>,
    /// What the witness saw of the window as it would for any failure (stalls of at least `LATE_NS`, steal), and
    /// whether something outranked it.
    pub stall: Option<Evidence>,
    /// Its wake-ups at least [`core_watch::FINE_LATE_NS`] late in the window, and their time in it (ns): inside a
    /// tick the loop's clock charged to itself, nothing of the loop's could have made them late.
    pub late: usize,
    pub late_ns: u64,
    /// The part of `interrupts` inside the witness's late stretches: a handler that made the witness late is in
    /// both accounts.
    pub interrupts_while_late_ns: u64,
}

impl TickTaken {
    /// What the machine took from the tick (ns): its interrupt time and the witness's late stretches in it, the
    /// interrupts inside those stretches once. Not the steal: /proc/stat counts it in 10 ms steps, sampled every
    /// 10 ms, so it cannot be placed inside a tick of about a millisecond (steal elsewhere in the samples' span
    /// would excuse a tick that really computed). Nothing when something outranked the witness.
    pub fn ns(&self) -> u64 {
        if self.stall.is_some_and(|e| e.outranked.is_some()) {
            return 0;
        }
        let irq = self.interrupts.as_ref().map_or(0, |t| t.ns);
        (irq + self.late_ns).saturating_sub(self.interrupts_while_late_ns.min(irq))
    }
}

impl std::fmt::Display for TickTaken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.interrupts {
            Some(t) => write!(f, "{t}; ")?,
            None => write!(f, "no kernel interrupt trace of it; ")?,
        }
        match &self.stall {
            Some(e) => write!(
                f,
                "{e}; in the tick {} wake-up(s) ≥ {} µs late, {:.0} µs",
                self.late,
                core_watch::FINE_LATE_NS / 1000,
                self.late_ns as f64 * 1e-3
            )?,
            None => write!(f, "the stall witness did not watch it")?,
        }
        if self.interrupts_while_late_ns > 0 {
            write!(
                f,
                " ({:.0} µs of the interrupts while the witness was late, counted once)",
                self.interrupts_while_late_ns as f64 * 1e-3
            )?;
        }
        write!(f, "; taken from the tick: {:.0} µs (steal not counted at this scale)", self.ns() as f64 * 1e-3)
    }
}

/// CLOCK_MONOTONIC in ns: the clock of the witness's records (and of the rig's frame stamps).
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The cores this process may run on (its affinity mask).
fn online_cores() -> Vec<usize> {
    // SAFETY: a zeroed cpu_set_t is a valid empty set; sched_getaffinity fills it.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    if unsafe { libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) } != 0 {
        return vec![0];
    }
    (0..libc::CPU_SETSIZE as usize).filter(|&c| unsafe { libc::CPU_ISSET(c, &set) }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core_watch::LatenessSeen;
    use crate::steal::StealSeen;

    fn taken(irq_us: u64, late_ms: f64, steal_ms: f64, irq_while_late_us: u64) -> TickTaken {
        let window = (1_000_000, 2_300_000);
        let interrupts = InterruptTime { cpu: 1, window, ns: irq_us * 1000, count: 2, top: String::new() };
        let lateness = Some(LatenessSeen { core: 1, ms: late_ms, longest_ms: late_ms, count: 1 });
        let steal = Some(StealSeen { cpu: 1, ms: steal_ms });
        TickTaken {
            interrupts: Some(interrupts),
            stall: Some(Evidence { window, lateness, steal, outranked: None }),
            late: 1,
            late_ns: (late_ms * 1e6) as u64,
            interrupts_while_late_ns: irq_while_late_us * 1000,
        }
    }

    /// A handler that made the witness late counts once, and the steal, counted in 10 ms steps, not at all.
    #[test]
    fn a_tick_is_credited_each_moment_once_and_no_steal() {
        assert_eq!(taken(400, 0.6, 0.0, 0).ns(), 1_000_000);
        assert_eq!(taken(400, 0.6, 0.0, 300).ns(), 700_000);
        assert_eq!(taken(0, 0.0, 10.0, 0).ns(), 0);
        assert_eq!(taken(100, 0.0, 10.0, 0).ns(), 100_000);
    }
}
