//! What else used the machine while the benchmark measured: per-process CPU time from /proc, steal and CPU
//! pressure, so a disturbed phase is flagged rather than averaged in.

use std::fmt::Write as _;

use super::*;

/// What else used the CPUs during one phase (sampled from /proc), and how much CPU the hypervisor stole.
#[derive(Default, Clone)]
pub(super) struct PhaseLoad {
    pub(super) wall_s: f64,
    /// CPU seconds of every process outside this benchmark (this process and the HAL, marsd and cyclictest
    /// it starts), among those that lived through at least one sample.
    pub(super) other_cpu_s: f64,
    /// The busiest of them, grouped by name (name, CPU seconds).
    pub(super) top: Vec<(String, f64)>,
    pub(super) steal_s: f64,
    /// Share of the time some runnable task waited for a CPU (PSI, this benchmark's own tasks included).
    pub(super) cpu_pressure: Option<f64>,
}

/// Per process (pid, start time): name, CPU seconds when first seen (0 if it started after the phase did),
/// CPU seconds when last seen.
pub(super) type Seen = HashMap<(u32, u64), (String, f64, f64)>;

/// Samples every process's CPU time (keyed by pid and start time) until finished.
pub(super) struct LoadProbe {
    pub(super) started: Instant,
    pub(super) steal: f64,
    pub(super) pressure_us: Option<f64>,
    pub(super) stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    pub(super) sampler: std::thread::JoinHandle<Seen>,
}

pub(super) fn clock_tick_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    1.0 / if hz > 0 { hz as f64 } else { 100.0 }
}

/// Steal seconds of all cores since boot, from /proc/stat.
pub(super) fn steal_s() -> f64 {
    let text = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let Some(line) = text.lines().find(|l| l.starts_with("cpu ")) else { return 0.0 };
    line.split_whitespace().nth(8).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0) * clock_tick_s()
}

/// Total µs some task waited for a CPU, from /proc/pressure/cpu.
pub(super) fn cpu_pressure_us() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/pressure/cpu").ok()?;
    let some = text.lines().find(|l| l.starts_with("some"))?;
    some.split_whitespace().find_map(|f| f.strip_prefix("total="))?.parse().ok()
}

/// Every other process's CPU seconds so far: (pid, start time) → (name, seconds). Skips this process and its
/// children.
pub(super) fn other_processes() -> HashMap<(u32, u64), (String, f64)> {
    let me = std::process::id();
    let mut out = HashMap::new();
    let Ok(dir) = std::fs::read_dir("/proc") else { return out };
    for entry in dir.flatten() {
        let Some(pid) = entry.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else { continue };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else { continue };
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else { continue };
        // A kernel worker's name says what it works on at the moment: keep the worker's name only.
        let name = stat[open + 1..close].split('-').next().unwrap_or_default().to_string();
        let rest: Vec<&str> = stat[close + 1..].split_whitespace().collect();
        let field = |i: usize| rest.get(i).and_then(|s| s.parse::<u64>().ok()).unwrap_or(0);
        // After the name: state(0) ppid(1) … utime(11) stime(12) … starttime(19).
        if pid == me || field(1) == u64::from(me) {
            continue;
        }
        out.insert((pid, field(19)), (name, (field(11) + field(12)) as f64 * clock_tick_s()));
    }
    out
}

impl LoadProbe {
    pub(super) fn start() -> Self {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        let first = other_processes();
        let sampler = std::thread::spawn(move || {
            let mut seen: Seen = first.into_iter().map(|(k, (n, t))| (k, (n, t, t))).collect();
            loop {
                let last = flag.load(std::sync::atomic::Ordering::Acquire);
                for (k, (n, t)) in other_processes() {
                    seen.entry(k).and_modify(|e| e.2 = t).or_insert((n, 0.0, t));
                }
                if last {
                    return seen;
                }
                std::thread::sleep(Duration::from_millis(250));
            }
        });
        Self { started: Instant::now(), steal: steal_s(), pressure_us: cpu_pressure_us(), stop, sampler }
    }

    pub(super) fn finish(self) -> PhaseLoad {
        let wall_s = self.started.elapsed().as_secs_f64();
        self.stop.store(true, std::sync::atomic::Ordering::Release);
        let seen = self.sampler.join().unwrap_or_default();
        let mut by_name: HashMap<String, f64> = HashMap::new();
        for (name, first, last) in seen.into_values() {
            *by_name.entry(name).or_default() += (last - first).max(0.0);
        }
        let other_cpu_s = by_name.values().sum();
        let mut top: Vec<(String, f64)> = by_name.into_iter().filter(|(_, t)| *t >= 0.1).collect();
        top.sort_by(|a, b| b.1.total_cmp(&a.1));
        top.truncate(5);
        let cpu_pressure = match (self.pressure_us, cpu_pressure_us()) {
            (Some(a), Some(b)) if wall_s > 0.0 => Some((b - a) * 1e-6 / wall_s),
            _ => None,
        };
        PhaseLoad { wall_s, other_cpu_s, top, steal_s: steal_s() - self.steal, cpu_pressure }
    }
}

impl PhaseLoad {
    pub(super) fn describe(&self, cores: usize) -> String {
        let cap = self.wall_s * cores as f64;
        let mut s = format!(
            "{:.0} s: other processes used {:.1} CPU-s of {:.0} ({:.0} %)",
            self.wall_s,
            self.other_cpu_s,
            cap,
            100.0 * self.other_cpu_s / cap.max(1e-9)
        );
        if !self.top.is_empty() {
            let top: Vec<String> = self.top.iter().map(|(n, t)| format!("{n} {t:.1} s")).collect();
            let _ = write!(s, " ({})", top.join(", "));
        }
        let _ = write!(s, "; steal {:.1} s", self.steal_s);
        if let Some(p) = self.cpu_pressure {
            let _ = write!(s, "; CPU pressure (a runnable task waiting, ours included) {:.0} % of the time", 100.0 * p);
        }
        s
    }
}
