//! Does this machine charge time its vCPU was away to the thread that was running?
//!
//! A thread pinned to one core at SCHED_FIFO 80 (marsd's servo priority) spins reading CLOCK_MONOTONIC and its
//! own CPU clock. Every stretch of at least 3 µs in which it made no progress is either
//! - **not charged**: its CPU clock stood still — something else ran on the core (the kernel's real-time
//!   throttling gives others 5 % of each second; the stall witness's wake-ups, with `--witness`), or
//! - **charged**: its CPU clock advanced with the wall clock — an interrupt handler (a kernel without
//!   IRQ_TIME_ACCOUNTING charges it to the thread it interrupted) or the hypervisor running something else while
//!   the guest did not see it go (steal the host did not report).
//!
//! A loop tick that "computed" past its period by its own clock, with no interrupt in the kernel's trace, is the
//! second kind. With `--witness` the stall witness runs on every core, and the not-charged time less the run
//! without it is what the witness costs the core.
//!
//! With `--churn MB` it asks the other question: how late can a neighbour's own kernel work make a waker at the
//! witness's priority on the same core? A thread of the normal scheduler maps (populated) and unmaps MB megabytes
//! in a loop on that core while a SCHED_FIFO 95 thread wakes every millisecond and counts its late wake-ups. A
//! kernel that does not preempt its own code (`preempt=none`), or a hypervisor that works on the guest's page
//! tables, delays the waker by the neighbour's doing — lateness the witness must not take for the machine's.
//!
//! ```text
//! cargo run --release -p stall-witness --example absence_probe -- [SECONDS=10] [CPU=1] [--witness | --churn MB]
//! ```

use stall_witness::core_watch::{pin, sched_fifo, sleep_until};
use stall_witness::monotonic_ns;

/// Charged stretches by length (µs): the upper bound of each bucket.
const BUCKETS_US: [u64; 6] = [100, 250, 500, 1000, 2000, u64::MAX];
/// A stretch without progress at least this long counts (the loop's own turn is well under 1 µs).
const GAP_NS: u64 = 3_000;

fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// A charged stretch at least this long is kept, to ask the kernel's interrupt trace about it afterwards.
const LONG_NS: u64 = 300_000;

#[derive(Default)]
struct Tally {
    /// Charged stretches of at least [`LONG_NS`]: (CLOCK_MONOTONIC start, length) ns.
    long: Vec<(u64, u64)>,
    charged: u64,
    charged_ns: u64,
    longest_charged_ns: u64,
    by_length: [u64; BUCKETS_US.len()],
    not_charged: u64,
    not_charged_ns: u64,
}

impl Tally {
    /// A stretch of `gap` ns without progress from `start`, in which the thread's CPU clock advanced `cpu` ns.
    fn add(&mut self, start: u64, gap: u64, cpu: u64) {
        if cpu * 2 <= gap {
            self.not_charged += 1;
            self.not_charged_ns += gap;
            return;
        }
        self.charged += 1;
        self.charged_ns += gap;
        if gap >= LONG_NS && self.long.len() < self.long.capacity() {
            self.long.push((start, gap));
        }
        self.longest_charged_ns = self.longest_charged_ns.max(gap);
        let bucket = BUCKETS_US.iter().position(|&b| gap < b * 1000).unwrap_or(BUCKETS_US.len() - 1);
        self.by_length[bucket] += 1;
    }
}

fn spin(seconds: f64) -> Tally {
    let end = monotonic_ns() + (seconds * 1e9) as u64;
    let (mut t, mut c) = (monotonic_ns(), thread_cpu_ns());
    let mut tally = Tally { long: Vec::with_capacity(4096), ..Tally::default() };
    while t < end {
        let (t1, c1) = (monotonic_ns(), thread_cpu_ns());
        if t1 - t >= GAP_NS {
            tally.add(t, t1 - t, c1.saturating_sub(c));
        }
        (t, c) = (t1, c1);
    }
    tally
}

/// Maps `mb` MB populated and unmaps it, over and over, until `end` (CLOCK_MONOTONIC ns); returns the rounds.
fn churn(mb: usize, end: u64) -> Result<u64, String> {
    let len = mb << 20;
    let (prot, flags) =
        (libc::PROT_READ | libc::PROT_WRITE, libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_POPULATE);
    let mut rounds = 0;
    while monotonic_ns() < end {
        // SAFETY: a fresh anonymous mapping, unmapped at once with its own length; nothing reads it.
        let p = unsafe { libc::mmap(std::ptr::null_mut(), len, prot, flags, -1, 0) };
        if p == libc::MAP_FAILED {
            return Err(format!("mapping {mb} MB: {}", std::io::Error::last_os_error()));
        }
        unsafe { libc::munmap(p, len) };
        rounds += 1;
    }
    Ok(rounds)
}

/// A waker at the witness's priority every ms on `cpu` beside [`churn`] of `mb` MB (none for 0); prints its
/// lateness.
fn churn_probe(seconds: f64, cpu: usize, mb: usize) -> Result<(), String> {
    let end = monotonic_ns() + (seconds * 1e9) as u64;
    let neighbour = std::thread::spawn(move || if mb == 0 { Ok(0) } else { pin(cpu).and_then(|()| churn(mb, end)) });
    pin(cpu)?;
    sched_fifo(stall_witness::PRIORITY)?;
    let (mut due, mut wakes, mut over_100us, mut over_500us, mut worst) = (monotonic_ns() + 1_000_000, 0, 0, 0, 0);
    while due < end {
        sleep_until(due);
        let late = monotonic_ns().saturating_sub(due);
        (wakes, worst) = (wakes + 1, worst.max(late));
        over_100us += u64::from(late >= 100_000);
        over_500us += u64::from(late >= 500_000);
        due += 1_000_000;
    }
    let rounds = neighbour.join().map_err(|_| "the neighbour panicked")??;
    println!(
        "cpu {cpu}, {seconds:.0} s: a neighbour mapped and unmapped {mb} MB {rounds} times; a SCHED_FIFO {} waker \
         every 1 ms woke {wakes} times, {over_100us} of them ≥ 100 µs late, {over_500us} ≥ 500 µs, the latest {:.0} µs",
        stall_witness::PRIORITY,
        worst as f64 * 1e-3
    );
    Ok(())
}

/// The command line: `[SECONDS] [CPU] [--witness | --churn MB]`.
struct Args {
    seconds: f64,
    cpu: usize,
    with_witness: bool,
    churn_mb: Option<usize>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args { seconds: 10.0, cpu: 1, with_witness: false, churn_mb: None };
    let mut numbers = 0;
    let mut args = std::env::args().skip(1);
    let bad = |what: &str, v: &str| {
        format!("{what}: {v:?} is not a number (usage: [SECONDS] [CPU] [--witness | --churn MB])")
    };
    while let Some(arg) = args.next() {
        match (arg.as_str(), numbers) {
            ("--witness", _) => a.with_witness = true,
            ("--churn", _) => {
                let mb = args.next().unwrap_or_default();
                a.churn_mb = Some(mb.parse().map_err(|_| bad("--churn MB", &mb))?);
            }
            (v, 0) => (a.seconds, numbers) = (v.parse().map_err(|_| bad("SECONDS", v))?, 1),
            (v, 1) => (a.cpu, numbers) = (v.parse().map_err(|_| bad("CPU", v))?, 2),
            (v, _) => return Err(format!("unexpected {v:?} (usage: [SECONDS] [CPU] [--witness | --churn MB])")),
        }
    }
    Ok(a)
}

fn exit_with(e: String) -> ! {
    eprintln!("{e}");
    std::process::exit(2)
}

fn main() {
    let Args { seconds, cpu, with_witness, churn_mb } = parse_args().unwrap_or_else(|e| exit_with(e));
    if let Some(mb) = churn_mb {
        return churn_probe(seconds, cpu, mb).unwrap_or_else(|e| exit_with(e));
    }
    if with_witness && let Some(why) = stall_witness::witness().unable() {
        exit_with(format!("the stall witness cannot run here: {why}"));
    }
    pin(cpu).and_then(|()| sched_fifo(80)).unwrap_or_else(|e| exit_with(format!("cpu {cpu}: {e} (run as root)")));
    // The kernel's own trace of interrupt handlers (root): which charged stretches an interrupt explains.
    let trace = stall_witness::irq_trace::IrqTrace::start();
    let t = spin(seconds);
    let labels = ["<100 µs", "<250", "<500", "<1 ms", "<2 ms", "≥2 ms"];
    let hist: Vec<String> = labels.iter().zip(t.by_length).map(|(l, n)| format!("{l} {n}")).collect();
    println!(
        "cpu {cpu}, {seconds:.0} s at SCHED_FIFO 80{}: charged to the thread's CPU clock {} stretches, {:.1} ms, \
         longest {:.0} µs ({}); not charged (something else ran) {} stretches, {:.1} ms",
        if with_witness { ", stall witness on every core" } else { "" },
        t.charged,
        t.charged_ns as f64 * 1e-6,
        t.longest_charged_ns as f64 * 1e-3,
        hist.join(", "),
        t.not_charged,
        t.not_charged_ns as f64 * 1e-6
    );
    if let Some(why) = trace.problem() {
        println!("no kernel interrupt trace ({why}): the charged stretches are not told apart");
        return;
    }
    // Per long stretch: its interrupt time, or None where the trace's buffer no longer reaches back to it.
    let irq: Vec<(u64, Option<u64>)> =
        t.long.iter().map(|&(from, len)| (len, trace.time_in(cpu, from, from + len).map(|i| i.ns))).collect();
    let unexplained: Vec<u64> =
        irq.iter().filter(|(len, ns)| ns.is_some_and(|ns| ns * 2 < *len)).map(|(len, _)| *len).collect();
    println!(
        "of the {} charged stretches ≥ {} µs, {} had less than half their time in interrupt handlers by the kernel's \
         trace (the longest {:.0} µs): time the guest did not run and charged to the thread; {} no longer in the trace",
        t.long.len(),
        LONG_NS / 1000,
        unexplained.len(),
        unexplained.iter().max().copied().unwrap_or(0) as f64 * 1e-3,
        irq.iter().filter(|(_, ns)| ns.is_none()).count()
    );
    if with_witness {
        witness_caught(cpu, &t.long);
    }
}

/// Of the charged stretches (the guest absent, charged to the spinner), how many the stall witness saw, by length:
/// as a stall (a wake-up ≥ 500 µs late in it) and in a tick's account (≥ 150 µs late: what
/// `Witness::machine_time_in_ticks` takes off a loop tick) — what it misses of the absences a loop's thread clock
/// would count as work.
fn witness_caught(cpu: usize, long: &[(u64, u64)]) {
    let w = stall_witness::witness();
    let mut rows = Vec::new();
    for (lo, hi) in [(300, 500), (500, 750), (750, 1000), (1000, u64::MAX)] {
        let of_len: Vec<&(u64, u64)> = long.iter().filter(|(_, len)| (lo * 1000..hi * 1000).contains(len)).collect();
        let stall = |&&&(from, len): &&&(u64, u64)| {
            w.seen_on(Some(cpu), from, from + len).is_some_and(|e| e.stalled_ms() > 0.0)
        };
        let in_tick = |&&&(from, len): &&&(u64, u64)| w.taken_from_tick(cpu, from, from + len).late_ns > 0;
        let (stalls, ticks) = (of_len.iter().filter(stall).count(), of_len.iter().filter(in_tick).count());
        let hi = if hi == u64::MAX { "∞".to_string() } else { hi.to_string() };
        rows.push(format!("{lo}–{hi} µs: {stalls} / {ticks} of {}", of_len.len()));
    }
    println!("charged stretches the stall witness saw (as a stall / in a tick's account): {}", rows.join(", "));
}
