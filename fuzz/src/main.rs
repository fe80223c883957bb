//! `mars-fuzz`: mutation fuzzing of every decoder of untrusted input (see the crate's doc and README's "Fuzzing").
//!
//! `mars-fuzz all --cases 10000000 --seed 1` runs every target; `mars-fuzz run lerobot-info …` one;
//! `mars-fuzz repro TARGET FILE` decodes a saved input again outside `catch_unwind` (the panic shows in full).

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use clap::{Parser, Subcommand};
use mars_fuzz::runner::{Options, Report, Target, run};
use mars_fuzz::targets;

#[global_allocator]
static ALLOC: mars_fuzz::guard::CappedAlloc = mars_fuzz::guard::CappedAlloc;

#[derive(Parser)]
#[command(about = "Seeded mutation fuzzing of every decoder of untrusted input (stable Rust)")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args, Clone)]
struct RunArgs {
    /// The first case to run (the cases a stopped run did not reach: the number its report or progress gives).
    #[arg(long, default_value_t = 0)]
    first_case: u64,
    /// Cases per target.
    #[arg(long, default_value_t = 100_000)]
    cases: u64,
    /// The run's seed: the same seed makes the same inputs.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Where failing inputs are saved.
    #[arg(long, default_value = "target/fuzz-failures")]
    out: PathBuf,
    /// A case running longer than this is a hang (s).
    #[arg(long, default_value_t = 20.0)]
    case_timeout_s: f64,
    /// Progress on stderr every this many seconds (0: none).
    #[arg(long, default_value_t = 60.0)]
    progress_s: f64,
    /// Stop each target after this many seconds, whatever --cases says (0: no limit).
    #[arg(long, default_value_t = 0.0)]
    time_limit_s: f64,
}

#[derive(Subcommand)]
enum Command {
    /// Every target, one after the other.
    All(RunArgs),
    /// The named targets.
    Run {
        #[arg(required = true)]
        targets: Vec<String>,
        #[command(flatten)]
        args: RunArgs,
    },
    /// The targets' names.
    List,
    /// Decode a saved input again, without catching its panic.
    Repro { target: String, input: PathBuf },
    /// Write the input of one case (the same as in a run with that seed) to a file.
    Case {
        target: String,
        #[arg(long)]
        seed: u64,
        #[arg(long)]
        case: u64,
        #[arg(long)]
        to: PathBuf,
    },
}

fn find(name: &str) -> Option<Arc<dyn Target>> {
    targets::all().into_iter().find(|t| t.name() == name)
}

fn options(a: &RunArgs) -> Result<Options, String> {
    let secs = |s: f64, what: &str| {
        Duration::try_from_secs_f64(s).map_err(|_| format!("--{what} must be a number of seconds ≥ 0, got {s}"))
    };
    let progress = secs(a.progress_s, "progress-s")?;
    let limit = secs(a.time_limit_s, "time-limit-s")?;
    Ok(Options {
        first_case: a.first_case,
        cases: a.cases,
        seed: a.seed,
        out: a.out.clone(),
        case_timeout: secs(a.case_timeout_s, "case-timeout-s")?,
        progress: (!progress.is_zero()).then_some(progress),
        time_limit: (!limit.is_zero()).then_some(limit),
    })
}

fn run_all(list: Vec<Arc<dyn Target>>, a: &RunArgs) -> ExitCode {
    let opts = match options(a) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("mars-fuzz: {e}");
            return ExitCode::from(2);
        }
    };
    println!("mars-fuzz: seed {}, {} cases per target from case {}", opts.seed, opts.cases, opts.first_case);
    let reports: Vec<Report> = list
        .into_iter()
        .map(|t| {
            let r = run(t, &opts);
            println!("{r}");
            r
        })
        .collect();
    let failed = reports.iter().filter(|r| !r.failures.is_empty()).count();
    println!("mars-fuzz: {} targets, {failed} with failures", reports.len());
    if failed == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE }
}

fn main() -> ExitCode {
    match Args::parse().command {
        Command::All(a) => run_all(targets::all(), &a),
        Command::Run { targets: names, args } => {
            let mut list = Vec::new();
            for n in &names {
                match find(n) {
                    Some(t) => list.push(t),
                    None => {
                        eprintln!("mars-fuzz: no target {n:?} (`mars-fuzz list` names them)");
                        return ExitCode::from(2);
                    }
                }
            }
            run_all(list, &args)
        }
        Command::List => {
            targets::all().iter().for_each(|t| println!("{}", t.name()));
            ExitCode::SUCCESS
        }
        Command::Case { target, seed, case, to } => {
            let Some(t) = find(&target) else {
                eprintln!("mars-fuzz: no target {target:?}");
                return ExitCode::from(2);
            };
            let input = t.generate(&mut mars_fuzz::runner::case_rng(seed, t.name(), case));
            match std::fs::write(&to, input) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("mars-fuzz: {}: {e}", to.display());
                    ExitCode::from(2)
                }
            }
        }
        Command::Repro { target, input } => {
            let Some(t) = find(&target) else {
                eprintln!("mars-fuzz: no target {target:?}");
                return ExitCode::from(2);
            };
            match std::fs::read(&input) {
                Ok(bytes) => {
                    let started = std::time::Instant::now();
                    let accepted = t.run(&bytes);
                    let took = started.elapsed().as_secs_f64() * 1e3;
                    let verdict = if accepted { "accepted" } else { "refused" };
                    println!("{target}: {} decoded without a panic in {took:.1} ms: {verdict}", input.display());
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("mars-fuzz: {}: {e}", input.display());
                    ExitCode::from(2)
                }
            }
        }
    }
}
