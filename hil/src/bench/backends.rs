//! `mars-hil bench-backends`: the HAL's two backends side by side in one run — the mock plant and the fci backend
//! driving franka-sim over the Franka Control Interface — on the same task, episodes and seed, on a quiet machine
//! and under noise (every core busy with a spinning thread, and the HAL process stopped for a few milliseconds
//! again and again, as a noisy VM or a kernel without PREEMPT_RT does). Per run: the HAL's robot state in →
//! command out, how late states came, the robot's own control success rate, lost states, resyncs and reflexes,
//! from the HAL's and marsd's JSON reports of this run; nothing is hard-coded.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context;
use serde_json::Value;

use crate::demo::{DemoArgs, DemoRobot};
use mars_runtime::cli::MarsdArgs;

#[derive(clap::Args, Debug, Clone)]
pub struct BackendBenchArgs {
    /// Daemon configuration (TOML).
    #[arg(long, default_value = "configs/marsd.toml")]
    pub config: PathBuf,
    /// Episodes per run (12 take a minute of the robot's own time or more: franka-sim runs slower than real time
    /// under the noise, and its cycles are what count).
    #[arg(long, default_value_t = 12)]
    pub episodes: usize,
    /// Where each run's reports and `results.md` go.
    #[arg(long, default_value = "runs/bench-backends")]
    pub out: PathBuf,
    /// Noise: how long each stop of the HAL process lasts (ms) ...
    #[arg(long, default_value_t = 8.0)]
    pub stall_ms: f64,
    /// ... and how often it comes (ms).
    #[arg(long, default_value_t = 300.0)]
    pub stall_every_ms: f64,
    /// Only the quiet machine.
    #[arg(long)]
    pub no_noise: bool,
    /// franka-sim's virtual environment (made by `.ci/franka-sim-venv`).
    #[arg(long, default_value = crate::demo::FRANKA_SIM_VENV)]
    pub franka_sim_venv: PathBuf,
}

/// A thread that stops a process (SIGSTOP) for `stall` every `every` until finished, as a noisy VM or a kernel
/// without PREEMPT_RT does to a real-time loop; `pid_of` finds the process each time (none yet: no stop).
pub struct ProcessStops {
    stop: Arc<AtomicBool>,
    thread: JoinHandle<u64>,
}

impl ProcessStops {
    pub fn start(pid_of: impl Fn() -> Option<libc::pid_t> + Send + 'static, stall: Duration, every: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let halt = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut stops = 0;
            while !halt.load(Ordering::Acquire) {
                std::thread::sleep(every);
                let Some(pid) = pid_of() else { continue };
                // SAFETY: kill(2) on a pid the caller names; SIGCONT follows whatever happens between.
                unsafe { libc::kill(pid, libc::SIGSTOP) };
                std::thread::sleep(stall);
                unsafe { libc::kill(pid, libc::SIGCONT) };
                stops += 1;
            }
            stops
        });
        Self { stop, thread }
    }

    /// Ends the stops (the process is running when this returns); how many there were.
    pub fn finish(self) -> u64 {
        self.stop.store(true, Ordering::Release);
        self.thread.join().unwrap_or(0)
    }
}

/// Busy threads on every core and [`ProcessStops`] on the HAL process, until finished.
struct Noise {
    stop: Arc<AtomicBool>,
    hogs: Vec<JoinHandle<()>>,
    stops: ProcessStops,
}

impl Noise {
    fn start(robot: String, stall: Duration, every: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        let hogs = (0..cores)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        x = std::hint::black_box(x.wrapping_add(1));
                    }
                })
            })
            .collect();
        let stops = ProcessStops::start(move || demo_child_pid("hal", &robot), stall, every);
        Self { stop, hogs, stops }
    }

    /// Stops the noise; how many times the HAL was stopped.
    fn finish(self) -> u64 {
        self.stop.store(true, Ordering::Relaxed);
        for h in self.hogs {
            let _ = h.join();
        }
        self.stops.finish()
    }
}

/// The pid of the process the demo started as `role` (`hal`, `marsd`) for `robot`: its command line is
/// `<exe> <role> … --robot <robot> …`.
pub(crate) fn demo_child_pid(role: &str, robot: &str) -> Option<libc::pid_t> {
    std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
        let pid: libc::pid_t = e.file_name().to_str()?.parse().ok()?;
        let cmd = std::fs::read(e.path().join("cmdline")).ok()?;
        let args: Vec<&[u8]> = cmd.split(|&b| b == 0).collect();
        let is_role = args.get(1) == Some(&role.as_bytes());
        let ours = args.windows(2).any(|w| w[0] == b"--robot" && w[1] == robot.as_bytes());
        (is_role && ours).then_some(pid)
    })
}

/// One run's reports.
struct Run {
    label: String,
    exit: Option<u8>,
    error: Option<String>,
    marsd: Value,
    hal: Value,
    stalls: Option<u64>,
}

fn read_json(path: &Path) -> Value {
    std::fs::read_to_string(path).ok().and_then(|t| serde_json::from_str(&t).ok()).unwrap_or(Value::Null)
}

fn run_one(args: &BackendBenchArgs, backend: DemoRobot, noisy: bool) -> Run {
    let name = format!(
        "{}-{}",
        if backend == DemoRobot::Mock { "mock" } else { "franka-sim" },
        if noisy { "noisy" } else { "quiet" }
    );
    let dir = args.out.join(&name);
    let _ = std::fs::remove_file(dir.join("summary.json"));
    let _ = std::fs::remove_file(dir.join("hal.json"));
    let robot = format!("bench-backends-{}-{name}", std::process::id());
    eprintln!("== bench-backends: {name}, {} episodes → {}", args.episodes, dir.display());
    let marsd = MarsdArgs {
        robot: Some(robot.clone()),
        episodes: Some(args.episodes),
        out: Some(dir.clone()),
        ..MarsdArgs::new(args.config.clone())
    };
    let demo = DemoArgs {
        hal_core: super::demo_hal_core(),
        backend,
        franka_sim_venv: args.franka_sim_venv.clone(),
        ..DemoArgs::new(marsd)
    };
    let noise = noisy.then(|| {
        let ms = |v: f64| Duration::from_secs_f64(v / 1e3);
        Noise::start(robot, ms(args.stall_ms), ms(args.stall_every_ms))
    });
    let result = crate::demo::demo(demo);
    let stalls = noise.map(Noise::finish);
    let (exit, error) = match result {
        Ok(code) => (Some(code), None),
        Err(e) => (None, Some(format!("{e:#}"))),
    };
    Run {
        label: name,
        exit,
        error,
        marsd: read_json(&dir.join("summary.json")),
        hal: read_json(&dir.join("hal.json")),
        stalls,
    }
}

fn num(v: &Value, pointer: &str) -> Option<f64> {
    v.pointer(pointer).and_then(Value::as_f64)
}

fn show(v: Option<f64>, decimals: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.decimals$}"))
}

/// The table: one column per run.
fn table(runs: &[Run], args: &BackendBenchArgs) -> String {
    type Row<'a> = (&'a str, Box<dyn Fn(&Run) -> String>);
    let rows: Vec<Row> = vec![
        (
            "episodes succeeded",
            Box::new(|r| format!("{} / {}", show(num(&r.marsd, "/successes"), 0), show(num(&r.marsd, "/episodes"), 0))),
        ),
        (
            "run length, s of robot cycles (HAL ticks / 1 kHz)",
            Box::new(|r| show(num(&r.hal, "/ticks").map(|t| t / 1e3), 1)),
        ),
        (
            "HAL: robot state in → command out, p50 / p99 / max µs (mock: the tick's work)",
            Box::new(|r| {
                let q = |k: &str| show(num(&r.hal, &format!("/work_us/{k}")), 0);
                format!("{} / {} / {}", q("p50"), q("p99"), q("max"))
            }),
        ),
        (
            "HAL: state later than its period, p99 / max µs (mock: wake-up lateness)",
            Box::new(|r| {
                format!("{} / {}", show(num(&r.hal, "/late_us/p99"), 0), show(num(&r.hal, "/late_us/max"), 0))
            }),
        ),
        (
            "robot's control success rate, min / last",
            Box::new(|r| {
                format!(
                    "{} / {}",
                    show(num(&r.hal, "/robot/min_success_rate"), 3),
                    show(num(&r.hal, "/robot/last_success_rate"), 3)
                )
            }),
        ),
        ("robot states the HAL never saw", Box::new(|r| show(num(&r.hal, "/robot/lost_states"), 0))),
        ("robot states bunched behind a late one", Box::new(|r| show(num(&r.hal, "/robot/bunched_states"), 0))),
        ("setpoint resyncs to the robot's history", Box::new(|r| show(num(&r.hal, "/robot/resyncs"), 0))),
        (
            "of them: a late command the robot threw away",
            Box::new(|r| show(num(&r.hal, "/robot/resyncs_thrown_away"), 0)),
        ),
        (
            "commands kept within the limits from two histories",
            Box::new(|r| show(num(&r.hal, "/robot/judged_twice"), 0)),
        ),
        (
            "robot reflexes",
            Box::new(|r| {
                r.hal.pointer("/robot/reflexes").and_then(Value::as_array).map_or("–".into(), |a| a.len().to_string())
            }),
        ),
        ("HAL: commands late for their tick", Box::new(|r| show(num(&r.hal, "/late_commands"), 0))),
        ("HAL: commands stepping from a setpoint timing moved", Box::new(|r| show(num(&r.hal, "/timing_steps"), 0))),
        (
            "HAL: commands rejected / clamped",
            Box::new(|r| format!("{} / {}", show(num(&r.hal, "/rejected"), 0), show(num(&r.hal, "/clamped"), 0))),
        ),
        ("marsd: servo periods missed", Box::new(|r| show(num(&r.marsd, "/deadline_misses/servo_missed_periods"), 0))),
        ("HAL process stops injected", Box::new(|r| r.stalls.map_or("–".into(), |s| s.to_string()))),
        ("marsd exit", Box::new(|r| r.exit.map_or_else(|| r.error.clone().unwrap_or_default(), |c| c.to_string()))),
    ];
    let mut t = String::new();
    let _ = writeln!(
        t,
        "HAL backends, {} episodes each (noise: a spinning thread per core, the HAL stopped {} ms every {} ms)\n",
        args.episodes, args.stall_ms, args.stall_every_ms
    );
    let _ = writeln!(t, "| | {} |", runs.iter().map(|r| r.label.as_str()).collect::<Vec<_>>().join(" | "));
    let _ = writeln!(t, "|---|{}", "---:|".repeat(runs.len()));
    for (name, cell) in &rows {
        let _ = writeln!(t, "| {name} | {} |", runs.iter().map(cell).collect::<Vec<_>>().join(" | "));
    }
    t
}

/// Runs the four (or two) demos and prints and writes the table.
pub fn run(args: BackendBenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.episodes > 0, "--episodes must be at least 1");
    anyhow::ensure!(
        args.stall_ms > 0.0 && args.stall_every_ms > args.stall_ms,
        "--stall-ms must be > 0 and < --stall-every-ms"
    );
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut runs = vec![];
    for noisy in if args.no_noise { vec![false] } else { vec![false, true] } {
        for backend in [DemoRobot::Mock, DemoRobot::FrankaSim] {
            runs.push(run_one(&args, backend, noisy));
        }
    }
    let t = table(&runs, &args);
    println!("\n{t}");
    let path = args.out.join("results.md");
    std::fs::write(&path, &t).with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}
