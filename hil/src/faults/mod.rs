//! `mars-hil faults`: marsd killed (SIGKILL) or stopped (SIGSTOP for 1–300 ms, then SIGCONT) at a random moment of
//! a Pick Cup episode, again and again, on the mock HAL and on franka-sim. Each trial's applied stream is recorded
//! and judged by `mars-checker`, a program of its own that shares no limit code with the HAL or marsd (the FR3's
//! position-dependent velocity bounds, acceleration, jerk and position by finite differences, the robot's
//! reflexes); this command only injects the faults, times them and tabulates the checker's verdicts.

mod rig;
mod table;
mod trial;
mod watch;

pub use rig::wait_child;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, LazyLock};
use std::time::Duration;

use anyhow::Context;
use rand::{Rng, SeedableRng};

use crate::demo::DemoRobot;
use trial::{Fault, Plan};

/// Set by SIGTERM or SIGINT: no further trial starts.
static STOP: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

#[derive(clap::Args, Debug, Clone)]
pub struct FaultArgs {
    /// Trials per backend.
    #[arg(long, default_value_t = 100)]
    pub trials: usize,
    /// Seed of each trial's fault, moment and stop length (the same sequence on every backend).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The backends: the mock HAL, franka-sim (the fci backend), or both in turn.
    #[arg(long, value_enum, default_value_t = Backends::Both)]
    pub backend: Backends,
    /// The shortest and the longest SIGSTOP (ms); each is drawn uniformly between them.
    #[arg(long, default_value_t = 1.0)]
    pub stop_min_ms: f64,
    #[arg(long, default_value_t = 300.0)]
    pub stop_max_ms: f64,
    /// Daemon configuration (TOML): the task, the profile whose limits the checker judges with.
    #[arg(long, default_value = mars_runtime::cli::DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Each trial's recording, logs and verdict go to <out>/<backend>/trial-<n>/; the table to <out>/results.md.
    #[arg(long, default_value = "runs/faults")]
    pub out: PathBuf,
    /// The checker program (default: `mars-checker` next to this executable; `cargo build --release -p
    /// mars-checker` builds it).
    #[arg(long)]
    pub checker: Option<PathBuf>,
    /// franka-sim's virtual environment (made by `.ci/franka-sim-venv`, run first when it is missing).
    #[arg(long, default_value = crate::demo::FRANKA_SIM_VENV)]
    pub franka_sim_venv: PathBuf,
}

#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backends {
    Mock,
    FrankaSim,
    Both,
}

/// Runs the trials and prints the table; `Ok(false)` when any trial was not clean (a violation, a reflex, the arm
/// not left at rest) or could not be run.
pub fn run(args: &FaultArgs) -> anyhow::Result<bool> {
    anyhow::ensure!(args.trials > 0, "--trials must be at least 1");
    anyhow::ensure!(
        args.stop_min_ms.is_finite() && args.stop_min_ms > 0.0 && args.stop_min_ms <= args.stop_max_ms,
        "--stop-min-ms must be positive and at most --stop-max-ms, got {} and {}",
        args.stop_min_ms,
        args.stop_max_ms
    );
    let exe = std::env::current_exe().context("locating this executable")?;
    let checker = args.checker.clone().unwrap_or_else(|| exe.with_file_name("mars-checker"));
    anyhow::ensure!(
        checker.exists(),
        "{} not found: build it with `cargo build --release -p mars-checker`, or pass --checker",
        checker.display()
    );
    let backends = match args.backend {
        Backends::Mock => vec![DemoRobot::Mock],
        Backends::FrankaSim => vec![DemoRobot::FrankaSim],
        Backends::Both => vec![DemoRobot::Mock, DemoRobot::FrankaSim],
    };
    // A termination request ends the run after the trial under way; the rig then stops as after the last trial.
    for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(signal, Arc::clone(&STOP)).context("registering the termination handler")?;
    }
    let mut rows = Vec::new();
    for backend in backends {
        if STOP.load(Ordering::Acquire) {
            break;
        }
        rows.push(run_backend(args, &exe, &checker, backend)?);
    }
    let all_clean = rows.iter().all(|r| r.errors.is_empty() && r.outcomes.iter().all(|o| o.clean));
    let text = table::render(&rows, args);
    print!("{text}");
    std::fs::create_dir_all(&args.out)?;
    std::fs::write(args.out.join("results.md"), &text)?;
    Ok(all_clean)
}

fn backend_name(b: DemoRobot) -> &'static str {
    if b == DemoRobot::Mock { "mock" } else { "franka-sim" }
}

/// One backend's trials: a clean episode first (its length bounds the moments drawn), then the faults. A reflex the
/// HAL cannot recover from (franka-sim's arm may not settle after one) restarts the rig, as a person would restart
/// the robot, in `<dir>/rig-<n>/`.
fn run_backend(
    args: &FaultArgs,
    exe: &Path,
    checker: &Path,
    backend: DemoRobot,
) -> anyhow::Result<table::BackendResult> {
    let dir = args.out.join(backend_name(backend));
    eprintln!("== faults on {}: {} trials → {}", backend_name(backend), args.trials, dir.display());
    let start_rig = |n: usize| {
        let at = if n == 0 { dir.clone() } else { dir.join(format!("rig-{n}")) };
        rig::Rig::start(exe, &args.config, backend, &args.franka_sim_venv, &at)
    };
    let mut rig = start_rig(0)?;
    let mut hal = Vec::new();
    let baseline =
        trial::run(&mut rig, checker, &dir.join("baseline"), Plan { fault: Fault::None, at: Duration::ZERO })?;
    let episode = baseline.session_time;
    eprintln!("   a clean episode: {:.2} s, checker: {}", episode.as_secs_f64(), summary(&baseline));
    let mut rng = rand::rngs::StdRng::seed_from_u64(args.seed);
    let (mut outcomes, mut errors) = (vec![baseline], Vec::new());
    for i in 0..args.trials {
        if STOP.load(Ordering::Acquire) {
            errors.push(format!("stopped by a signal after {i} trials"));
            break;
        }
        let plan = draw(&mut rng, episode, args);
        match trial::run(&mut rig, checker, &dir.join(format!("trial-{i:03}")), plan) {
            Ok(o) => {
                eprintln!("   {:>3}/{} {}: {}", i + 1, args.trials, describe(&plan), summary(&o));
                let reflex = trial::reflexes(&o.verdict) > 0;
                outcomes.push(o);
                if reflex && !trial::recover(&mut rig) {
                    eprintln!("   the HAL could not take the arm over after the reflex: the rig is restarted");
                    hal.push(rig.stop());
                    rig = start_rig(hal.len())?;
                }
            }
            Err(e) => {
                eprintln!("   {:>3}/{} {}: could not run: {e:#}", i + 1, args.trials, describe(&plan));
                errors.push(format!("trial {i}: {e:#}"));
            }
        }
    }
    hal.push(rig.stop());
    Ok(table::BackendResult { backend, outcomes, errors, hal })
}

/// The latest moment a fault is drawn at, as a share of the clean episode's length: a trial's episode can end a little
/// sooner than the clean one (on a noisy VM, 2026-11-29, a SIGKILL drawn late found marsd finished: a trial lost).
const LATEST_SHARE: f64 = 0.8;

/// A trial's fault: SIGKILL or SIGSTOP with equal odds, at a moment uniform over the first [`LATEST_SHARE`] of a clean
/// episode's length, a stop's length uniform in [stop_min, stop_max].
fn draw(rng: &mut impl Rng, episode: Duration, args: &FaultArgs) -> Plan {
    let kill = rng.random_bool(0.5);
    let at = episode.mul_f64(LATEST_SHARE * rng.random_range(0.0..1.0));
    let held = Duration::from_secs_f64(rng.random_range(args.stop_min_ms..=args.stop_max_ms) / 1e3);
    Plan { fault: if kill { Fault::Kill } else { Fault::Stop(held) }, at }
}

fn describe(plan: &Plan) -> String {
    let at = plan.at.as_secs_f64();
    match plan.fault {
        Fault::Stop(held) => format!("SIGSTOP {:.0} ms at {at:.2} s", held.as_secs_f64() * 1e3),
        f => format!("{} at {at:.2} s", f.kind()),
    }
}

fn summary(o: &trial::Outcome) -> String {
    let v = &o.verdict;
    let r = &v["reaction"];
    let reaction = if r.is_object() {
        format!(
            "; HAL {} ({}) after {} ms, at rest after {} ms",
            if r["held"] == true { "held" } else { "kept following" },
            r["hold_reason"].as_str().unwrap_or("?"),
            table::ms(&r["hold_ms"]),
            table::ms(&r["rest_ms"])
        )
    } else {
        String::new()
    };
    format!(
        "{} ({} violations, {} reflexes, {} frames, {} lost){reaction}; marsd exit {}",
        if o.clean { "clean" } else { "NOT CLEAN" },
        v["violations"],
        trial::reflexes(v),
        v["frames"],
        v["lost_frames"],
        o.marsd_exit.map_or("killed".into(), |c| c.to_string())
    )
}
