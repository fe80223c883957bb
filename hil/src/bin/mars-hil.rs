//! `mars-hil`: the FR3 hardware-in-the-loop task (Pick Cup, rim vs handle): expert demos recorded on the sim
//! plant, and in-process evaluation of a checkpoint against it.

use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};

// Counts heap allocations per thread, so every run reports that the servo tick made none.
#[global_allocator]
static ALLOC: mars_runtime::alloc_count::CountingAlloc = mars_runtime::alloc_count::CountingAlloc;
use mars_hil::task::cli;

#[derive(Parser)]
#[command(name = "mars-hil", version, about = "MARS on the FR3 HIL task: the demo, demos, in-process evaluation")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

/// Where the task and the robot are described (shared by every subcommand).
#[derive(clap::Args)]
struct TaskArgs {
    #[arg(long, default_value = "configs/pick_cup.toml")]
    task: PathBuf,
    #[arg(long, default_value = "configs/fr3.toml")]
    profile: PathBuf,
}

#[derive(Subcommand)]
enum Command {
    /// The HIL demo: start the mock FR3 HAL and marsd as two processes, run the episodes, print the report
    /// (success, modes, γ, K, latency percentiles, deadline misses, limit violations) and write plots and
    /// histogram logs.
    Demo {
        #[command(flatten)]
        args: mars_hil::demo::DemoArgs,
    },
    /// A recorded episode's commands through the HAL again (marsd runs the recording's chunks from the same
    /// start pose, recorded in turn): how closely the plant's trajectory and the episode's outcome come back.
    /// Exit status 0 when reproduced within --tolerance, 2 when not, marsd's when the run failed.
    Replay {
        #[command(flatten)]
        args: mars_hil::hil_replay::HilReplayArgs,
    },
    /// The benchmark, in one run: servo wake-up jitter next to cyclictest, tick compute and allocations per
    /// tick, MARS vs FM on the task; prints a markdown table and writes it to <out>/results.md.
    Bench {
        #[command(flatten)]
        args: mars_hil::bench::BenchArgs,
    },
    /// The demo with its policy on `marsd serve` behind a link delayed by each of --one-way-ms, next to the demo on
    /// its local engine: success, whose chunks, round trip, capture → command, link bytes, misses, limits, handover
    /// jerk; prints a markdown table and writes it to <out>/results.md.
    BenchRemote {
        #[command(flatten)]
        args: mars_hil::bench::remote::RemoteBenchArgs,
    },
    /// One `marsd serve` serving N robots (clients of the wire, each asking every period, phase-shifted): per robot
    /// the chunks in time, misses, round trip, and the host's queue waits; prints a markdown table.
    BenchFleet {
        #[command(flatten)]
        args: mars_hil::bench::fleet::FleetBenchArgs,
    },
    /// The HAL's backends side by side in one run: the mock plant and the fci backend on franka-sim, on a quiet
    /// machine and under noise (busy cores, the HAL stopped for milliseconds again and again); prints a markdown
    /// table and writes it to <out>/results.md.
    BenchBackends {
        #[command(flatten)]
        args: mars_hil::bench::backends::BackendBenchArgs,
    },
    /// marsd killed (SIGKILL) or stopped (SIGSTOP 1–300 ms) at a random moment of Pick Cup, trial after trial, on
    /// the mock HAL and on franka-sim; each trial's applied stream judged by `mars-checker` (a program of its own:
    /// the FR3's position-dependent velocity bounds, acceleration, jerk, position, the robot's reflexes). Prints
    /// the table (and writes <out>/results.md); exit status 1 on any violation, reflex or arm not left at rest.
    Faults {
        #[command(flatten)]
        args: mars_hil::faults::FaultArgs,
    },
    /// The demo loop for a long time (default 1 h per backend; Pick Cup until stopped) on the mock HAL and on
    /// franka-sim, with marsd's and the HAL's RSS sampled: prints RSS after warm-up (start / end / max), the loops'
    /// allocations after warm-up and any trip; exit status 1 on a trip or an allocation.
    Soak {
        #[command(flatten)]
        args: mars_hil::soak::SoakArgs,
    },
    /// The controller daemon and its tools (the same as the `marsd` binary; the demo starts it this way).
    #[command(args_conflicts_with_subcommands = true)]
    Marsd {
        #[command(flatten)]
        args: mars_runtime::cli::MarsdCommandLine,
    },
    /// The mock HAL process (the same as the `mars-hal` binary; the demo starts it this way).
    Hal {
        #[command(flatten)]
        args: mars_hal::cli::HalArgs,
    },
    /// The Push-T scene (the demo starts it with `--task push-t`): the T block's physics with the pusher where
    /// the robot's flange is, the top-down camera published on mars/<robot>/camera/<name>, the episode's referee.
    Scene {
        #[command(flatten)]
        args: mars_hil::scene::SceneArgs,
    },
    /// Train a Push-T vision policy: expert demos made in process from their seed (half by each route), then the
    /// trainer `mars train` runs, then a checkpoint marsd and the engine load.
    PushTTrain {
        #[arg(long, value_parser = mars_policy::kind_arg::policy_kind_parser())]
        policy: mars_policy::config::PolicyKind,
        #[arg(long, default_value = "configs/push_t_policy.toml")]
        config: PathBuf,
        #[arg(long, default_value = "configs/push_t.toml")]
        task: PathBuf,
        #[arg(long, default_value = "configs/fr3.toml")]
        profile: PathBuf,
        #[arg(long, default_value_t = 40)]
        demos: usize,
        #[arg(long, default_value_t = mars_hil::task::push_t_cli::DEMO_SEED)]
        seed: u64,
        /// Override the config's `train.epochs`.
        #[arg(long)]
        epochs: Option<usize>,
        #[arg(long)]
        out: PathBuf,
    },
    /// Roll Push-T checkpoints out in process (the scene's world, the camera the policy sees there): success,
    /// successes by route, γ, mean K, call latency; one markdown row per checkpoint.
    PushTEval {
        /// Checkpoint directories (e.g. …/mars …/fm …/a2a).
        #[arg(long, num_args = 1.., required = true)]
        checkpoint: Vec<PathBuf>,
        #[arg(long, default_value = "configs/push_t.toml")]
        task: PathBuf,
        #[arg(long, default_value = "configs/fr3.toml")]
        profile: PathBuf,
        #[arg(long, default_value_t = 50)]
        episodes: usize,
        #[arg(long, default_value_t = 1000)]
        seed: u64,
        /// Actions executed per chunk (default: the whole chunk, as marsd does).
        #[arg(long)]
        exec_horizon: Option<usize>,
    },
    /// Record balanced, verified expert demos on the sim plant (train on them with `mars train --demos`).
    Demos {
        #[command(flatten)]
        task: TaskArgs,
        #[arg(long, default_value_t = 100)]
        n: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value = "runs/fr3/demos.json")]
        out: PathBuf,
    },
    /// Training efficiency on Pick Cup (paper Fig. 1(e)): train each policy × seed with a snapshot every N
    /// epochs (through the `mars` binary next to this one), roll every snapshot out in-process, and write
    /// success and γ per epoch (mean ± std), epochs-to-X % success and a plot.
    Curve {
        #[command(flatten)]
        args: mars_policy::curve::CurveArgs,
        #[command(flatten)]
        task: TaskArgs,
        /// Train in this process instead of through `mars` (slower: this binary's allocator counts every
        /// allocation; for a machine without the `mars` binary).
        #[arg(long)]
        in_process: bool,
    },
    /// Roll a checkpoint out in-process against the sim plant (no IPC): success, grasp modes, γ, mean K.
    EvalSim {
        #[arg(long, default_value = "assets/checkpoints/fr3_pick_cup/mars")]
        checkpoint: PathBuf,
        #[command(flatten)]
        task: TaskArgs,
        #[arg(long, default_value_t = 100)]
        episodes: usize,
        #[arg(long, default_value_t = 1000)]
        seed: u64,
        /// Also write the report with every episode to this JSON file.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Roll a checkpoint out in-process with each chunk adopted N policy periods after its observation (a round
    /// trip of N periods to an inference host), for each way to continue the rows already executed (drop-late,
    /// guided, history): success and boundary jerk with 95 % intervals, each against drop-late on the same seeds.
    DelaySweep {
        #[arg(long, default_value = "assets/checkpoints/fr3_pick_cup/mars")]
        checkpoint: PathBuf,
        #[command(flatten)]
        task: TaskArgs,
        /// Delays in policy periods (at most half a chunk).
        #[arg(long, value_delimiter = ',', default_value = "0,1,2,4")]
        delays: Vec<usize>,
        #[arg(long, default_value_t = 200)]
        episodes: usize,
        #[arg(long, default_value_t = 1000)]
        seed: u64,
    },
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    mars_policy::cli::init_runtime_env(1);
    let result = match args.command {
        Command::Demo { args } => match mars_hil::demo::demo(args) {
            Ok(code) => return std::process::ExitCode::from(code),
            Err(e) => Err(e),
        },
        Command::Replay { args } => match mars_hil::hil_replay::run(&args) {
            Ok((report, code)) => {
                if let Some(r) = report {
                    print!("{r}");
                }
                return std::process::ExitCode::from(code);
            }
            Err(e) => Err(e),
        },
        Command::Bench { args } => mars_hil::bench::run(args),
        Command::BenchRemote { args } => mars_hil::bench::remote::run(args),
        Command::BenchFleet { args } => mars_hil::bench::fleet::run(args),
        Command::BenchBackends { args } => mars_hil::bench::backends::run(args),
        Command::Faults { args } => match mars_hil::faults::run(&args) {
            Ok(clean) => return std::process::ExitCode::from(if clean { 0 } else { 1 }),
            Err(e) => Err(e),
        },
        Command::Soak { args } => match mars_hil::soak::run(&args) {
            Ok(clean) => return std::process::ExitCode::from(if clean { 0 } else { 1 }),
            Err(e) => Err(e),
        },
        Command::Marsd { args } => return mars_runtime::cli::run_command_line(args),
        Command::Hal { args } => {
            let code = mars_hal::cli::report_and_exit_code(mars_hal::cli::run_hal(args));
            return std::process::ExitCode::from(code as u8);
        }
        Command::PushTTrain { policy, config, task, profile, demos, seed, epochs, out } => {
            mars_hil::task::push_t_cli::train(&config, &task, &profile, policy, demos, seed, epochs, &out)
        }
        Command::PushTEval { checkpoint, task, profile, episodes, seed, exec_horizon } => (|| {
            println!(
                "| policy | success | by route (upper, lower) | γ | mean K | call p50 / p99 ms (candle) | final error (mean) |"
            );
            println!("|---|---:|---:|---:|---:|---:|---:|");
            for c in &checkpoint {
                let e = mars_hil::task::push_t_cli::eval(c, &task, &profile, episodes, seed, exec_horizon)?;
                println!("{e}");
            }
            Ok(())
        })(),
        Command::Scene { args } => mars_hil::scene::run(&args).map(|_| ()),
        Command::Demos { task, n, seed, out } => cli::demos(&task.task, &task.profile, n, seed, &out),
        Command::Curve { args, task, in_process } => curve(&args, &task, in_process),
        Command::EvalSim { checkpoint, task, episodes, seed, out } => {
            cli::eval(&checkpoint, &task.task, &task.profile, episodes, seed, out.as_deref()).map(|_| ())
        }
        Command::DelaySweep { checkpoint, task, delays, episodes, seed } => {
            delay_sweep(&checkpoint, &task, &delays, episodes, seed)
        }
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn delay_sweep(checkpoint: &Path, task: &TaskArgs, delays: &[usize], n: usize, seed: u64) -> anyhow::Result<()> {
    use mars_hil::task::delay_sweep::{sweep, table};
    let rows = sweep(checkpoint, &task.task, &task.profile, delays, n, seed)?;
    let rate = cli::load_task(&task.task, &task.profile)?.0.cfg.policy_rate_hz;
    println!("{} episodes per row (seeds {seed}..), {}", n, checkpoint.display());
    print!("{}", table(&rows, rate));
    Ok(())
}

fn curve(args: &mars_policy::curve::CurveArgs, task: &TaskArgs, in_process: bool) -> anyhow::Result<()> {
    use anyhow::Context;
    use mars_policy::curve::Trainer;
    // Training runs in the `mars` binary by default: this one's global allocator counts every allocation (for
    // the servo tick), which is no allocator to train candle on.
    let trainer = if in_process {
        Trainer::InProcess
    } else {
        let here = std::env::current_exe().context("cannot find this executable")?;
        let mars = here.with_file_name("mars");
        anyhow::ensure!(
            mars.exists(),
            "{} not found: build it with `cargo build --release --bin mars`, or pass --in-process",
            mars.display()
        );
        Trainer::Command(mars)
    };
    let curve_task = cli::PickCurve {
        task: task.task.clone(),
        profile: task.profile.clone(),
        demos: args.demos,
        episodes: args.episodes,
    };
    let config = args.config.clone().unwrap_or_else(|| "configs/fr3_policy.toml".into());
    let out = args.out.clone().unwrap_or_else(|| "runs/curve_pick_cup".into());
    let extra = format!(" --task {} --profile {}", task.task.display(), task.profile.display());
    let command = args.command_line("mars-hil", &extra);
    mars_policy::curve::run(&out, &config, &args.options(), &curve_task, &trainer, &command).map(|_| ())
}
