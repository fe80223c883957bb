//! Which loop ticks blocked, and why a tick's answer took longer than the period, from the kernel's own
//! accounting of the loop thread.
//!
//! A thread gives the CPU up itself only by blocking (a lock, a sleep, I/O): the kernel counts each such voluntary
//! context switch (`ru_nvcsw`), so "the tick never blocks" is a count that must stay 0. Preemption and a virtual
//! CPU stolen by the hypervisor are not voluntary, and take no CPU time from the thread's clock
//! (`CLOCK_THREAD_CPUTIME_ID`; with paravirtual steal accounting, stolen time is not the thread's either).
//!
//! A tick's answer can leave after the tick itself: a robot-paced loop returns its command to the driver, which
//! sends it and then waits for the next state. So a tick is judged up to the next one's start when the thread
//! never waited in between (the driver's sending and reading were part of answering), else up to its own end. If
//! that took longer than the period, either the tick's own CPU time reached the period (its work did not fit:
//! the loop's doing) or it did not, and the rest of the time the thread was held off the CPU or busy in the driver
//! and the kernel after the tick (the machine's doing, as far as the loop can tell). So a test can blame the machine
//! for a late answer with evidence for that very tick.
//!
//! One caveat, stated where the counts are shown: a kernel without `CONFIG_IRQ_TIME_ACCOUNTING` charges interrupts
//! taken during the tick to the thread's CPU time, so "computing" may include the kernel's interrupt work.

use std::time::{Duration, Instant};

/// The calling thread's CPU time and voluntary context switches at one instant.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ThreadTimes {
    pub cpu_ns: u64,
    pub voluntary_switches: u64,
}

impl ThreadTimes {
    /// Two non-blocking syscalls (`clock_gettime(CLOCK_THREAD_CPUTIME_ID)`, `getrusage(RUSAGE_THREAD)`); no
    /// allocation. Zeros where the kernel refuses (never on Linux).
    pub fn now() -> Self {
        let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: both calls only write the structs passed, which live on this stack frame.
        let cpu_ns = if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
        } else {
            0
        };
        // SAFETY: as above; an all-zero rusage is a valid value of the plain C struct.
        let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
        let voluntary_switches =
            if unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut ru) } == 0 { ru.ru_nvcsw as u64 } else { 0 };
        Self { cpu_ns, voluntary_switches }
    }
}

/// An instant on the loop thread: the time and the thread's times.
#[derive(Debug, Clone, Copy)]
pub struct Stamp {
    pub at: Instant,
    pub times: ThreadTimes,
}

impl Stamp {
    /// Now, on the calling thread (see [`ThreadTimes::now`]).
    pub fn now() -> Self {
        Self { at: Instant::now(), times: ThreadTimes::now() }
    }
}

/// Why a tick's answer took longer than the period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overlong {
    /// The tick's own CPU time reached the period: its work did not fit.
    Computing,
    /// It did not: the thread was held off the CPU (preemption, hypervisor steal), or busy in the driver and the
    /// kernel after the tick.
    HeldUp,
}

/// Why answering took `wall` past `period` when the tick's own work took `tick_cpu`; `None` within the period.
pub fn overlong(wall: Duration, period: Duration, tick_cpu: Duration) -> Option<Overlong> {
    if wall <= period {
        None
    } else if tick_cpu >= period {
        Some(Overlong::Computing)
    } else {
        Some(Overlong::HeldUp)
    }
}

/// Ticks that blocked, and the others whose answer overran the period by why, since a loop started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct OverlongCounts {
    pub blocked: u64,
    pub computing: u64,
    pub held_up: u64,
}

/// The tick whose answer overran the most: which (counted from 1), how long, and the tick's own CPU time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Longest {
    pub tick: u64,
    pub wall_us: u64,
    pub tick_cpu_us: u64,
}

/// A tick whose own CPU time reached the period: when it started (CLOCK_MONOTONIC ns), how long its answer took
/// and its CPU time. A test may ask the kernel's interrupt trace about that very window (see `stall-witness`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ComputingTick {
    pub start_ns: u64,
    pub wall_us: u64,
    pub tick_cpu_us: u64,
}

/// Computing ticks recorded with their times, the first ones of a run (more are only counted).
pub const COMPUTING_TICKS_KEPT: usize = 4;

/// A tick that ended, waiting for the next one's start to be judged.
#[derive(Debug, Clone, Copy)]
struct Ended {
    number: u64,
    start: Stamp,
    end: Stamp,
    /// Not judged: it blocked (counted already), or a delay was injected into it on purpose.
    skip: bool,
}

/// The ticks of one loop, counted as they start and end. Allocation-free.
#[derive(Debug)]
pub struct TickAccount {
    period: Duration,
    ticks: u64,
    current: Option<Stamp>,
    ended: Option<Ended>,
    counts: OverlongCounts,
    longest: Option<Longest>,
    computing_ticks: [ComputingTick; COMPUTING_TICKS_KEPT],
    /// An instant and CLOCK_MONOTONIC at it (`Instant` reads that clock on Linux), to date the computing ticks.
    anchor: (Instant, u64),
}

impl TickAccount {
    pub fn new(period: Duration) -> Self {
        Self {
            period,
            ticks: 0,
            current: None,
            ended: None,
            counts: OverlongCounts::default(),
            longest: None,
            computing_ticks: [ComputingTick::default(); COMPUTING_TICKS_KEPT],
            anchor: (Instant::now(), crate::monotonic_ns()),
        }
    }

    /// The first computing ticks (at most [`COMPUTING_TICKS_KEPT`]; `counts().computing` says how many there were).
    pub fn computing_ticks(&self) -> &[ComputingTick] {
        let kept = (self.counts.computing as usize).min(COMPUTING_TICKS_KEPT);
        &self.computing_ticks[..kept]
    }

    fn monotonic_ns_of(&self, at: Instant) -> u64 {
        let (instant, ns) = self.anchor;
        match at.checked_duration_since(instant) {
            Some(after) => ns + after.as_nanos() as u64,
            None => ns.saturating_sub((instant - at).as_nanos() as u64),
        }
    }

    pub fn period(&self) -> Duration {
        self.period
    }

    /// The counts of the ticks judged so far: every tick before the current one.
    pub fn counts(&self) -> OverlongCounts {
        self.counts
    }

    /// The tick whose answer overran the most so far, if one did.
    pub fn longest(&self) -> Option<Longest> {
        self.longest
    }

    /// A tick starts at `start`: the one before is judged.
    pub fn begin(&mut self, start: Stamp) {
        if let Some(t) = self.ended.take() {
            self.judge(t, Some(start));
        }
        self.ticks += 1;
        self.current = Some(start);
    }

    /// The current tick ends at `end`; `injected`: a delay was put into it on purpose (a fault injected), so its
    /// timing is no finding about the loop.
    pub fn end(&mut self, end: Stamp, injected: bool) {
        let Some(start) = self.current.take() else { return };
        let blocked = !injected && end.times.voluntary_switches > start.times.voluntary_switches;
        self.counts.blocked += u64::from(blocked);
        self.ended = Some(Ended { number: self.ticks, start, end, skip: blocked || injected });
    }

    /// No tick follows: the last one is judged up to its own end.
    pub fn finish(&mut self) {
        if let Some(t) = self.ended.take() {
            self.judge(t, None);
        }
    }

    fn judge(&mut self, t: Ended, next: Option<Stamp>) {
        if t.skip {
            return;
        }
        let until = match next {
            Some(n) if n.times.voluntary_switches == t.end.times.voluntary_switches => n.at,
            _ => t.end.at,
        };
        let wall = until - t.start.at;
        let tick_cpu = Duration::from_nanos(t.end.times.cpu_ns.saturating_sub(t.start.times.cpu_ns));
        let Some(o) = overlong(wall, self.period, tick_cpu) else { return };
        let wall_us = wall.as_micros() as u64;
        match o {
            Overlong::Computing => {
                let start_ns = self.monotonic_ns_of(t.start.at);
                if let Some(slot) = self.computing_ticks.get_mut(self.counts.computing as usize) {
                    *slot = ComputingTick { start_ns, wall_us, tick_cpu_us: tick_cpu.as_micros() as u64 };
                }
                self.counts.computing += 1;
            }
            Overlong::HeldUp => self.counts.held_up += 1,
        }
        if self.longest.is_none_or(|l| wall_us > l.wall_us) {
            self.longest = Some(Longest { tick: t.number, wall_us, tick_cpu_us: tick_cpu.as_micros() as u64 });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn an_overrun_is_the_ticks_own_work_or_a_hold_up() {
        assert_eq!(overlong(MS, MS, MS), None, "within the period");
        assert_eq!(overlong(3 * MS, MS, MS), Some(Overlong::Computing));
        assert_eq!(overlong(3 * MS, MS, MS / 20), Some(Overlong::HeldUp));
    }

    fn stamp(base: Instant, ms: f64, cpu_ms: f64, switches: u64) -> Stamp {
        let at = base + Duration::from_secs_f64(ms * 1e-3);
        Stamp { at, times: ThreadTimes { cpu_ns: (cpu_ms * 1e6) as u64, voluntary_switches: switches } }
    }

    #[test]
    fn a_tick_is_judged_up_to_the_next_start_when_the_thread_never_waited_in_between() {
        let t0 = Instant::now();
        let mut a = TickAccount::new(MS);
        // Tick 1: 0.1 ms of work, then the driver waits for the next state (a switch): fine.
        a.begin(stamp(t0, 0.0, 0.0, 0));
        a.end(stamp(t0, 0.1, 0.1, 0), false);
        // Tick 2: 0.1 ms, but the thread did not wait before tick 3 began 1.5 ms later: held up while the driver
        // was sending this tick's answer.
        a.begin(stamp(t0, 1.0, 0.1, 1));
        assert_eq!(a.counts(), OverlongCounts::default());
        a.end(stamp(t0, 1.1, 0.2, 1), false);
        a.begin(stamp(t0, 2.6, 0.9, 1));
        assert_eq!(a.counts(), OverlongCounts { held_up: 1, ..Default::default() });
        // Tick 3 computes 1.2 ms itself.
        a.end(stamp(t0, 3.8, 2.1, 1), false);
        a.begin(stamp(t0, 4.0, 2.1, 2));
        assert_eq!(a.counts(), OverlongCounts { held_up: 1, computing: 1, ..Default::default() });
        // Tick 4 blocks inside (counted at its end, however short), tick 5 is delayed on purpose, tick 6 waits
        // for the next state after 0.1 ms: only tick 4 counts.
        a.end(stamp(t0, 4.1, 2.15, 3), false);
        assert_eq!(a.counts().blocked, 1);
        a.begin(stamp(t0, 6.0, 2.2, 3));
        a.end(stamp(t0, 9.0, 2.3, 4), true);
        a.begin(stamp(t0, 9.5, 2.3, 4));
        a.end(stamp(t0, 9.6, 2.4, 4), false);
        a.begin(stamp(t0, 11.0, 2.4, 5));
        a.end(stamp(t0, 11.1, 2.5, 5), false);
        a.finish();
        assert_eq!(a.counts(), OverlongCounts { held_up: 1, computing: 1, blocked: 1 });
        assert_eq!(a.longest(), Some(Longest { tick: 2, wall_us: 1600, tick_cpu_us: 100 }));
        // Tick 3 is dated on CLOCK_MONOTONIC, 2.6 ms after t0.
        let [c] = a.computing_ticks() else { panic!("{:?}", a.computing_ticks()) };
        assert_eq!((c.wall_us, c.tick_cpu_us), (1200, 1200));
        let t0_ns = crate::monotonic_ns() - t0.elapsed().as_nanos() as u64;
        assert!(c.start_ns.abs_diff(t0_ns + 2_600_000) < 100_000, "{} vs {}", c.start_ns, t0_ns + 2_600_000);
    }

    /// The kernel's counts behave as the account assumes, on this very machine: sleeping is a voluntary switch,
    /// spinning is CPU time without one.
    #[test]
    fn a_sleep_counts_as_a_voluntary_switch_and_spinning_as_cpu_time() {
        let start = ThreadTimes::now();
        std::thread::sleep(2 * MS);
        let slept = ThreadTimes::now();
        assert!(slept.voluntary_switches > start.voluntary_switches, "{start:?} → {slept:?}");
        let spin_from = Instant::now();
        while spin_from.elapsed() < 3 * MS {
            std::hint::spin_loop();
        }
        let spun = ThreadTimes::now();
        assert!(spun.cpu_ns > slept.cpu_ns, "{slept:?} → {spun:?}");
        assert_eq!(spun.voluntary_switches, slept.voluntary_switches, "spinning gave nothing up");
    }
}
