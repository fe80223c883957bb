//! What `marsd` reports at exit: success, modes and γ, K statistics, deadline misses, limit violations, frame
//! refusals and the latency percentile table — printed, and written as `summary.json` with the plots.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use crate::config::DaemonConfig;
use crate::frame::FrameCounts;
use crate::latency::{Channel, Totals};
use crate::policy_loop::{EpisodeResult, PolicyReport};
use crate::servo::StopCause;
use crate::servo_loop::ServoReport;

#[derive(Debug, Clone, Serialize)]
pub struct KStats {
    pub calls: u64,
    pub requested_mean: f64,
    pub used_mean: f64,
    pub used_max: f64,
    /// Calls whose K the deadline cut.
    pub capped: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct DeadlineMisses {
    /// Servo periods skipped because a tick ran a whole period late.
    pub servo_missed_periods: u64,
    pub late_chunks: u64,
    pub over_budget: u64,
    /// Actions of late chunks that were already due, dropped.
    pub actions_dropped: u64,
    /// Servo ticks with the chunk used up and no newer one.
    pub starved_ticks: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct LimitViolations {
    /// Commands that failed marsd's own final check (never sent).
    pub final_check: u64,
    /// Commands the HAL refused or clamped, from its state frames.
    pub hal_rejected: u64,
    pub hal_clamped: u64,
    /// Re-synchronisations to the HAL's applied setpoint after a late command (see `ServoCounters::resyncs`).
    pub resyncs: u64,
}

impl LimitViolations {
    /// Commands that would have exceeded a limit: refused by marsd's final check or by the HAL. (A late
    /// command the HAL smoothed is counted in `hal_clamped`: the stream was within limits, but the HAL's
    /// setpoint had moved on without it.)
    pub fn total(&self) -> u64 {
        self.final_check + self.hal_rejected
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub robot: String,
    pub checkpoint: PathBuf,
    /// "finished", "signal" or "trip".
    pub stop: &'static str,
    pub trip: Option<String>,
    pub episodes: usize,
    pub successes: usize,
    pub success_rate: f64,
    pub modes: Vec<(String, usize)>,
    /// k · min_i n_i / Σ n_i over the k modes: 1 when successes split evenly, 0 if a mode is never used.
    pub gamma: f64,
    pub k: KStats,
    pub deadline_misses: DeadlineMisses,
    pub limit_violations: LimitViolations,
    pub frames: FrameCounts,
    pub commands_sent: u64,
    /// Heap allocations on the servo thread after warm-up, over `servo_ticks_counted` ticks (None: not measured).
    pub servo_allocations: Option<crate::alloc_count::Counts>,
    pub servo_ticks_counted: u64,
    pub latency: Totals,
    pub episode_results: Vec<EpisodeResult>,
}

impl Summary {
    pub fn new(cfg: &DaemonConfig, mode_names: &[String], s: &ServoReport, p: &PolicyReport, latency: Totals) -> Self {
        let successes = p.episodes.iter().filter(|e| e.success).count();
        let counts: Vec<usize> = (0..mode_names.len())
            .map(|m| p.episodes.iter().filter(|e| e.success && e.mode == Some(m)).count())
            .collect();
        let total: usize = counts.iter().sum();
        let gamma = match counts.iter().min() {
            Some(&min) if total > 0 => counts.len() as f64 * min as f64 / total as f64,
            _ => 0.0,
        };
        let mean = |c: Channel| latency.stats(c).map_or(0.0, |s| s.mean);
        let (stop, trip) = match s.cause {
            Some(StopCause::Trip(t)) => ("trip", Some(t.to_string())),
            Some(StopCause::Signal) => ("signal", None),
            _ => ("finished", None),
        };
        Self {
            robot: cfg.robot.clone(),
            checkpoint: cfg.checkpoint.clone(),
            stop,
            trip,
            episodes: p.episodes.len(),
            successes,
            success_rate: if p.episodes.is_empty() { 0.0 } else { successes as f64 / p.episodes.len() as f64 },
            modes: mode_names.iter().cloned().zip(counts).collect(),
            gamma,
            k: KStats {
                calls: p.inferences,
                requested_mean: mean(Channel::KRequested),
                used_mean: mean(Channel::KUsed),
                used_max: latency.stats(Channel::KUsed).map_or(0.0, |s| s.max),
                capped: p.capped,
            },
            deadline_misses: DeadlineMisses {
                servo_missed_periods: s.missed_periods,
                late_chunks: p.late_chunks,
                over_budget: p.over_budget,
                actions_dropped: s.counters.actions_dropped,
                starved_ticks: s.counters.starved_ticks,
            },
            limit_violations: LimitViolations {
                final_check: s.counters.limit_violations,
                hal_rejected: s.hal_rejected,
                hal_clamped: s.hal_clamped,
                resyncs: s.counters.resyncs,
            },
            frames: s.frames,
            commands_sent: s.counters.commands_sent,
            servo_allocations: s.allocations_after_warmup,
            servo_ticks_counted: s.ticks_counted,
            latency,
            episode_results: p.episodes.clone(),
        }
    }

    /// Writes `summary.json`, `latency.txt` and the PNG plots into `dir`; returns the paths written.
    pub fn write(&self, dir: &Path, p: &PolicyReport) -> anyhow::Result<Vec<PathBuf>> {
        let mut written = Vec::new();
        let mode_names: Vec<String> = self.modes.iter().map(|(name, _)| name.clone()).collect();
        let json = dir.join("summary.json");
        std::fs::write(&json, serde_json::to_string_pretty(self)?)
            .with_context(|| format!("writing {}", json.display()))?;
        written.push(json);
        let table = dir.join("latency.txt");
        std::fs::write(&table, self.latency.to_string()).with_context(|| format!("writing {}", table.display()))?;
        written.push(table);
        written.push(self.latency.log.clone());
        type Draw<'a> = Box<dyn Fn(&Path) -> anyhow::Result<()> + 'a>;
        let plots: [(&str, Draw); 3] = [
            ("latency.png", Box::new(|path| crate::plots::plot_latency(&self.latency, path))),
            ("k.png", Box::new(|path| crate::plots::plot_k(&self.latency, path))),
            // Joints 0 and 6 are where the two grasps differ most.
            ("episodes.png", Box::new(|path| crate::plots::plot_episodes(&p.traces, &mode_names, 0, 6, path))),
        ];
        for (name, draw) in plots {
            let path = dir.join(name);
            match draw(&path) {
                Ok(()) => written.push(path),
                Err(e) => tracing::warn!("could not draw {}: {e:#}", path.display()),
            }
        }
        Ok(written)
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let modes: Vec<String> = self.modes.iter().map(|(m, n)| format!("{m} {n}")).collect();
        writeln!(
            f,
            "marsd on {}: {} episodes, {} succeeded ({:.0} %), modes: {}, γ = {:.2}",
            self.robot,
            self.episodes,
            self.successes,
            100.0 * self.success_rate,
            modes.join(", "),
            self.gamma
        )?;
        match &self.trip {
            Some(t) => writeln!(f, "  STOPPED BY THE WATCHDOG: {t}")?,
            None => writeln!(f, "  stopped: {}", self.stop)?,
        }
        let k = &self.k;
        writeln!(
            f,
            "  K: {} calls, mean requested {:.2}, mean used {:.2}, max used {}, capped by the deadline {}",
            k.calls, k.requested_mean, k.used_mean, k.used_max, k.capped
        )?;
        let d = &self.deadline_misses;
        writeln!(
            f,
            "  deadline misses: servo periods missed {}, late chunks {}, over budget {} (actions dropped {}, starved ticks {})",
            d.servo_missed_periods, d.late_chunks, d.over_budget, d.actions_dropped, d.starved_ticks
        )?;
        let l = &self.limit_violations;
        writeln!(
            f,
            "  limit violations: {} of {} commands (final check {}, HAL rejected {}); late commands the HAL smoothed {}, re-synchronised {}",
            l.total(),
            self.commands_sent,
            l.final_check,
            l.hal_rejected,
            l.hal_clamped,
            l.resyncs
        )?;
        match self.servo_allocations {
            Some(n) => writeln!(
                f,
                "  servo thread after warm-up ({} ticks): {} system-allocator calls; {} small blocks from the preallocated RT pool (iceoryx2's per-sample bookkeeping)",
                self.servo_ticks_counted, n.system, n.pooled
            )?,
            None => writeln!(f, "  servo thread heap allocations: not measured (counting allocator not installed)")?,
        }
        let fr = &self.frames;
        writeln!(
            f,
            "  state frames: {} used, {} refused (wrong DOF {}, non-finite {}, sensor fault {}, stale {}, out of order {})",
            fr.used,
            fr.refused(),
            fr.wrong_dof,
            fr.non_finite,
            fr.sensor_fault,
            fr.stale,
            fr.out_of_order
        )?;
        write!(f, "{}", self.latency)
    }
}
