//! `marsd`: the MARS controller daemon. Drives a robot's HAL process over iceoryx2 with a MARS policy: a
//! pinned servo loop with jerk-limited smoothing, a deadline-capped policy loop, a watchdog.

use clap::Parser;

// Counts heap allocations per thread, so every run reports that the servo tick made none.
#[global_allocator]
static ALLOC: mars_runtime::alloc_count::CountingAlloc = mars_runtime::alloc_count::CountingAlloc;
use mars_runtime::cli::{MarsdArgs, init_logging, marsd};

#[derive(Parser)]
#[command(version, about = "MARS controller daemon: servo loop, deadline-capped policy, watchdog")]
#[command(args_conflicts_with_subcommands = true)]
struct Args {
    #[command(flatten)]
    marsd: MarsdArgs,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Measure this machine in a few seconds (wake-ups at the servo's rate and priority, steal, RT limits,
    /// PREEMPT_RT, CPU governor, isolated cores), say what a run can expect and how to improve it, and write
    /// doctor.json.
    Doctor(mars_runtime::doctor::DoctorArgs),
    /// Watch one camera's frames for a few seconds through the policy's checks (size, encoding, schema, capture
    /// age on CLOCK_MONOTONIC, order): what arrived, what was refused and why, how old frames were, at what rate.
    /// Exits 0 when usable frames came and none was refused, 2 otherwise.
    Camera(mars_runtime::camera_watch::CameraArgs),
    /// Watch a running daemon live: servo wake-up lateness and tick time, state age, inference time against its
    /// budget, K, camera ages (p50/p99/max of each last interval, and how many samples took a period or more),
    /// the servo's phase, episode and trip. Reads mars/<robot>/live; costs the daemon's loops nothing.
    Top(mars_runtime::top::TopArgs),
    /// Replay a recorded run's policy calls (a dataset from `--record`) through the engine with the seeds and
    /// step counts the run used, and compare with the actions it executed: identical bit for bit on an unchanged
    /// checkpoint, else the first call that differs. Exits 0 when identical, 2 when they differ.
    Replay(mars_runtime::replay::ReplayArgs),
}

fn main() -> std::process::ExitCode {
    init_logging();
    let args = Args::parse();
    match args.command {
        Some(Command::Doctor(d)) => match mars_runtime::doctor::run(&d.config, d.seconds, d.out.as_deref()) {
            Ok(report) => {
                print!("{report}");
                std::process::ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(Command::Replay(r)) => match mars_runtime::replay::run(&r) {
            Ok(report) => {
                print!("{report}");
                std::process::ExitCode::from(if report.identical { 0 } else { 2 })
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(Command::Camera(c)) => match mars_runtime::camera_watch::run(&c) {
            Ok(report) => {
                print!("{report}");
                std::process::ExitCode::from(if report.healthy() { 0 } else { 2 })
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(Command::Top(t)) => match mars_runtime::top::run(&t) {
            Ok(_) => std::process::ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        None => marsd(args.marsd),
    }
}
