//! `mars-hil bench`: the controller's benchmark, measured in one run and written as a markdown table.
//!
//! 1. Servo-loop wake-up jitter next to `cyclictest` (rt-tests): the HIL demo with MARS, then `cyclictest` on
//!    the otherwise idle machine for as many wake-ups at the same rate, SCHED_FIFO priority and core, with
//!    mlockall — the best the same kernel does for a loop that does nothing.
//! 2. The servo tick's compute time and its heap allocations per tick (system allocator and RT pool).
//! 3. MARS vs FM (and optionally A2A) on the FR3 task: the same demo, episodes and seed, one checkpoint each.
//!
//! The machine is shared and noisy, so the output also says what else used the CPUs during each phase.
//! Every number is read from this run's `summary.json` files and cyclictest's output; nothing is hard-coded.

use std::collections::HashMap;
use std::io::{Read, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use serde_json::Value;

use crate::demo::DemoArgs;
use mars_runtime::cli::MarsdArgs;

pub mod backends;
mod cyclictest;
pub mod fleet;
mod load;
pub mod remote;
mod report;

use cyclictest::run_cyclictest;
use load::{LoadProbe, PhaseLoad};

#[derive(clap::Args, Debug, Clone)]
pub struct BenchArgs {
    /// Daemon configuration (TOML): servo core, priority and rate are taken from it (and its profile).
    #[arg(long, default_value = "configs/marsd.toml")]
    pub config: PathBuf,
    /// Episodes per policy (the same seed for every policy: the config's `seed`).
    #[arg(long, default_value_t = 5)]
    pub episodes: usize,
    /// Where each run's report and `results.md` go.
    #[arg(long, default_value = "runs/bench")]
    pub out: PathBuf,
    /// Directory holding one checkpoint per policy, named as in --policies.
    #[arg(long, default_value = "assets/checkpoints/fr3_pick_cup")]
    pub checkpoints: PathBuf,
    /// Policies to compare (`mars` is required: its run is the one measured against cyclictest).
    #[arg(long, value_delimiter = ',', default_value = "mars,fm")]
    pub policies: Vec<String>,
    /// CPU core of the HAL's loop (default: the demo's).
    #[arg(long)]
    pub hal_core: Option<usize>,
    /// Skip cyclictest (marsd's numbers only).
    #[arg(long)]
    pub no_cyclictest: bool,
    /// Let cyclictest hold /dev/cpu_dma_latency at 0 µs (its default). Off by default: marsd does not touch
    /// power management, so cyclictest runs with `--default-system` and both see the same system settings.
    #[arg(long)]
    pub cyclictest_pm_qos: bool,
}

/// A phase during which other processes used more than this share of the CPUs is flagged as disturbed.
const DISTURBED: f64 = 0.05;

/// The summary.json of one policy's run, and what the run's log said.
struct PolicyRun {
    name: String,
    checkpoint: PathBuf,
    dir: PathBuf,
    exit: Option<u8>,
    error: Option<String>,
    summary: Option<Value>,
    rt: RtLog,
    load: PhaseLoad,
}

impl PolicyRun {
    fn channel(&self, channel: &str) -> Option<&Value> {
        self.summary.as_ref()?["latency"]["channels"].as_array()?.iter().find(|c| c["channel"] == channel)
    }

    /// A channel's statistic (`p50`, `p99.9`, `max`, `mean`, `count`, …).
    fn stat(&self, channel: &str, key: &str) -> Option<f64> {
        self.channel(channel)?[key].as_f64()
    }

    fn get(&self, pointer: &str) -> Option<&Value> {
        self.summary.as_ref()?.pointer(pointer)
    }

    fn num(&self, pointer: &str) -> Option<f64> {
        self.get(pointer)?.as_f64()
    }
}

/// The real-time setup marsd applied to its loop threads, as its summary.json's `realtime` says.
#[derive(Default, Clone)]
struct RtLog {
    servo: Option<String>,
    policy: Option<String>,
    /// What was requested and not applied, per thread.
    refusals: Vec<String>,
}

/// An `Outcome` as serialized: `"Applied"`, `"NotRequested"` or `{"Denied": {"errno": 1}}`.
fn outcome_text(v: &Value) -> (String, bool) {
    match v {
        Value::String(s) => (s.clone(), true),
        Value::Object(m) => match m.iter().next() {
            Some((kind, detail)) => (format!("{kind} (errno {})", detail["errno"]), false),
            None => ("?".into(), false),
        },
        _ => ("?".into(), false),
    }
}

fn rt_from_summary(summary: &Value) -> RtLog {
    let mut rt = RtLog::default();
    for t in summary["realtime"].as_array().into_iter().flatten() {
        let thread = t["thread"].as_str().unwrap_or("?");
        let core = t["core"].as_u64().map_or("none".to_string(), |c| c.to_string());
        let (fifo, fifo_ok) = outcome_text(&t["sched_fifo"]);
        let (lock, lock_ok) = outcome_text(&t["memory_locked"]);
        let text = format!("core {core}, SCHED_FIFO {fifo}, mlockall {lock}");
        if let Some(e) = t["pin_error"].as_str() {
            rt.refusals.push(format!("{thread} thread: pinning failed: {e}"));
        }
        if !fifo_ok {
            rt.refusals.push(format!("{thread} thread: SCHED_FIFO {fifo}"));
        }
        if !lock_ok {
            rt.refusals.push(format!("{thread} thread: mlockall {lock}"));
        }
        match thread {
            "servo" => rt.servo = Some(text),
            "policy" => rt.policy = Some(text),
            _ => {}
        }
    }
    rt
}

/// Runs `f` with this process's stderr (fd 2, inherited by the processes it spawns) copied into a string as
/// well as to the real stderr, so marsd's log can be read after the demo.
fn tee_stderr<T>(f: impl FnOnce() -> T) -> anyhow::Result<(T, String)> {
    let mut fds = [0; 2];
    // SAFETY: plain pipe(2)/dup(2)/dup2(2) on descriptors this function owns; fd 2 is restored below.
    if unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
        bail!("pipe: {}", std::io::Error::last_os_error());
    }
    let (read_end, write_end) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    let saved = unsafe { libc::fcntl(2, libc::F_DUPFD_CLOEXEC, 3) };
    if saved < 0 {
        bail!("dup of stderr: {}", std::io::Error::last_os_error());
    }
    let saved = unsafe { OwnedFd::from_raw_fd(saved) };
    let echo = saved.try_clone().context("dup of stderr")?;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::Builder::new().name("bench-stderr".into()).spawn(move || {
        let mut pipe = std::fs::File::from(read_end);
        let mut echo = std::fs::File::from(echo);
        let (mut buf, mut all) = ([0u8; 8192], Vec::new());
        while let Ok(n) = pipe.read(&mut buf) {
            if n == 0 {
                break;
            }
            let _ = echo.write_all(&buf[..n]);
            all.extend_from_slice(&buf[..n]);
        }
        let _ = tx.send(all);
    })?;
    // fd 2 becomes the pipe (dup2 clears close-on-exec, so children inherit it).
    if unsafe { libc::dup2(std::os::fd::AsRawFd::as_raw_fd(&write_end), 2) } < 0 {
        bail!("redirecting stderr: {}", std::io::Error::last_os_error());
    }
    drop(write_end);
    let result = f();
    let _ = std::io::stderr().flush();
    unsafe { libc::dup2(std::os::fd::AsRawFd::as_raw_fd(&saved), 2) };
    // EOF once every writer is gone (the demo waits for its children); a straggler holding the pipe only
    // costs the log's tail.
    let log = rx.recv_timeout(Duration::from_secs(10)).unwrap_or_default();
    Ok((result, String::from_utf8_lossy(&log).into_owned()))
}

fn run_policy(args: &BenchArgs, name: &str, robot: &str) -> PolicyRun {
    let checkpoint = args.checkpoints.join(name);
    let dir = args.out.join(name);
    let summary_path = dir.join("summary.json");
    let _ = std::fs::remove_file(&summary_path);
    eprintln!("== bench: {name} ({}), {} episodes → {}", checkpoint.display(), args.episodes, dir.display());
    let marsd = MarsdArgs {
        robot: Some(format!("{robot}-bench-{}-{name}", std::process::id())),
        episodes: Some(args.episodes),
        out: Some(dir.clone()),
        checkpoint: Some(checkpoint.clone()),
        ..MarsdArgs::new(args.config.clone())
    };
    let demo = DemoArgs { hal_core: args.hal_core.unwrap_or_else(demo_hal_core), ..DemoArgs::new(marsd) };
    let probe = LoadProbe::start();
    let teed = tee_stderr(|| crate::demo::demo(demo));
    let load = probe.finish();
    let mut run = PolicyRun {
        name: name.to_string(),
        checkpoint,
        dir: dir.clone(),
        exit: None,
        error: None,
        summary: None,
        rt: RtLog::default(),
        load,
    };
    match teed {
        Ok((result, log)) => {
            let _ = std::fs::create_dir_all(&dir);
            let _ = std::fs::write(dir.join("marsd.log"), &log);
            match result {
                Ok(code) => run.exit = Some(code),
                Err(e) => run.error = Some(format!("{e:#}")),
            }
        }
        Err(e) => run.error = Some(format!("{e:#}")),
    }
    match std::fs::read_to_string(&summary_path) {
        Ok(text) => match serde_json::from_str(&text) {
            Ok(v) => {
                run.rt = rt_from_summary(&v);
                run.summary = Some(v);
            }
            Err(e) => add_error(&mut run.error, format!("{}: {e}", summary_path.display())),
        },
        Err(e) => add_error(&mut run.error, format!("no {} ({e})", summary_path.display())),
    }
    run
}

/// `mars-hil demo`'s default --hal-core.
pub(crate) fn demo_hal_core() -> usize {
    #[derive(clap::Parser)]
    struct Demo {
        #[command(flatten)]
        args: DemoArgs,
    }
    <Demo as clap::Parser>::try_parse_from(["demo"]).map_or(0, |d| d.args.hal_core)
}

fn add_error(slot: &mut Option<String>, msg: String) {
    *slot = Some(match slot.take() {
        Some(prev) => format!("{prev}; {msg}"),
        None => msg,
    });
}

fn first_line(cmd: &str, args: &[&str]) -> Option<String> {
    let out = Command::new(cmd).args(args).output().ok()?;
    let s = String::from_utf8_lossy(&out.stdout);
    s.lines().next().map(|l| l.trim().to_string()).filter(|l| !l.is_empty())
}

fn read_trim(path: &str) -> Option<String> {
    std::fs::read_to_string(path).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty())
}

/// Whether a fresh thread of this process may use SCHED_FIFO at `priority` (the thread ends right after).
fn probe_sched_fifo(priority: i32) -> String {
    std::thread::spawn(move || format!("{:?}", mars_runtime::rt::try_sched_fifo(priority)))
        .join()
        .unwrap_or_else(|_| "?".into())
}

/// Runs the benchmark and prints (and writes) the results.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.episodes > 0, "--episodes must be at least 1");
    anyhow::ensure!(
        args.policies.iter().any(|p| p == "mars"),
        "--policies must include mars (its run is the one measured against cyclictest)"
    );
    let cfg = mars_runtime::config::DaemonConfig::load(&args.config)?;
    // One real-time rig at a time: cyclictest and the demo rigs measured here must not share the cores.
    let _rig = mars_runtime::rt::rig_lock::rt_rig_lock().context("taking the real-time rig lock")?;
    let profile = mars_profile::Profile::load(&cfg.profile)?;
    let period_us = (profile.period_s() * 1e6).round() as u64;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let started = first_line("date", &["-u", "+%Y-%m-%d %H:%M UTC"]).unwrap_or_else(|| "?".into());

    // MARS first: its run is the one cyclictest is compared with.
    let mut order: Vec<&String> = args.policies.iter().filter(|p| *p == "mars").collect();
    order.extend(args.policies.iter().filter(|p| *p != "mars"));
    let runs: Vec<PolicyRun> = order.iter().map(|p| run_policy(&args, p, &cfg.robot)).collect();
    let mars = &runs[0];

    let wake_count = mars.stat("wake_jitter", "count").map(|c| c as u64).filter(|&c| c > 0);
    let cyclic = if args.no_cyclictest {
        Err(anyhow::anyhow!("skipped (--no-cyclictest)"))
    } else {
        // As many wake-ups as marsd's servo loop measured (so the same duration), 30 s if it measured none.
        let loops = wake_count.unwrap_or(30_000_000 / period_us.max(1));
        run_cyclictest(&args, loops, period_us, cfg.servo.priority, cfg.servo.core)
    };

    let md = report::results_md(&report::Results {
        cmdline: std::env::args().collect::<Vec<_>>().join(" "),
        started,
        config: &args.config,
        episodes: args.episodes,
        seed: cfg.seed,
        rate_hz: profile.rate_hz,
        period_us,
        servo_priority: cfg.servo.priority,
        servo_core: cfg.servo.core,
        policy_core: cfg.policy.core,
        hal_core: args.hal_core.unwrap_or_else(demo_hal_core),
        cyclictest_pm_qos: args.cyclictest_pm_qos,
        runs: &runs,
        cyclic: &cyclic,
    });
    println!("\n{md}");
    let path = args.out.join("results.md");
    std::fs::write(&path, &md).with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    if runs.iter().any(|r| r.summary.is_none()) {
        bail!("a policy's run produced no summary (see the table)");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::cyclictest::Cyclic;
    use super::*;

    #[test]
    fn reads_the_real_time_setup_from_the_summary() {
        use mars_runtime::rt::{Outcome, RtStatus};
        let threads = [
            RtStatus {
                thread: "servo".into(),
                core: Some(1),
                pin_error: None,
                sched_fifo: Outcome::Applied,
                memory_locked: Outcome::Denied { errno: 12 },
            },
            RtStatus {
                thread: "policy".into(),
                core: None,
                pin_error: Some("no such core".into()),
                sched_fifo: Outcome::Denied { errno: 1 },
                memory_locked: Outcome::NotRequested,
            },
        ];
        // As `Summary` serializes it.
        let summary = serde_json::json!({ "realtime": threads });
        let rt = rt_from_summary(&summary);
        assert_eq!(rt.servo.as_deref(), Some("core 1, SCHED_FIFO Applied, mlockall Denied (errno 12)"));
        assert_eq!(rt.policy.as_deref(), Some("core none, SCHED_FIFO Denied (errno 1), mlockall NotRequested"));
        assert_eq!(
            rt.refusals,
            [
                "servo thread: mlockall Denied (errno 12)",
                "policy thread: pinning failed: no such core",
                "policy thread: SCHED_FIFO Denied (errno 1)"
            ]
        );
    }

    #[test]
    fn cyclictest_quantiles_count_overflows() {
        let c = Cyclic {
            cmdline: String::new(),
            version: String::new(),
            cycles: 1000,
            hist: vec![(10_000, 500), (20_000, 490), (900_000, 9)],
            overflows: 1,
            bound_ns: 1_000_000,
            min_ns: 10_000,
            max_ns: 2_000_000,
            avg_ns: 0.0,
            warnings: Vec::new(),
            load: PhaseLoad::default(),
        };
        assert_eq!(c.quantile_us(0.5), Some(10.0));
        assert_eq!(c.quantile_us(0.99), Some(20.0));
        assert_eq!(c.quantile_us(0.999), Some(900.0));
        assert_eq!(c.quantile_us(0.9999), None);
        assert_eq!(c.at_least(1_000_000), 1);
        assert_eq!(c.at_least(900_000), 10);
    }
}
