//! results.md: what `mars-hil bench` measured, as markdown. Every number comes from the runs' summary.json files
//! and cyclictest's output handed in; this file only lays them out.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::Value;

use super::cyclictest::Cyclic;
use super::load::PhaseLoad;
use super::{DISTURBED, PolicyRun, probe_sched_fifo, read_trim};

/// What results.md is written from: the runs (MARS first), cyclictest's, and the settings they ran with.
pub(super) struct Results<'a> {
    pub cmdline: String,
    pub started: String,
    pub config: &'a Path,
    pub episodes: usize,
    pub seed: u64,
    pub rate_hz: f64,
    pub period_us: u64,
    pub servo_priority: i32,
    pub servo_core: Option<usize>,
    pub policy_core: Option<usize>,
    pub hal_core: usize,
    pub cyclictest_pm_qos: bool,
    pub runs: &'a [PolicyRun],
    pub cyclic: &'a anyhow::Result<Cyclic>,
}

/// The whole results.md.
pub(super) fn results_md(res: &Results) -> String {
    let mut md = String::new();
    let w = &mut md;
    let _ = writeln!(w, "# marsd benchmark\n");
    let _ = writeln!(
        w,
        "`{}` — {}; config `{}`, {} episodes per policy, seed {}, servo {} Hz.\n",
        res.cmdline,
        res.started,
        res.config.display(),
        res.episodes,
        res.seed,
        res.rate_hz
    );
    machine(w, res);
    jitter(w, res);
    tick(w, &res.runs[0]);
    policies(w, res.runs);
    artifacts(w, res.runs);
    md
}

/// The machine, each run's real-time setup and what else used the CPUs meanwhile.
fn machine(w: &mut String, res: &Results) {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let _ = writeln!(w, "## Machine\n\n| | |\n|---|---|");
    let online = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "?".into());
    let _ = writeln!(w, "| nproc | {cores} usable of {online} online ({cpu}) |");
    let kernel = format!(
        "{} {}",
        read_trim("/proc/sys/kernel/osrelease").unwrap_or_default(),
        read_trim("/proc/sys/kernel/version").unwrap_or_default()
    );
    let preempt_rt = read_trim("/sys/kernel/realtime").is_some_and(|s| s == "1") || kernel.contains("PREEMPT_RT");
    let _ = writeln!(w, "| kernel | {kernel} ({}) |", if preempt_rt { "PREEMPT_RT" } else { "not PREEMPT_RT" });
    let rtprio = unsafe {
        let mut r: libc::rlimit = std::mem::zeroed();
        libc::getrlimit(libc::RLIMIT_RTPRIO, &mut r);
        if r.rlim_cur == libc::RLIM_INFINITY { "unlimited".to_string() } else { r.rlim_cur.to_string() }
    };
    let _ = writeln!(
        w,
        "| this user | uid {}, RLIMIT_RTPRIO {rtprio}; a fresh thread asking SCHED_FIFO {}: {} |",
        unsafe { libc::getuid() },
        res.servo_priority,
        probe_sched_fifo(res.servo_priority)
    );
    for r in res.runs {
        let servo = r.rt.servo.clone().unwrap_or_else(|| "not in summary.json".into());
        let policy = r.rt.policy.clone().unwrap_or_else(|| "not in summary.json".into());
        let _ = writeln!(
            w,
            "| marsd ({}) real-time setup, from its summary.json | servo thread: {servo}; policy thread: {policy} |",
            r.name
        );
        for refusal in &r.rt.refusals {
            let _ = writeln!(w, "| marsd ({}) real-time request not applied | {} |", r.name, refusal.replace('|', "/"));
        }
    }
    let _ = writeln!(
        w,
        "| demo layout | servo loop on core {}, policy loop on core {}, mock HAL on core {} |",
        res.servo_core.map_or("–".into(), |c| c.to_string()),
        res.policy_core.map_or("–".into(), |c| c.to_string()),
        res.hal_core
    );
    for r in res.runs {
        let _ = writeln!(w, "| load during the {} demo | {} |", r.name, r.load.describe(cores));
    }
    let mut phases: Vec<(String, &PhaseLoad)> =
        res.runs.iter().map(|r| (format!("the {} demo", r.name), &r.load)).collect();
    if let Ok(c) = res.cyclic {
        let _ = writeln!(w, "| load during cyclictest | {} |", c.load.describe(cores));
        phases.push(("cyclictest".into(), &c.load));
    }
    let disturbed: Vec<String> = phases
        .iter()
        .filter(|(_, l)| l.other_cpu_s > DISTURBED * l.wall_s * cores as f64)
        .map(|(name, _)| name.clone())
        .collect();
    if !disturbed.is_empty() {
        let _ = writeln!(
            w,
            "\n**Disturbed:** other processes used more than {:.0} % of the CPUs during {}; rerun on a quiet machine.",
            100.0 * DISTURBED,
            disturbed.join(", ")
        );
    }
}

/// 1. The servo loop's wake-up jitter next to cyclictest's.
fn jitter(w: &mut String, res: &Results) {
    let mars = &res.runs[0];
    let _ = writeln!(w, "\n## 1. Servo-loop wake-up jitter vs cyclictest (µs)\n");
    let _ =
        writeln!(w, "| | wake-ups | p50 | p99 | p99.9 | max | ≥ 1 period late |\n|---|---:|---:|---:|---:|---:|---:|");
    let mj = |k: &str| mars.stat("wake_jitter", k);
    let missed = mars.num("/deadline_misses/servo_missed_periods");
    let _ = writeln!(
        w,
        "| marsd servo loop (MARS run: HAL, policy and servo running) | {} | {} | {} | {} | {} | {} periods skipped |",
        mj("count").map_or("–".into(), |c| format!("{c:.0}")),
        f1(mj("p50")),
        f1(mj("p99")),
        f1(mj("p99.9")),
        f1(mj("max")),
        missed.map_or("–".into(), |m| format!("{m:.0}"))
    );
    match res.cyclic {
        Ok(c) => {
            let q = |p: f64| c.quantile_us(p);
            let over = |v: Option<f64>| v.map_or(format!("> {:.0}", c.bound_ns as f64 * 1e-3), |v| format!("{v:.1}"));
            let _ = writeln!(
                w,
                "| cyclictest (after the demos: no HAL, no marsd) | {} | {} | {} | {} | {:.1} | {} wake-ups |",
                c.cycles,
                over(q(0.5)),
                over(q(0.99)),
                over(q(0.999)),
                c.max_ns as f64 * 1e-3,
                c.at_least(res.period_us * 1000)
            );
            let _ = writeln!(
                w,
                "| ratio marsd / cyclictest | | {} | {} | {} | {} | |",
                ratio(mj("p50"), q(0.5)),
                ratio(mj("p99"), q(0.99)),
                ratio(mj("p99.9"), q(0.999)),
                ratio(mj("max"), Some(c.max_ns as f64 * 1e-3))
            );
            let _ = writeln!(
                w,
                "\ncyclictest {} (min {:.1} µs, mean {:.1} µs, {} wake-ups past the {} µs histogram bound): `{}`.",
                c.version,
                c.min_ns as f64 * 1e-3,
                c.avg_ns * 1e-3,
                c.overflows,
                c.bound_ns / 1000,
                c.cmdline
            );
            let pm = if res.cyclictest_pm_qos {
                "cyclictest held /dev/cpu_dma_latency at 0 µs (marsd does not)"
            } else {
                "`--default-system`: cyclictest leaves power management alone, as marsd does"
            };
            let _ = writeln!(
                w,
                "It ran after the demos, with none of the benchmark's other processes (no HAL, no marsd; the load \
                 row above says what else ran), for the same number of wake-ups, at the same period ({} µs), \
                 SCHED_FIFO priority ({}), core ({}) and with mlockall; {pm}.",
                res.period_us,
                res.servo_priority,
                res.servo_core.map_or("unpinned".into(), |c| c.to_string())
            );
            if !c.warnings.is_empty() {
                let _ = writeln!(w, "cyclictest said: {}", c.warnings.join(" / "));
            }
        }
        Err(e) => {
            let _ = writeln!(w, "| cyclictest | **did not run: {e:#}** | | | | | |");
        }
    }
    let _ = writeln!(
        w,
        "\nBoth measure lateness past the absolute deadline of a clock_nanosleep(TIMER_ABSTIME) loop. marsd's loop \
         moves its deadline to the latest one passed when it wakes more than a period late (the skipped periods \
         are counted), so its max stays below a period; cyclictest's max is the full lateness."
    );
}

/// 2. The servo tick's compute time and allocations (the MARS run).
fn tick(w: &mut String, mars: &PolicyRun) {
    let _ = writeln!(w, "\n## 2. Servo tick (MARS run)\n");
    let _ = writeln!(
        w,
        "| tick compute p50 (µs) | p99 | p99.99 | max | ticks counted after warm-up | system-allocator calls / tick \
         | pooled blocks / tick |\n|---:|---:|---:|---:|---:|---:|---:|"
    );
    let ticks = mars.num("/servo_ticks_counted");
    let per_tick = |key: &str| match (mars.num(&format!("/servo_allocations/{key}")), ticks) {
        (Some(n), Some(t)) if t > 0.0 => format!("{:.3} ({n:.0} in all)", n / t),
        (None, _) if mars.summary.is_some() => "not measured".into(),
        _ => "–".into(),
    };
    let _ = writeln!(
        w,
        "| {} | {} | {} | {} | {} | {} | {} |",
        f1(mars.stat("tick_compute", "p50")),
        f1(mars.stat("tick_compute", "p99")),
        f1(mars.stat("tick_compute", "p99.99")),
        f1(mars.stat("tick_compute", "max")),
        ticks.map_or("–".into(), |t| format!("{t:.0}")),
        per_tick("system"),
        per_tick("pooled")
    );
}

/// 3. MARS against the baselines, a row per measure.
fn policies(w: &mut String, runs: &[PolicyRun]) {
    let mars = &runs[0];
    let _ = writeln!(w, "\n## 3. MARS vs the baselines on the FR3 task (HIL demo, same episodes and seed)\n");
    let others: Vec<&PolicyRun> = runs.iter().skip(1).collect();
    let mut header = String::from("| |");
    let mut rule = String::from("|---|");
    for r in runs {
        let _ = write!(header, " {} |", r.name.to_uppercase());
        rule.push_str("---:|");
    }
    for o in &others {
        let _ = write!(header, " MARS/{} |", o.name.to_uppercase());
        rule.push_str("---:|");
    }
    let _ = writeln!(w, "{header}\n{rule}");
    let rows = policy_rows();
    for (label, cell, with_ratio) in &rows {
        let mut line = format!("| {label} |");
        for r in runs {
            let _ = write!(line, " {} |", cell(r).0);
        }
        for o in &others {
            let text = if *with_ratio { ratio(cell(mars).1, cell(o).1) } else { String::new() };
            let _ = write!(line, " {text} |");
        }
        let _ = writeln!(w, "{line}");
    }
}

/// A cell of the policies' table: its text, and the value a MARS/baseline ratio is taken of.
type Cell = Box<dyn Fn(&PolicyRun) -> (String, Option<f64>)>;

/// A cell showing one measure, `format`ted, whose value the MARS/baseline ratio is taken of.
fn ratio_cell(measure: fn(&PolicyRun) -> Option<f64>, format: fn(Option<f64>) -> String) -> Cell {
    Box::new(move |r| {
        let v = measure(r);
        (format(v), v)
    })
}

/// The policies' table: a label, how to fill its cell, whether it gets a MARS/baseline ratio.
fn policy_rows() -> Vec<(&'static str, Cell, bool)> {
    vec![
        (
            "success",
            Box::new(|r| match (r.num("/successes"), r.num("/episodes")) {
                (Some(s), Some(e)) => (format!("{s:.0}/{e:.0}"), None),
                _ => ("–".into(), None),
            }),
            false,
        ),
        (
            "modes",
            Box::new(|r| {
                let modes = r.get("/modes").and_then(Value::as_array).map(|m| {
                    m.iter()
                        .filter_map(|p| Some(format!("{} {}", p[0].as_str()?, p[1].as_u64()?)))
                        .collect::<Vec<_>>()
                        .join(", ")
                });
                (modes.unwrap_or_else(|| "–".into()), None)
            }),
            false,
        ),
        ("γ", Box::new(|r| (f2(r.num("/gamma")), None)), false),
        (
            "stop",
            Box::new(|r| {
                let stop = r.get("/stop").and_then(Value::as_str).unwrap_or("–").to_string();
                let text = match (r.get("/trip").and_then(Value::as_str), &r.error) {
                    (Some(t), _) => format!("{stop}: {t}"),
                    (None, Some(e)) => format!("{stop} ({e})"),
                    _ => stop,
                };
                (text.replace('|', "/"), None)
            }),
            false,
        ),
        ("policy calls", Box::new(|r| (r.num("/k/calls").map_or("–".into(), |v| format!("{v:.0}")), None)), false),
        ("K requested mean", ratio_cell(|r| r.num("/k/requested_mean"), f2), true),
        ("K requested p50", Box::new(|r| (f0(r.stat("k_requested", "p50")), r.stat("k_requested", "p50"))), false),
        ("K requested max", Box::new(|r| (f0(r.stat("k_requested", "max")), None)), false),
        ("K used mean", ratio_cell(|r| r.num("/k/used_mean"), f2), true),
        ("K used max", Box::new(|r| (f0(r.num("/k/used_max")), None)), false),
        (
            "calls capped by the deadline",
            Box::new(|r| (r.num("/k/capped").map_or("–".into(), |v| format!("{v:.0}")), None)),
            false,
        ),
        ("inference p50 (µs)", ratio_cell(|r| r.stat("inference", "p50"), f1), true),
        ("inference p99 (µs)", ratio_cell(|r| r.stat("inference", "p99"), f1), true),
        (
            "late chunks / over budget",
            Box::new(|r| match (r.num("/deadline_misses/late_chunks"), r.num("/deadline_misses/over_budget")) {
                (Some(a), Some(b)) => (format!("{a:.0} / {b:.0}"), None),
                _ => ("–".into(), None),
            }),
            false,
        ),
        (
            "out-of-limit commands (final check + HAL rejected + HAL clamped)",
            Box::new(|r| {
                let parts =
                    ["final_check", "hal_rejected", "hal_clamped"].map(|k| r.num(&format!("/limit_violations/{k}")));
                match parts {
                    [Some(a), Some(b), Some(c)] => (format!("{:.0}", a + b + c), None),
                    _ => ("–".into(), None),
                }
            }),
            false,
        ),
        (
            "late commands (seen by marsd / counted by the HAL)",
            Box::new(|r| {
                match (r.num("/deadline_misses/late_commands"), r.num("/deadline_misses/hal_late_commands")) {
                    (Some(a), Some(b)) => (format!("{a:.0} / {b:.0}"), None),
                    _ => ("–".into(), None),
                }
            }),
            false,
        ),
        (
            "HAL last resorts (guard hits / infeasible / backend errors)",
            Box::new(|r| {
                let parts = ["position_guard_hits", "infeasible_steps", "backend_errors"]
                    .map(|k| r.num(&format!("/hal_last_resorts/{k}")));
                match parts {
                    [Some(a), Some(b), Some(c)] => (format!("{a:.0} / {b:.0} / {c:.0}"), None),
                    _ => ("–".into(), None),
                }
            }),
            false,
        ),
        ("servo wake jitter p99 (µs)", Box::new(|r| (f1(r.stat("wake_jitter", "p99")), None)), false),
    ]
}

/// Where each run's checkpoint and report are.
fn artifacts(w: &mut String, runs: &[PolicyRun]) {
    let _ = writeln!(w, "\nCheckpoints and each run's summary.json, latency table, histogram log and plots:");
    for r in runs {
        let exit = r.exit.map_or("–".into(), |c| c.to_string());
        let _ = writeln!(
            w,
            "- {}: `{}` → `{}/` (marsd exit status {exit})",
            r.name,
            r.checkpoint.display(),
            r.dir.display()
        );
    }
}

fn f0(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{v:.0}"))
}

fn f1(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{v:.1}"))
}

fn f2(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{v:.2}"))
}

fn ratio(a: Option<f64>, b: Option<f64>) -> String {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => format!("{:.2}×", a / b),
        _ => "–".into(),
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use serde_json::json;

    use super::*;
    use crate::bench::RtLog;

    fn run(name: &str, k_used_mean: f64, inference_p50: f64) -> PolicyRun {
        let summary = json!({
            "successes": 4, "episodes": 5, "gamma": 0.5, "stop": "done", "modes": [["rim", 3], ["handle", 1]],
            "k": { "calls": 10, "requested_mean": 4.0, "used_mean": k_used_mean, "used_max": 8, "capped": 0 },
            "deadline_misses": { "servo_missed_periods": 3, "late_chunks": 0, "over_budget": 1 },
            "latency": { "channels": [
                { "channel": "wake_jitter", "count": 1000, "p50": 40.0, "p99": 200.0, "p99.9": 800.0, "max": 900.0 },
                { "channel": "inference", "p50": inference_p50, "p99": 2.0 * inference_p50 },
            ] },
        });
        PolicyRun {
            name: name.into(),
            checkpoint: PathBuf::from(format!("ck/{name}")),
            dir: PathBuf::from(format!("out/{name}")),
            exit: Some(0),
            error: None,
            summary: Some(summary),
            rt: RtLog::default(),
            load: PhaseLoad::default(),
        }
    }

    #[test]
    fn the_policies_table_puts_each_baseline_beside_mars_with_the_ratio() {
        let runs = [run("mars", 3.0, 500.0), run("fm", 6.0, 1000.0)];
        let cyclic = Err(anyhow::anyhow!("skipped (--no-cyclictest)"));
        let md = results_md(&Results {
            cmdline: "mars-hil bench".into(),
            started: "today".into(),
            config: Path::new("configs/marsd.toml"),
            episodes: 5,
            seed: 7,
            rate_hz: 1000.0,
            period_us: 1000,
            servo_priority: 80,
            servo_core: Some(1),
            policy_core: Some(0),
            hal_core: 1,
            cyclictest_pm_qos: false,
            runs: &runs,
            cyclic: &cyclic,
        });
        for line in [
            "`mars-hil bench` — today; config `configs/marsd.toml`, 5 episodes per policy, seed 7, servo 1000 Hz.",
            "| | MARS | FM | MARS/FM |",
            "| success | 4/5 | 4/5 |  |",
            "| modes | rim 3, handle 1 | rim 3, handle 1 |  |",
            "| K used mean | 3.00 | 6.00 | 0.50× |",
            "| inference p50 (µs) | 500.0 | 1000.0 | 0.50× |",
            "| late chunks / over budget | 0 / 1 | 0 / 1 |  |",
            "| marsd servo loop (MARS run: HAL, policy and servo running) | 1000 | 40.0 | 200.0 | 800.0 | 900.0 | 3 \
             periods skipped |",
            "| cyclictest | **did not run: skipped (--no-cyclictest)** | | | | | |",
            "| demo layout | servo loop on core 1, policy loop on core 0, mock HAL on core 1 |",
            "- fm: `ck/fm` → `out/fm/` (marsd exit status 0)",
        ] {
            assert!(md.contains(line), "missing {line:?} in\n{md}");
        }
        let sections = ["## Machine", "## 1. ", "## 2. ", "## 3. ", "Checkpoints and each run"];
        let at: Vec<usize> = sections.iter().map(|s| md.find(s).unwrap()).collect();
        assert!(at.windows(2).all(|w| w[0] < w[1]), "sections out of order: {at:?}");
    }
}
