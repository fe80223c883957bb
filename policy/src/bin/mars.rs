//! `mars`: generate nav2d demos, train MARS or a baseline, evaluate, plot, and run the whole benchmark.

use clap::{Parser, Subcommand};
use mars_policy::cli;
use mars_policy::config::PolicyKind;
use mars_policy::family;
use std::path::PathBuf;

// candle allocates a fresh buffer for every op; mimalloc made backward passes 3–4× faster than glibc here.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(name = "mars", version, about = "MARS policy: train, evaluate and benchmark on 2-D navigation")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate expert demos on a nav2d layout (balanced across the passages).
    Demos {
        #[arg(long, default_value = "configs/nav2d.toml")]
        layout: PathBuf,
        #[arg(long, default_value_t = 200)]
        n: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value = "runs/nav2d/demos.json")]
        out: PathBuf,
    },
    /// Training speed: seconds per epoch by hand, through candle's autograd and (with --python) in the PyTorch
    /// peer (policy/benches/torch_trainer.py) on the same samples, in turns; medians and ratios.
    BenchTrain(BenchTrainArgs),
    /// Train one policy on a demo file and write a checkpoint directory.
    Train(TrainArgs),
    /// Roll a checkpoint out N times (distinct seeds) and print success, passage counts, γ, K and latency.
    Eval {
        #[arg(long)]
        checkpoint: PathBuf,
        #[arg(long, default_value = "configs/nav2d.toml")]
        layout: PathBuf,
        #[arg(long, default_value_t = 1000)]
        rollouts: usize,
        #[arg(long, default_value_t = 1000)]
        seed: u64,
        /// Actions executed from each chunk before re-planning.
        #[arg(long, default_value_t = cli::DEFAULT_EXEC_HORIZON)]
        exec_horizon: usize,
        /// Ablation: integrate with exactly this many Euler steps instead of K(w) (writes eval_k<N>.json).
        #[arg(long, conflicts_with = "k_full_w")]
        steps: Option<usize>,
        /// Ablation: K(w) with this ‖w‖∞ getting K_max steps instead of the checkpoint's `model.k_full_w`.
        #[arg(long)]
        k_full_w: Option<f32>,
        /// Rollouts run side by side through the model per call (the scores do not depend on it).
        #[arg(long, default_value_t = mars_policy::evaluation::DEFAULT_BATCH)]
        batch: usize,
    },
    /// Where the diversity loss acts on a checkpoint: per layout region, S_next vs S_curr, how often
    /// ReLU(S_next − S_curr) is active, w, and which demos the neighbours come from.
    Diagnose {
        #[arg(long)]
        checkpoint: PathBuf,
        #[arg(long, default_value = "runs/nav2d/demos.json")]
        demos: PathBuf,
        #[arg(long, default_value = "configs/nav2d.toml")]
        layout: PathBuf,
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// Where a `mars family` run's checkpoints lose their demos' modes, judged over its seeds: each seed's first
    /// chunk past the entry gate against its rollouts, MARS against FM; writes diagnose_family.md and .json in RUN.
    DiagnoseFamily {
        /// The folder `mars family --out` wrote.
        run: PathBuf,
        /// The layout files the family ran on.
        #[arg(long, default_value = "configs/nav2d_family")]
        layouts: PathBuf,
        /// Chunks sampled from each demo's state past the entry gate.
        #[arg(long, default_value_t = 10)]
        draws: usize,
    },
    /// Draw the PNG plots of a run directory (demos, rollouts coloured by ‖w‖∞, K per step, losses).
    Plot {
        #[arg(long, default_value = "runs/nav2d")]
        run: PathBuf,
        #[arg(long, default_value = "configs/nav2d.toml")]
        layout: PathBuf,
    },
    /// Train and evaluate MARS, FM, A2A and Noise-A2A with the paper's settings; write results.md and plots.
    Benchmark(BenchmarkArgs),
    /// Training efficiency (paper Fig. 1(e)): train each policy × seed with a snapshot every N epochs, roll
    /// every snapshot out, and write success and γ per epoch (mean ± std), epochs-to-X % success and a plot.
    Curve {
        #[command(flatten)]
        args: mars_policy::curve::CurveArgs,
        #[arg(long, default_value = "configs/nav2d.toml")]
        layout: PathBuf,
        #[arg(long, default_value_t = cli::DEFAULT_EXEC_HORIZON)]
        exec_horizon: usize,
    },
    /// FM ablations of the paper's appendix: Fig. S3 (`--knob source-std`: loss and success against the source
    /// variance) and Fig. S4 (`--knob fm-lambda-rec`: an ungated L_rec pulls FM to the central passages).
    Ablate(AblateArgs),
    /// Two `mars family` runs (their family.json: same layouts, seeds and demos, two configurations) compared seed
    /// by seed: B − A per layout and policy with 95 % intervals.
    FamilyDiff {
        a: PathBuf,
        b: PathBuf,
        /// Also write the table here (markdown).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// The benchmark on every layout of a folder over several training seeds; judges MARS's mode targets
    /// against FM, and A2A's collapse, by their intervals over the seeds; writes family.md and family.json.
    Family(FamilyArgs),
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let jobs = match &args.command {
        Command::Benchmark(a) => a.jobs.unwrap_or(cores).max(1),
        Command::Family(a) => a.jobs.unwrap_or(cores).max(1),
        Command::Curve { args, .. } => args.jobs.unwrap_or(cores).max(1),
        Command::Ablate(a) => a.jobs.unwrap_or(cores).max(1),
        // RAYON_NUM_THREADS = cores / jobs: the threads asked for.
        Command::BenchTrain(a) => (cores / a.threads.max(1)).max(1),
        _ => 1,
    };
    cli::init_runtime_env(jobs);
    let result = match args.command {
        Command::Demos { layout, n, seed, out } => cli::demos(&layout, n, seed, &out),
        Command::FamilyDiff { a, b, out } => mars_policy::family_diff::run(&a, &b, out.as_deref()),
        Command::BenchTrain(args) => args.run(jobs),
        Command::Train(args) => args.run(jobs),
        Command::Curve { args, layout, exec_horizon } => {
            let task =
                cli::Nav2dCurve { layout: layout.clone(), demos: args.demos, rollouts: args.episodes, exec_horizon };
            let config = args.config.clone().unwrap_or_else(|| "configs/policy.toml".into());
            let out = args.out.clone().unwrap_or_else(|| "runs/curve_nav2d".into());
            let command = args.command_line("mars", &format!(" --layout {}", layout.display()));
            let trainer = mars_policy::curve::Trainer::InProcess;
            mars_policy::curve::run(&out, &config, &args.options(), &task, &trainer, &command).map(|_| ())
        }
        Command::Eval { checkpoint, layout, rollouts, seed, exec_horizon, steps, k_full_w, batch } => {
            let ablation = cli::StepsAblation { steps, k_full_w };
            cli::eval_with_steps(&checkpoint, &layout, rollouts, seed, exec_horizon, batch, ablation).map(|_| ())
        }
        Command::Diagnose { checkpoint, demos, layout, seed } => cli::diagnose(&checkpoint, &demos, &layout, seed),
        Command::DiagnoseFamily { run, layouts, draws } => mars_policy::diagnose_family::run(&run, &layouts, draws),
        Command::Plot { run, layout } => cli::plot(&run, &layout),
        Command::Benchmark(args) => args.run(jobs),
        Command::Ablate(args) => args.run(jobs),
        Command::Family(args) => args.run(jobs),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

#[derive(clap::Args)]
struct BenchTrainArgs {
    #[arg(long, value_parser = mars_policy::kind_arg::policy_kind_parser(), default_value_t = PolicyKind::Mars)]
    policy: PolicyKind,
    #[arg(long, default_value = "configs/policy.toml")]
    config: PathBuf,
    #[arg(long, default_value = "runs/nav2d/demos.json")]
    demos: PathBuf,
    #[arg(long, default_value_t = 2)]
    epochs: usize,
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// A Python with torch and safetensors (e.g. a venv's bin/python) to run the PyTorch peer.
    #[arg(long)]
    python: Option<PathBuf>,
    /// Threads for each trainer.
    #[arg(long, default_value_t = 1)]
    threads: usize,
    #[arg(long, default_value = "runs/bench_train")]
    out: PathBuf,
}

#[derive(clap::Args)]
struct TrainArgs {
    #[arg(long, value_parser = mars_policy::kind_arg::policy_kind_parser(), default_value_t = PolicyKind::Mars)]
    policy: PolicyKind,
    /// The policy's config (default: configs/policy.toml; with --dataset, the dataset's features on the shipped
    /// defaults, printed and written beside the checkpoint as config.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// A demo file (`mars demos`).
    #[arg(long, default_value = "runs/nav2d/demos.json")]
    demos: PathBuf,
    /// Train on a LeRobot v3.0 dataset instead (its directory: meta/, data/, videos/).
    #[arg(long, conflicts_with = "demos")]
    dataset: Option<PathBuf>,
    /// The dataset's state feature: the front of the observation.
    #[arg(long, default_value = "observation.state", requires = "dataset")]
    state_key: String,
    /// The dataset's action feature.
    #[arg(long, default_value = "action", requires = "dataset")]
    action_key: String,
    /// A camera stream (video feature) of the dataset, once per camera in the policy's order (default: every
    /// video feature, in name order).
    #[arg(long, requires = "dataset")]
    image_key: Vec<String>,
    /// What pads the action history before an episode starts: first-state or first-action (default: the
    /// first state when state and action have the same size, else the first action).
    #[arg(long, requires = "dataset")]
    rest_action: Option<mars_lerobot::demos::RestAction>,
    /// Where the normalisation's mean and std come from: the frames read (data) or the dataset's
    /// meta/stats.json (stats).
    #[arg(long, value_enum, default_value_t = mars_policy::from_dataset::Normalization::Data, requires = "dataset")]
    normalize_from: mars_policy::from_dataset::Normalization,
    /// Checkpoint directory (default: runs/nav2d/<policy>, or runs/<dataset name>/<policy>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Override `train.epochs`.
    #[arg(long)]
    epochs: Option<usize>,
    /// Override `train.seed`.
    #[arg(long)]
    seed: Option<u64>,
    /// Also save a checkpoint every N epochs (and at the last) under <out>/snapshots/epoch_NNNN.
    #[arg(long)]
    snapshot_every: Option<usize>,
}

/// The configuration a benchmark or family run compares, beside what `--config` says.
#[derive(clap::Args)]
struct Variant {
    /// Condition the velocity field and the scheduler on the history (model.velocity_uses_history and
    /// scheduler_uses_history), whatever --config says.
    #[arg(long)]
    history_conditioning: bool,
    /// Evaluate MARS with this ‖w‖∞ getting K_max steps instead of its checkpoint's `model.k_full_w` (1: the
    /// paper's K(w)); with --resume, the same checkpoints under another K(w) rule.
    #[arg(long)]
    k_full_w: Option<f32>,
}

#[derive(clap::Args)]
struct BenchmarkArgs {
    #[arg(long, default_value = "runs/nav2d")]
    out: PathBuf,
    #[arg(long, default_value = "configs/policy.toml")]
    config: PathBuf,
    #[arg(long, default_value = "configs/nav2d.toml")]
    layout: PathBuf,
    #[arg(long, default_value_t = 200)]
    demos: usize,
    #[arg(long)]
    epochs: Option<usize>,
    #[arg(long, default_value_t = 1000)]
    rollouts: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, default_value_t = cli::DEFAULT_EXEC_HORIZON)]
    exec_horizon: usize,
    /// Only these policies (default: all four).
    #[arg(long, value_parser = mars_policy::kind_arg::policy_kind_parser(), value_delimiter = ',')]
    policies: Vec<PolicyKind>,
    /// Policies trained at the same time (default: one per core). Evaluation is always one at a time.
    #[arg(long)]
    jobs: Option<usize>,
    /// Keep policies already trained under --out with this configuration and these demos (they are still
    /// evaluated): a stopped run continues where it stopped.
    #[arg(long)]
    resume: bool,
    #[command(flatten)]
    variant: Variant,
}

#[derive(clap::Args)]
struct AblateArgs {
    #[arg(long, value_enum)]
    knob: mars_policy::ablation::Knob,
    #[arg(long, value_delimiter = ',', required = true)]
    values: Vec<f64>,
    #[arg(long, default_value = "runs/ablation")]
    out: PathBuf,
    #[arg(long, default_value = "configs/policy.toml")]
    config: PathBuf,
    #[arg(long, default_value = "configs/nav2d.toml")]
    layout: PathBuf,
    #[arg(long, default_value_t = 100)]
    demos: usize,
    #[arg(long)]
    epochs: Option<usize>,
    #[arg(long, default_value_t = 1000)]
    rollouts: usize,
    /// Training seeds 0..N (each also seeds its demos and rollouts); the table gives means with 95 % intervals.
    #[arg(long, default_value_t = 5)]
    seeds: u64,
    #[arg(long, default_value_t = cli::DEFAULT_EXEC_HORIZON)]
    exec_horizon: usize,
    #[arg(long)]
    jobs: Option<usize>,
    /// Keep each value × seed already trained under --out with this configuration (it is still evaluated).
    #[arg(long)]
    resume: bool,
}

#[derive(clap::Args)]
struct FamilyArgs {
    #[arg(long, default_value = "runs/family")]
    out: PathBuf,
    #[arg(long, default_value = "configs/policy.toml")]
    config: PathBuf,
    #[arg(long, default_value = "configs/nav2d_family")]
    layouts: PathBuf,
    /// Training seeds 0..N.
    #[arg(long, default_value_t = 5)]
    seeds: u64,
    #[arg(long, default_value_t = 200)]
    demos: usize,
    #[arg(long)]
    epochs: Option<usize>,
    #[arg(long, default_value_t = 1000)]
    rollouts: usize,
    #[arg(long, default_value_t = cli::DEFAULT_EXEC_HORIZON)]
    exec_horizon: usize,
    /// Policies to compare (default: MARS and FM, the targets' two sides).
    #[arg(long, value_parser = mars_policy::kind_arg::policy_kind_parser(), value_delimiter = ',')]
    policies: Vec<PolicyKind>,
    #[arg(long)]
    jobs: Option<usize>,
    /// Keep each layout × seed × policy already trained under --out with this configuration (it is still
    /// evaluated): a stopped family run continues where it stopped, and more seeds add to fewer.
    #[arg(long)]
    resume: bool,
    #[command(flatten)]
    variant: Variant,
}

impl BenchTrainArgs {
    fn run(self, _jobs: usize) -> anyhow::Result<()> {
        let Self { policy, config, demos, epochs, rounds, python, threads, out } = self;
        let opts = mars_policy::bench_train::BenchTrainOptions {
            kind: policy,
            config,
            demos,
            epochs,
            rounds,
            python,
            threads,
            out,
        };
        mars_policy::bench_train::run(&opts)
    }
}

impl TrainArgs {
    fn run(self, _jobs: usize) -> anyhow::Result<()> {
        let Self {
            policy,
            config,
            demos,
            dataset,
            state_key,
            action_key,
            image_key,
            rest_action,
            normalize_from,
            out,
            epochs,
            seed,
            snapshot_every,
        } = self;
        let (input, runs) = match dataset {
            None => (cli::TrainInput::Demos(demos), PathBuf::from("runs/nav2d")),
            Some(dir) => {
                let name = dir.file_name().map_or_else(|| "dataset".into(), |n| n.to_owned());
                let input = mars_policy::from_dataset::DatasetInput {
                    dir,
                    state_key,
                    action_key,
                    image_keys: image_key,
                    rest: rest_action,
                    normalize: normalize_from,
                };
                (cli::TrainInput::Dataset(input), PathBuf::from("runs").join(name))
            }
        };
        let out = out.unwrap_or_else(|| runs.join(policy.name()));
        cli::train(policy, config.as_deref(), &input, &out, epochs, seed, snapshot_every).map(|_| ())
    }
}

impl BenchmarkArgs {
    fn run(self, jobs: usize) -> anyhow::Result<()> {
        let Self {
            out,
            config,
            layout,
            demos,
            epochs,
            rollouts,
            seed,
            exec_horizon,
            policies,
            resume,
            variant: Variant { history_conditioning, k_full_w },
            ..
        } = self;
        let policies = if policies.is_empty() { PolicyKind::ALL.to_vec() } else { policies };
        let opts = mars_policy::benchmark::BenchmarkOptions {
            demos,
            epochs,
            rollouts,
            seed,
            exec_horizon,
            policies,
            jobs,
            resume,
            history_conditioning,
            k_full_w,
            side_by_side: false,
        };
        mars_policy::benchmark::benchmark(&out, &config, &layout, &opts).map(|_| ())
    }
}

impl AblateArgs {
    fn run(self, jobs: usize) -> anyhow::Result<()> {
        let Self { knob, values, out, config, layout, demos, epochs, rollouts, seeds, exec_horizon, resume, .. } = self;
        let opts = mars_policy::ablation::AblateOptions {
            knob,
            values,
            demos,
            epochs,
            rollouts,
            seeds,
            exec_horizon,
            jobs,
            resume,
        };
        mars_policy::ablation::run(&out, &config, &layout, &opts).map(|_| ())
    }
}

impl FamilyArgs {
    fn run(self, jobs: usize) -> anyhow::Result<()> {
        let Self {
            out,
            config,
            layouts,
            seeds,
            demos,
            epochs,
            rollouts,
            exec_horizon,
            policies,
            resume,
            variant: Variant { history_conditioning, k_full_w },
            ..
        } = self;
        let policies = if policies.is_empty() { vec![PolicyKind::Mars, PolicyKind::Fm] } else { policies };
        let bench = mars_policy::benchmark::BenchmarkOptions {
            demos,
            epochs,
            rollouts,
            seed: 0,
            exec_horizon,
            policies,
            jobs,
            resume,
            history_conditioning,
            k_full_w,
            side_by_side: false,
        };
        let opts = family::FamilyOptions { bench, seeds, targets: family::Targets::default() };
        family::run(&out, &config, &layouts, &opts).map(|_| ())
    }
}
