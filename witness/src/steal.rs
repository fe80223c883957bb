//! The kernel's per-CPU `steal` counter (/proc/stat): CPU time the hypervisor ran something else on a virtual
//! CPU. Sampled every [`SAMPLE_MS`] by a thread under the normal scheduler (it needs no precision: the counter is
//! cumulative; a sample taken late only widens the bracket, which [`StealWatch::largest_in`] bounds).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::monotonic_ns;

pub const SAMPLE_MS: u64 = 10;
/// Samples kept (the oldest go first): about an hour and a half.
const CAPACITY: usize = 1 << 19;
/// A bracket of samples may be this much wider than the window it judges, in all, else it says nothing of the
/// window.
const SLACK_NS: u64 = 4 * SAMPLE_MS * 1_000_000;

/// Steal (ms) of each CPU at a moment.
#[derive(Debug, Clone)]
struct Sample {
    at_ns: u64,
    steal_ms: Vec<f64>,
}

/// Steal over a window, on the CPU that lost most.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StealSeen {
    pub cpu: usize,
    pub ms: f64,
}

pub struct StealWatch {
    samples: Arc<Mutex<VecDeque<Sample>>>,
}

impl StealWatch {
    pub fn start() -> Self {
        let samples = Arc::new(Mutex::new(VecDeque::new()));
        let s = samples.clone();
        let _ = std::thread::Builder::new().name("witness-steal".into()).spawn(move || {
            let hz = clock_ticks_per_s();
            loop {
                if let Some(steal_ms) = std::fs::read_to_string("/proc/stat").ok().and_then(|t| per_cpu_ms(&t, hz)) {
                    let mut g = s.lock().unwrap_or_else(|e| e.into_inner());
                    if g.len() == CAPACITY {
                        g.pop_front();
                    }
                    g.push_back(Sample { at_ns: monotonic_ns(), steal_ms });
                }
                std::thread::sleep(Duration::from_millis(SAMPLE_MS));
            }
        });
        Self { samples }
    }

    /// The most steal a CPU lost over `(from, to)` (CPU `only`, or any), from the last sample at or before `from`
    /// to the first at or after `to` — `None` if the samples do not bracket the window within `SLACK_NS`.
    pub fn largest_in(&self, (from, to): (u64, u64), only: Option<usize>) -> Option<StealSeen> {
        let patience = monotonic_ns() + 3 * SAMPLE_MS * 1_000_000;
        loop {
            let g = self.samples.lock().unwrap_or_else(|e| e.into_inner());
            if g.back().is_some_and(|s| s.at_ns >= to) || monotonic_ns() > patience {
                let before = g.iter().rev().find(|s| s.at_ns <= from)?;
                let after = g.iter().find(|s| s.at_ns >= to)?;
                if (after.at_ns - before.at_ns) > (to - from) + SLACK_NS {
                    return None;
                }
                let grew = after.steal_ms.iter().zip(&before.steal_ms).map(|(a, b)| a - b).enumerate();
                let grew = grew.filter(|&(cpu, _)| only.is_none_or(|k| k == cpu));
                return grew.map(|(cpu, ms)| StealSeen { cpu, ms }).max_by(|a, b| a.ms.total_cmp(&b.ms));
            }
            drop(g);
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// The `steal` column (the 8th value) of each `cpuN` line of /proc/stat, in ms at `hz` ticks per second.
pub fn per_cpu_ms(proc_stat: &str, hz: f64) -> Option<Vec<f64>> {
    let cpus: Vec<f64> = proc_stat
        .lines()
        .filter(|l| l.starts_with("cpu") && l.as_bytes().get(3).is_some_and(u8::is_ascii_digit))
        .map(|l| l.split_whitespace().nth(8).and_then(|t| t.parse::<f64>().ok()).map(|t| t * 1e3 / hz.max(1.0)))
        .collect::<Option<_>>()?;
    (!cpus.is_empty()).then_some(cpus)
}

fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    unsafe { libc::sysconf(libc::_SC_CLK_TCK) as f64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steal_is_read_per_cpu_in_ms() {
        let stat = "cpu  10 0 5 100 0 0 0 7 0 0\ncpu0 5 0 2 50 0 0 0 3 0 0\ncpu1 5 0 3 50 0 0 0 4 0 0\nintr 1\n";
        assert_eq!(per_cpu_ms(stat, 100.0), Some(vec![30.0, 40.0]));
        assert_eq!(per_cpu_ms("cpu  1 2 3\n", 100.0), None, "no per-CPU lines");
        assert_eq!(per_cpu_ms("cpu0 1 2 3\n", 100.0), None, "no steal column");
    }
}
