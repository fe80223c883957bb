//! The command line of `marsd`, as library code: the `marsd` binary and `mars-hil marsd` run the very same
//! daemon (the demo, `mars_hil::demo`, spawns it as a separate process from its own executable, so one
//! `cargo run` builds everything the demo needs).

use std::path::PathBuf;
use std::process::ExitCode;

use crate::daemon::{self, exit};

#[derive(clap::Args, Debug, Clone)]
pub struct MarsdArgs {
    /// Daemon configuration (TOML).
    #[arg(long, default_value = DEFAULT_CONFIG)]
    pub config: PathBuf,
    /// Override `robot` (the iceoryx2 namespace; must match the HAL's --robot). In `mars-hil demo`, a robot's
    /// name (`fr3`, `r1-lite`) picks that robot's demo instead (configs/marsd.toml, configs/marsd_r1_lite.toml),
    /// in a namespace of its own; any other value is the namespace.
    #[arg(long)]
    pub robot: Option<String>,
    /// Override `episodes` (0: run until SIGTERM/SIGINT).
    #[arg(long)]
    pub episodes: Option<usize>,
    /// Override `out`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override `checkpoint`.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Fault injection: every ODE step of the engine busy-waits this long (ms).
    #[arg(long)]
    pub engine_step_delay_ms: Option<f64>,
    /// Override `watchdog.max_state_gap_ms`.
    #[arg(long)]
    pub max_state_gap_ms: Option<f64>,
    /// Record every episode as a LeRobot v3.0 dataset in this directory (it must not exist yet).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Fault injection: the recording's writer sleeps this long per frame (a writer that cannot keep up).
    #[arg(long, requires = "record")]
    pub record_writer_delay_ms: Option<f64>,
    /// Run a recorded episode's chunks instead of the policy's (a dataset `--record` wrote; see `mars-hil
    /// replay`): one episode, with the recording's seed, so from the same start pose.
    #[arg(long, requires = "replay_episode")]
    pub replay_actions: Option<PathBuf>,
    /// The episode of `--replay-actions` (0-based, as LeRobot numbers them).
    #[arg(long, requires = "replay_actions")]
    pub replay_episode: Option<usize>,
}

impl MarsdArgs {
    /// marsd on `config` as the file says: no override, no fault injected, nothing recorded or replayed (what
    /// the command line gives without options).
    pub fn new(config: PathBuf) -> Self {
        Self {
            config,
            robot: None,
            episodes: None,
            out: None,
            checkpoint: None,
            engine_step_delay_ms: None,
            max_state_gap_ms: None,
            record: None,
            record_writer_delay_ms: None,
            replay_actions: None,
            replay_episode: None,
        }
    }
}

/// marsd's logging, the HAL's ([`mars_rt::logging::init_logging`]), and its environment (the video encoder quiet:
/// [`mars_lerobot::video_out::quiet_encoder`]); from main, before any thread exists.
pub fn init_logging() {
    mars_lerobot::video_out::quiet_encoder();
    mars_rt::logging::init_logging();
}

/// `marsd`'s main: exit status per [`daemon::exit`].
pub fn marsd(args: MarsdArgs) -> ExitCode {
    let prepared = (|| {
        let mut cfg = daemon::load_config(&args.config, args.robot, args.episodes, args.out)?;
        if let Some(c) = args.checkpoint {
            cfg.checkpoint = c;
        }
        if let Some(d) = args.engine_step_delay_ms {
            anyhow::ensure!(d.is_finite() && d >= 0.0, "--engine-step-delay-ms must be ≥ 0, got {d}");
            cfg.faults.engine_step_delay_ms = d;
        }
        if let Some(g) = args.max_state_gap_ms {
            anyhow::ensure!(g.is_finite() && g > 0.0, "--max-state-gap-ms must be a positive number of ms, got {g}");
            cfg.watchdog.max_state_gap_ms = g;
        }
        if let Some(r) = args.record {
            cfg.record = Some(r);
        }
        if let Some(d) = args.record_writer_delay_ms {
            anyhow::ensure!(d.is_finite() && d >= 0.0, "--record-writer-delay-ms must be ≥ 0, got {d}");
            cfg.faults.record_writer_delay_ms = d;
        }
        let prepared = daemon::prepare(cfg)?;
        match (&args.replay_actions, args.replay_episode) {
            (Some(dataset), Some(n)) => prepared.replaying(dataset, n),
            _ => Ok(prepared),
        }
    })();
    let prepared = match prepared {
        Ok(p) => p,
        Err(e) => {
            tracing::error!("refusing to start, nothing was commanded: {e:#}");
            return ExitCode::from(exit::BAD_SETUP);
        }
    };
    match daemon::run(prepared) {
        Ok(outcome) => {
            // The last of marsd's own work (the arm held, the report written): what follows is the kernel taking
            // the process down, which a test times apart.
            tracing::info!(status = outcome.exit, "marsd done, exiting");
            ExitCode::from(outcome.exit)
        }
        Err(e) => {
            tracing::error!("{e:#}");
            ExitCode::from(exit::FAILURE)
        }
    }
}

/// marsd's configuration when `--config` is not given.
pub const DEFAULT_CONFIG: &str = "configs/marsd.toml";

/// marsd's whole command line: the daemon's options, or one of its tools (the `marsd` binary, and `mars-hil marsd`,
/// which the demo and the HIL tests start).
#[derive(clap::Args)]
pub struct MarsdCommandLine {
    #[command(flatten)]
    pub marsd: MarsdArgs,
    #[command(subcommand)]
    pub tool: Option<MarsdTool>,
}

#[derive(clap::Subcommand)]
pub enum MarsdTool {
    /// Measure this machine in a few seconds (wake-ups at the servo's rate and priority, steal, RT limits,
    /// PREEMPT_RT, CPU governor, isolated cores), say what a run can expect and how to improve it, and write
    /// doctor.json.
    Doctor(crate::tools::doctor::DoctorArgs),
    /// Watch one camera's frames for a few seconds through the policy's checks (size, encoding, schema, capture
    /// age on CLOCK_MONOTONIC, order): what arrived, what was refused and why, how old frames were, at what rate.
    /// Exits 0 when usable frames came and none was refused, 2 otherwise.
    Camera(crate::tools::camera_watch::CameraArgs),
    /// Watch a running daemon live: servo wake-up lateness and tick time, state age, inference time against its
    /// budget, K, camera ages (p50/p99/max of each last interval, and how many samples took a period or more),
    /// the servo's phase, episode and trip. Reads mars/<robot>/live; costs the daemon's loops nothing.
    Top(crate::tools::top::TopArgs),
    /// Replay a recorded run's policy calls (a dataset from `--record`) through the engine with the seeds and
    /// step counts the run used, and compare with the actions it executed: identical bit for bit on an unchanged
    /// checkpoint, else the first call that differs. Exits 0 when identical, 2 when they differ.
    Replay(crate::tools::replay::ReplayArgs),
    /// Be the inference host of robots whose marsd has `[remote]`: a checkpoint per robot (`--robot NAME=DIR`),
    /// their queries answered over Zenoh earliest deadline first, until SIGTERM/SIGINT or `--duration-s`; prints
    /// per robot the chunks sent, mean K, queries expired unrun and replies sent late.
    Serve(crate::tools::serve::ServeArgs),
}

/// Runs marsd's command line: the daemon, or the tool it names (exit status per [`daemon::exit`] for the daemon;
/// 0 healthy, 2 not, 1 on an error for the tools).
pub fn run_command_line(cl: MarsdCommandLine) -> ExitCode {
    match cl.tool {
        Some(MarsdTool::Doctor(d)) => match crate::tools::doctor::run(&d.config, d.seconds, d.out.as_deref()) {
            Ok(report) => {
                print!("{report}");
                std::process::ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(MarsdTool::Replay(r)) => match crate::tools::replay::run(&r) {
            Ok(report) => {
                print!("{report}");
                std::process::ExitCode::from(if report.identical { 0 } else { 2 })
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(MarsdTool::Camera(c)) => match crate::tools::camera_watch::run(&c) {
            Ok(report) => {
                print!("{report}");
                std::process::ExitCode::from(if report.healthy() { 0 } else { 2 })
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(MarsdTool::Serve(s)) => match crate::tools::serve::run(&s) {
            Ok(served) => {
                print!("{served}");
                std::process::ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        Some(MarsdTool::Top(t)) => match crate::tools::top::run(&t) {
            Ok(_) => std::process::ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
        None => marsd(cl.marsd),
    }
}
