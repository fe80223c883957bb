//! `mars-hil soak`: the demo loop (`mars-hil demo --episodes 0`, Pick Cup until stopped) for a long time on the mock
//! HAL and on franka-sim, with marsd's and the HAL's resident memory sampled from /proc/<pid>/status. Prints per
//! backend the RSS at the end of the warm-up, at the end and its highest in between, the real-time loops'
//! allocations after warm-up (from marsd's and the HAL's own reports) and whether marsd tripped.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use serde_json::Value;

use crate::bench::backends::demo_child_pid;
use crate::demo::DemoRobot;
use crate::faults::Backends;

#[derive(clap::Args, Debug, Clone)]
pub struct SoakArgs {
    /// How long the demo loop runs on each backend (s).
    #[arg(long, default_value_t = 3600.0)]
    pub duration_s: f64,
    /// The backends: the mock HAL, franka-sim (the fci backend), or both in turn.
    #[arg(long, value_enum, default_value_t = Backends::Both)]
    pub backend: Backends,
    /// RSS is judged from this long after the start on (s): loading, and the bounded rings filling (marsd keeps
    /// the last `traces_kept` episodes' traces, 20 by default: ~2 min of Pick Cup, during which its RSS grows by
    /// ~7 MiB and then stays).
    #[arg(long, default_value_t = 300.0)]
    pub warmup_s: f64,
    /// How often RSS is sampled (s).
    #[arg(long, default_value_t = 1.0)]
    pub sample_every_s: f64,
    /// Daemon configuration (TOML).
    #[arg(long, default_value = mars_runtime::cli::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Each backend's demo output (summary.json, hal.json, logs, rss.csv) goes to <out>/<backend>/.
    #[arg(long, default_value = "runs/soak")]
    pub out: PathBuf,
}

/// One RSS sample.
struct Sample {
    /// Seconds since marsd and the HAL were found.
    at_s: f64,
    marsd_kb: u64,
    hal_kb: u64,
}

/// One backend's soak.
struct Soaked {
    backend: &'static str,
    ran_s: f64,
    samples: Vec<Sample>,
    demo_exit: Option<i32>,
    marsd: Value,
    hal: Value,
}

/// Runs the soak(s) and prints the table; `Ok(false)` when marsd tripped or a loop allocated after warm-up.
pub fn run(args: &SoakArgs) -> anyhow::Result<bool> {
    for (name, v) in [("--duration-s", args.duration_s), ("--sample-every-s", args.sample_every_s)] {
        anyhow::ensure!(v.is_finite() && v > 0.0 && v <= 1e6, "{name} must be a positive number of seconds, got {v}");
    }
    anyhow::ensure!(
        args.warmup_s.is_finite() && args.warmup_s >= 0.0 && args.warmup_s < args.duration_s,
        "--warmup-s must be at least 0 and shorter than --duration-s, got {}",
        args.warmup_s
    );
    let exe = std::env::current_exe().context("locating this executable")?;
    let backends = match args.backend {
        Backends::Mock => vec![DemoRobot::Mock],
        Backends::FrankaSim => vec![DemoRobot::FrankaSim],
        Backends::Both => vec![DemoRobot::Mock, DemoRobot::FrankaSim],
    };
    let soaked = backends.into_iter().map(|b| soak(args, &exe, b)).collect::<anyhow::Result<Vec<_>>>()?;
    let text = render(&soaked, args);
    print!("{text}");
    std::fs::write(args.out.join("results.md"), &text)?;
    Ok(soaked.iter().all(|s| trip(s).is_none() && allocations(s).iter().all(|a| *a == Some(0))))
}

fn soak(args: &SoakArgs, exe: &Path, backend: DemoRobot) -> anyhow::Result<Soaked> {
    let name = if backend == DemoRobot::Mock { "mock" } else { "franka-sim" };
    let dir = args.out.join(name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    for stale in ["summary.json", "hal.json"] {
        let _ = std::fs::remove_file(dir.join(stale));
    }
    let robot = format!("soak-{}-{name}", std::process::id());
    eprintln!("== soak on {name}: {} s → {}", args.duration_s, dir.display());
    let mut demo = Command::new(exe)
        .arg("demo")
        .args(["--backend", if backend == DemoRobot::Mock { "mock" } else { "franka-sim" }])
        .arg("--config")
        .arg(&args.config)
        .args(["--episodes", "0", "--robot", &robot])
        .arg("--out")
        .arg(&dir)
        .stdout(std::fs::File::create(dir.join("demo.out"))?)
        .stderr(std::fs::File::create(dir.join("demo.log"))?)
        .stdin(Stdio::null())
        .spawn()
        .context("starting the demo")?;
    let result = sample_until(args, &mut demo, &robot, &dir);
    // SAFETY: kill(2) on our own child's pid: the demo passes SIGTERM on to marsd, which ends its episode at rest.
    unsafe { libc::kill(demo.id() as libc::pid_t, libc::SIGTERM) };
    let demo_exit = crate::faults::wait_child(&mut demo, Duration::from_secs(60));
    let (samples, ran_s) = result?;
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).ok().and_then(|t| serde_json::from_str(&t).ok());
    Ok(Soaked {
        backend: name,
        ran_s,
        samples,
        demo_exit,
        marsd: read("summary.json").unwrap_or(Value::Null),
        hal: read("hal.json").unwrap_or(Value::Null),
    })
}

/// Samples marsd's and the HAL's RSS until the duration is over or the demo ended; writes them to `dir/rss.csv`.
/// Returns the samples and how long the loop ran (s).
fn sample_until(args: &SoakArgs, demo: &mut Child, robot: &str, dir: &Path) -> anyhow::Result<(Vec<Sample>, f64)> {
    let start = Instant::now();
    let running = |demo: &mut Child| matches!(demo.try_wait(), Ok(None));
    // The demo measures the machine (2 s) and starts franka-sim first: find its two processes.
    let pids = loop {
        if let (Some(m), Some(h)) = (demo_child_pid("marsd", robot), demo_child_pid("hal", robot)) {
            break (m, h);
        }
        anyhow::ensure!(
            running(demo) && start.elapsed() < Duration::from_secs(120),
            "the demo did not start marsd and the HAL; see {}",
            dir.join("demo.log").display()
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let began = Instant::now();
    let every = Duration::from_secs_f64(args.sample_every_s);
    let mut samples = Vec::new();
    let mut csv = String::from("s,marsd_rss_kb,hal_rss_kb\n");
    while began.elapsed().as_secs_f64() < args.duration_s && running(demo) {
        let (Some(m), Some(h)) = (rss_kb(pids.0), rss_kb(pids.1)) else { break };
        let t = began.elapsed().as_secs_f64();
        samples.push(Sample { at_s: t, marsd_kb: m, hal_kb: h });
        let _ = writeln!(csv, "{t:.1},{m},{h}");
        std::thread::sleep(every);
    }
    std::fs::write(dir.join("rss.csv"), csv)?;
    Ok((samples, began.elapsed().as_secs_f64()))
}

/// VmRSS of a process (kB), from /proc/<pid>/status.
pub fn rss_kb(pid: libc::pid_t) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

fn trip(s: &Soaked) -> Option<String> {
    match &s.marsd["trip"] {
        Value::Null if !s.marsd.is_null() => None,
        Value::Null => Some("no summary.json (marsd did not end cleanly)".into()),
        t => Some(t.to_string()),
    }
}

/// The servo thread's and the HAL loop's system-allocator calls after warm-up (None: not reported).
fn allocations(s: &Soaked) -> [Option<u64>; 2] {
    [s.marsd["servo_allocations"]["system"].as_u64(), s.hal["loop_allocations"].as_u64()]
}

/// (start, end, max) after warm-up of column `col` (0 marsd, 1 HAL), in MiB.
fn rss_after_warmup(s: &Soaked, warmup_s: f64, col: usize) -> String {
    let v: Vec<u64> =
        s.samples.iter().filter(|x| x.at_s >= warmup_s).map(|x| if col == 0 { x.marsd_kb } else { x.hal_kb }).collect();
    match (v.first(), v.last(), v.iter().max()) {
        (Some(a), Some(b), Some(m)) => {
            let mib = |k: &u64| *k as f64 / 1024.0;
            format!("{:.1} / {:.1} / {:.1}", mib(a), mib(b), mib(m))
        }
        _ => "– (no sample after warm-up)".into(),
    }
}

fn render(soaked: &[Soaked], args: &SoakArgs) -> String {
    let mut s = format!(
        "\nmars-hil soak --duration-s {} --warmup-s {} --sample-every-s {}\n\n| backend | ran (s) | episodes (succeeded) \
         | RSS samples | marsd RSS after warm-up, start / end / max MiB | HAL RSS, start / end / max MiB | servo allocations \
         after warm-up | HAL loop allocations after warm-up | trip | demo exit |\n|---|---:|---:|---:|---|---|---:|---:|---|---:|\n",
        args.duration_s, args.warmup_s, args.sample_every_s
    );
    let show = |v: Option<u64>| v.map_or("–".into(), |n| n.to_string());
    for x in soaked {
        let [servo, hal] = allocations(x);
        let _ = writeln!(
            s,
            "| {} | {:.0} | {} ({}) | {} | {} | {} | {} | {} | {} | {} |",
            x.backend,
            x.ran_s,
            show(x.marsd["episodes"].as_u64()),
            show(x.marsd["successes"].as_u64()),
            x.samples.len(),
            rss_after_warmup(x, args.warmup_s, 0),
            rss_after_warmup(x, args.warmup_s, 1),
            show(servo),
            show(hal),
            trip(x).unwrap_or_else(|| "none".into()),
            x.demo_exit.map_or("– (killed)".into(), |c| c.to_string())
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rss_of_a_running_process_is_read_and_of_none_is_not() {
        // SAFETY: getpid(2) has no preconditions.
        let me = unsafe { libc::getpid() };
        assert!(rss_kb(me).is_some_and(|kb| kb > 0));
        assert_eq!(rss_kb(-1), None);
    }

    fn soaked(samples: &[(f64, u64, u64)]) -> Soaked {
        Soaked {
            backend: "mock",
            ran_s: 10.0,
            samples: samples.iter().map(|&(at_s, marsd_kb, hal_kb)| Sample { at_s, marsd_kb, hal_kb }).collect(),
            demo_exit: Some(0),
            marsd: serde_json::json!({"trip": null, "servo_allocations": {"system": 0}}),
            hal: serde_json::json!({"loop_allocations": 3}),
        }
    }

    #[test]
    fn rss_is_judged_after_the_warm_up_only() {
        let s =
            soaked(&[(0.0, 100 * 1024, 1024), (5.0, 10 * 1024, 2048), (6.0, 12 * 1024, 2048), (7.0, 11 * 1024, 4096)]);
        assert_eq!(rss_after_warmup(&s, 5.0, 0), "10.0 / 11.0 / 12.0");
        assert_eq!(rss_after_warmup(&s, 5.0, 1), "2.0 / 4.0 / 4.0");
        assert!(rss_after_warmup(&s, 8.0, 0).contains("no sample"));
        // The HAL's 3 allocations are reported; marsd did not trip.
        assert_eq!(allocations(&s), [Some(0), Some(3)]);
        assert_eq!(trip(&s), None);
    }
}
