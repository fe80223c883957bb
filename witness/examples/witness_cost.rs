//! Does the stall witness make the machine it watches stall more?
//!
//! The witness wakes every 250 µs on every core (15 % of a core by `absence_probe --witness`). On a VM that keeps a
//! vCPU runnable it may also draw more of the hypervisor's absences (steal), which the HIL tests then see — and
//! rerun on. This alternates windows with a witness (its own child process, as in a test binary) and without one,
//! in pairs whose order swaps from pair to pair (so a drifting host weighs on both alike), and measures in each:
//!
//! - **steal**: the kernel's `steal` counter (/proc/stat), all CPUs, ms per second of the window;
//! - **a 1 kHz loop's lateness**: a thread per core at SCHED_FIFO 80 (marsd's servo priority) waking every 1 ms on
//!   an absolute deadline, its wake-ups at least 0.5 ms late added up, ms per second — what a servo loop loses;
//! - the witness child's own CPU time (its rusage), % of one core.
//!
//! It prints each pair and the mean difference (with − without) with its 95 % t interval over the pairs.
//!
//! ```text
//! cargo run --release -p stall-witness --example witness_cost -- [PAIRS=10] [SECONDS=30]   # as root
//! ```

use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use stall_witness::core_watch::{pin, sched_fifo, sleep_until};
use stall_witness::monotonic_ns;

const LOOP_PERIOD_NS: u64 = 1_000_000;
const LATE_NS: u64 = 500_000;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("--witness-for") {
        return witness_for(args.get(1).and_then(|s| s.parse().ok()).unwrap_or(30));
    }
    let pairs: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(10);
    let secs: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(30);
    let late_ns = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let loops: Vec<_> = (0..cores()).map(|c| spawn_loop(c, late_ns.clone(), stop.clone())).collect();
    println!(
        "{pairs} pairs of {secs} s windows; per window: steal ms/s (all CPUs), 1 kHz loops' late ms/s, witness CPU %"
    );
    let (mut steal_d, mut late_d) = (Vec::new(), Vec::new());
    for pair in 0..pairs {
        let order = if pair % 2 == 0 { [true, false] } else { [false, true] };
        let mut got = [Window::default(); 2];
        for with in order {
            got[usize::from(!with)] = window(with, secs, &late_ns);
        }
        let [w, wo] = got;
        println!(
            "pair {:2}: with   steal {:6.2}  late {:6.2}  witness {:4.1} %   without   steal {:6.2}  late {:6.2}",
            pair + 1,
            w.steal,
            w.late,
            w.witness_cpu,
            wo.steal,
            wo.late
        );
        steal_d.push(w.steal - wo.steal);
        late_d.push(w.late - wo.late);
    }
    stop.store(true, Ordering::Release);
    for l in loops {
        let _ = l.join();
    }
    println!("with − without, mean (95 % t interval over {pairs} pairs):");
    println!("  steal        {}", interval(&steal_d));
    println!("  loops' late  {}", interval(&late_d));
}

#[derive(Default, Clone, Copy)]
struct Window {
    steal: f64,
    late: f64,
    witness_cpu: f64,
}

/// One window of `secs`, with a witness child or without; rates per second.
fn window(with: bool, secs: u64, late_ns: &AtomicU64) -> Window {
    let child = with.then(|| {
        let exe = std::env::current_exe().expect("this program's path");
        Command::new(exe).args(["--witness-for", &secs.to_string()]).spawn().expect("a witness child")
    });
    // Let the child start its threads before the window opens.
    std::thread::sleep(Duration::from_millis(200));
    let (t0, s0, l0) = (monotonic_ns(), steal_ms(), late_ns.load(Ordering::Acquire));
    std::thread::sleep(Duration::from_secs(secs).saturating_sub(Duration::from_millis(400)));
    let (t1, s1, l1) = (monotonic_ns(), steal_ms(), late_ns.load(Ordering::Acquire));
    let per_s = |x: f64| x / ((t1 - t0) as f64 / 1e9);
    let witness_cpu = child.map_or(0.0, |c| 100.0 * child_cpu_s(c) / secs as f64);
    Window { steal: per_s(s1 - s0), late: per_s((l1 - l0) as f64 / 1e6), witness_cpu }
}

/// The child: the stall witness on every core for `secs`, doing nothing else.
fn witness_for(secs: u64) {
    let w = stall_witness::witness();
    if let Some(why) = w.unable() {
        eprintln!("the witness cannot run here: {why}");
        std::process::exit(2);
    }
    std::thread::sleep(Duration::from_secs(secs));
}

/// A 1 kHz loop pinned to `core` at SCHED_FIFO 80, adding up its wake-ups at least [`LATE_NS`] late.
fn spawn_loop(core: usize, late_ns: Arc<AtomicU64>, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        pin(core).expect("pinning the loop");
        sched_fifo(80).expect("SCHED_FIFO 80 (run as root)");
        let mut due = monotonic_ns() + LOOP_PERIOD_NS;
        while !stop.load(Ordering::Acquire) {
            sleep_until(due);
            let late = monotonic_ns().saturating_sub(due);
            if late >= LATE_NS {
                late_ns.fetch_add(late, Ordering::AcqRel);
            }
            // Deadlines missed while late are skipped, not caught up: a servo tick does not run twice.
            due += LOOP_PERIOD_NS * (1 + late / LOOP_PERIOD_NS);
        }
    })
}

/// Steal of all CPUs (ms), from /proc/stat's `cpu` line.
fn steal_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/stat").expect("/proc/stat");
    let line = stat.lines().next().expect("the cpu line");
    let steal: f64 = line.split_whitespace().nth(8).and_then(|v| v.parse().ok()).expect("its steal column");
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    steal * 1000.0 / hz
}

/// Waits for the child and returns its user + system CPU time (s).
fn child_cpu_s(mut child: std::process::Child) -> f64 {
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid; wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    if r != pid {
        let _ = child.wait();
        return f64::NAN;
    }
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 / 1e6;
    s(usage.ru_utime) + s(usage.ru_stime)
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// "mean (lo – hi)" with a 95 % t interval.
fn interval(d: &[f64]) -> String {
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    if d.len() < 2 {
        return format!("{mean:.2} (one pair: no interval)");
    }
    let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let half = t975(d.len() - 1) * sd / n.sqrt();
    format!("{mean:.2} ({:.2} – {:.2})", mean - half, mean + half)
}

/// Student's t, 0.975 quantile, `df` degrees of freedom (standard table; 1.96 beyond 30).
fn t975(df: usize) -> f64 {
    const T: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
    ];
    T.get(df.wrapping_sub(1)).copied().unwrap_or(1.96)
}
