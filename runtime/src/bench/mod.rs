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
use std::fmt::Write as _;
use std::io::{Read, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use serde_json::Value;

use crate::cli::{DemoArgs, MarsdArgs};

pub mod backends;
mod cyclictest;
mod load;

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
    let teed = tee_stderr(|| crate::cli::demo(demo));
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
    std::thread::spawn(move || format!("{:?}", crate::rt::try_sched_fifo(priority)))
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
    let cfg = crate::config::DaemonConfig::load(&args.config)?;
    // One real-time rig at a time: cyclictest and the demo rigs measured here must not share the cores.
    let _rig = crate::rt::rig_lock::rt_rig_lock().context("taking the real-time rig lock")?;
    let profile = mars_hal::profile::Profile::load(&cfg.profile)?;
    let period_us = (profile.period_s() * 1e6).round() as u64;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let started = first_line("date", &["-u", "+%Y-%m-%d %H:%M UTC"]).unwrap_or_else(|| "?".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());

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

    let mut md = String::new();
    let w = &mut md;
    let cmdline: Vec<String> = std::env::args().collect();
    let _ = writeln!(w, "# marsd benchmark\n");
    let _ = writeln!(
        w,
        "`{}` — {started}; config `{}`, {} episodes per policy, seed {}, servo {} Hz.\n",
        cmdline.join(" "),
        args.config.display(),
        args.episodes,
        cfg.seed,
        profile.rate_hz
    );

    // Machine facts.
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
        cfg.servo.priority,
        probe_sched_fifo(cfg.servo.priority)
    );
    for r in &runs {
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
        cfg.servo.core.map_or("–".into(), |c| c.to_string()),
        cfg.policy.core.map_or("–".into(), |c| c.to_string()),
        args.hal_core.unwrap_or_else(demo_hal_core)
    );
    for r in &runs {
        let _ = writeln!(w, "| load during the {} demo | {} |", r.name, r.load.describe(cores));
    }
    let mut phases: Vec<(String, &PhaseLoad)> =
        runs.iter().map(|r| (format!("the {} demo", r.name), &r.load)).collect();
    if let Ok(c) = &cyclic {
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

    // 1. Wake-up jitter.
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
    match &cyclic {
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
                c.at_least(period_us * 1000)
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
            let pm = if args.cyclictest_pm_qos {
                "cyclictest held /dev/cpu_dma_latency at 0 µs (marsd does not)"
            } else {
                "`--default-system`: cyclictest leaves power management alone, as marsd does"
            };
            let _ = writeln!(
                w,
                "It ran after the demos, with none of the benchmark's other processes (no HAL, no marsd; the load \
                 row above says what else ran), for the same number of wake-ups, at the same period ({period_us} µs), \
                 SCHED_FIFO priority ({}), core ({}) and with mlockall; {pm}.",
                cfg.servo.priority,
                cfg.servo.core.map_or("unpinned".into(), |c| c.to_string())
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

    // 2. The tick.
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

    // 3. Policies.
    let _ = writeln!(w, "\n## 3. MARS vs the baselines on the FR3 task (HIL demo, same episodes and seed)\n");
    let others: Vec<&PolicyRun> = runs.iter().skip(1).collect();
    let mut header = String::from("| |");
    let mut rule = String::from("|---|");
    for r in &runs {
        let _ = write!(header, " {} |", r.name.to_uppercase());
        rule.push_str("---:|");
    }
    for o in &others {
        let _ = write!(header, " MARS/{} |", o.name.to_uppercase());
        rule.push_str("---:|");
    }
    let _ = writeln!(w, "{header}\n{rule}");
    type Cell = Box<dyn Fn(&PolicyRun) -> (String, Option<f64>)>;
    let rows: Vec<(&str, Cell, bool)> = vec![
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
        (
            "K requested mean",
            Box::new(|r| {
                let v = r.num("/k/requested_mean");
                (f2(v), v)
            }),
            true,
        ),
        ("K requested p50", Box::new(|r| (f0(r.stat("k_requested", "p50")), r.stat("k_requested", "p50"))), false),
        ("K requested max", Box::new(|r| (f0(r.stat("k_requested", "max")), None)), false),
        (
            "K used mean",
            Box::new(|r| {
                let v = r.num("/k/used_mean");
                (f2(v), v)
            }),
            true,
        ),
        ("K used max", Box::new(|r| (f0(r.num("/k/used_max")), None)), false),
        (
            "calls capped by the deadline",
            Box::new(|r| (r.num("/k/capped").map_or("–".into(), |v| format!("{v:.0}")), None)),
            false,
        ),
        (
            "inference p50 (µs)",
            Box::new(|r| {
                let v = r.stat("inference", "p50");
                (f1(v), v)
            }),
            true,
        ),
        (
            "inference p99 (µs)",
            Box::new(|r| {
                let v = r.stat("inference", "p99");
                (f1(v), v)
            }),
            true,
        ),
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
    ];
    for (label, cell, with_ratio) in &rows {
        let mut line = format!("| {label} |");
        for r in &runs {
            let _ = write!(line, " {} |", cell(r).0);
        }
        for o in &others {
            let text = if *with_ratio { ratio(cell(mars).1, cell(o).1) } else { String::new() };
            let _ = write!(line, " {text} |");
        }
        let _ = writeln!(w, "{line}");
    }
    let _ = writeln!(w, "\nCheckpoints and each run's summary.json, latency table, histogram log and plots:");
    for r in &runs {
        let exit = r.exit.map_or("–".into(), |c| c.to_string());
        let _ = writeln!(
            w,
            "- {}: `{}` → `{}/` (marsd exit status {exit})",
            r.name,
            r.checkpoint.display(),
            r.dir.display()
        );
    }

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
        use crate::rt::{Outcome, RtStatus};
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
